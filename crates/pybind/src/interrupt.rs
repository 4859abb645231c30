//! Long native work run from Python so that Ctrl-C and Python callbacks reach it: the work
//! runs on a worker thread with the GIL released while the calling thread polls Python's
//! signal handlers.

use std::sync::mpsc;
use std::time::Duration;

use nudge_sim::Cancel;
use pyo3::prelude::*;

use crate::args::panic_error;
use crate::errors::NudgeError;

/// How often a thread waiting for native work polls Python's signal handlers.
pub const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// Runs `work` on a worker thread with the GIL released while this (the calling) thread, every
/// [`SIGNAL_POLL`], runs Python's signal handlers and then `tick(false)`: the first error of
/// either sets `cancel` (which `work` is expected to watch) and is returned once `work` has
/// ended. When `work` ends, `tick(true)` runs once (an error is returned, nothing to cancel).
/// A panic of the worker becomes a `NudgeError` (`what` names the work in the message).
pub(crate) fn interruptibly<T, W, K>(
    py: Python<'_>,
    cancel: &Cancel,
    what: &str,
    work: W,
    mut tick: K,
) -> PyResult<T>
where
    T: Send,
    W: FnOnce() -> T + Send,
    K: FnMut(bool) -> PyResult<()> + Send,
{
    let mut interrupt: Option<PyErr> = None;
    let finished = py.detach(|| {
        std::thread::scope(|scope| {
            let (tx, rx) = mpsc::channel();
            let worker = scope.spawn(move || {
                // The receiver outlives the worker: sending cannot fail.
                let _ = tx.send(work());
            });
            loop {
                match rx.recv_timeout(SIGNAL_POLL) {
                    Ok(value) => {
                        if interrupt.is_none()
                            && let Err(e) = tick(true)
                        {
                            interrupt = Some(e);
                        }
                        return Ok(value);
                    }
                    Err(mpsc::RecvTimeoutError::Timeout) => {
                        if interrupt.is_none()
                            && let Err(e) =
                                Python::attach(|py| py.check_signals()).and_then(|()| tick(false))
                        {
                            cancel.cancel();
                            interrupt = Some(e);
                        }
                    }
                    // The worker panicked: its payload becomes a NudgeError.
                    Err(mpsc::RecvTimeoutError::Disconnected) => {
                        return Err(worker.join().err());
                    }
                }
            }
        })
    });
    if let Some(e) = interrupt {
        return Err(e);
    }
    finished.map_err(|payload| match payload {
        Some(p) => panic_error(p.as_ref()),
        None => NudgeError::new_err(format!("the {what} worker stopped without a result")),
    })
}
