//! Arguments at the binding boundary: Python ints range-checked where their name is known,
//! and the last-resort guard that turns a Rust panic into a `NudgeError`.

use std::panic::{AssertUnwindSafe, catch_unwind};

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyBool;

use crate::errors::{InputError, NudgeError};

/// A Python int argument, range-checked in the function body where its name is known (pyo3
/// names an argument only in a `TypeError`; a negative or huge int would otherwise surface as
/// a bare `OverflowError`). Accepts `int` and anything with `__index__` (numpy integers), not
/// `bool`.
#[derive(Debug, Clone)]
pub struct Int(Result<u64, String>);

impl From<u64> for Int {
    fn from(v: u64) -> Self {
        Self(Ok(v))
    }
}

impl<'a, 'py> FromPyObject<'a, 'py> for Int {
    type Error = PyErr;

    fn extract(obj: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        if obj.is_instance_of::<PyBool>() {
            return Err(PyTypeError::new_err("expected an int, got bool"));
        }
        match obj.extract::<u64>() {
            Ok(v) => Ok(Self(Ok(v))),
            // An int out of u64's range: negative or too large, reported with the name.
            Err(e) if e.is_instance_of::<pyo3::exceptions::PyOverflowError>(obj.py()) => {
                Ok(Self(Err(obj.repr()?.to_string())))
            }
            Err(e) => Err(e),
        }
    }
}

impl Int {
    /// The value, or `InputError` naming the argument `name` when it is negative or beyond
    /// `u64` (the message states `bound`, the argument's documented bound; values within `u64`
    /// are left to the library's own check of that bound, so both front ends word it alike).
    pub fn u64(self, name: &str, bound: u64) -> PyResult<u64> {
        self.0.map_err(|shown| {
            InputError::new_err(if shown.trim_start().starts_with('-') {
                format!("invalid argument `{name}`: must be a non-negative integer, got {shown}")
            } else {
                format!("invalid argument `{name}`: {shown} is too large (at most {bound})")
            })
        })
    }

    /// A `usize` argument (a count or an index), as [`Int::u64`].
    pub fn usize(self, name: &str, bound: usize) -> PyResult<usize> {
        let v = self.u64(name, bound as u64)?;
        usize::try_from(v).map_err(|_| {
            InputError::new_err(format!(
                "invalid argument `{name}`: {v} is too large (at most {bound})"
            ))
        })
    }
}

/// Runs `f`, turning a Rust panic into `NudgeError` with the panic's message: the last resort
/// that keeps pyo3's `PanicException` (a `BaseException`) from reaching Python. Every cause
/// found is fixed where it lies; this only guards against the ones not found yet.
pub fn guard<T>(f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|payload| Err(panic_error(payload.as_ref())))
}

/// `NudgeError` for a panic payload.
pub fn panic_error(payload: &(dyn std::any::Any + Send)) -> PyErr {
    let msg = payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".to_owned());
    NudgeError::new_err(format!("internal error in nudge (please report it): {msg}"))
}
