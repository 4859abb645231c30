//! [`AnimateError`]: why an animation could not be made.

use std::path::PathBuf;

/// Why an animation could not be made (the one error type of this crate).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AnimateError {
    /// The run to draw is malformed: `item` names the frame and field (e.g. `frame 3
    /// plan`), `reason` says what is wrong with it.
    #[error("cannot animate: {item}: {reason}")]
    Invalid {
        /// The frame and field at fault.
        item: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A step of the run carries no trace: the run was simulated without tracing
    /// (`nudge simulate --animate` and `nudge.simulate(..., trace=True)` trace).
    #[error(
        "cannot animate run on {scene}: step {step} has no trace (simulate with tracing on: \
         `--animate`, or trace=True from Python)"
    )]
    NoTrace {
        /// The run's scenario.
        scene: String,
        /// The first step without a trace.
        step: usize,
    },
    /// An animation setting is out of range.
    #[error("animation setting `{field}` = {value}: {reason}")]
    Setting {
        /// The setting.
        field: &'static str,
        /// Its value.
        value: String,
        /// The allowed range.
        reason: &'static str,
    },
    /// Writing an output file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The GIF encoder failed.
    #[error("{}: GIF encoding failed: {source}", path.display())]
    Gif {
        /// The file.
        path: PathBuf,
        /// The encoder's error.
        source: gif::EncodingError,
    },
    /// `ffmpeg` ran but did not write the MP4.
    #[error("{}: ffmpeg failed ({status}): {stderr}", path.display())]
    Ffmpeg {
        /// The file it was to write.
        path: PathBuf,
        /// Its exit status.
        status: String,
        /// The end of its error output.
        stderr: String,
    },
}
