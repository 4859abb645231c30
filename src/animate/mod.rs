//! Animations of closed-loop runs: one GIF (and an MP4 when `ffmpeg` is on `PATH`) per run,
//! drawn by the one renderer both the `nudge simulate --animate` command and Python's
//! `nudge.animate` use.
//!
//! Every frame shows the state before one planning step (the last the state after the last
//! step), seen from above with the camera following the ego along the road (x to the right,
//! the road's left side at the top):
//!
//! * the lanes (edges solid, inner boundaries dashed) and every vehicle as its rotated box
//!   (the ego blue, magenta in a collision; the vehicle the plan's safety binds on orange);
//! * the ego's executed path so far (cyan);
//! * the step's plan z_0..z_T (green);
//! * the planning predictor's predicted reaction of every other vehicle to that plan
//!   (yellow);
//! * the binding vehicle's safety ellipses at each plan step, centred on its predicted
//!   positions (red; the one at the binding step bold);
//! * a caption: the run, the step, the plan's status, the speed, the planning time and the
//!   binding vehicle with its b.
//!
//! The run must have been simulated with tracing on ([`nudge_sim::RunControl::trace`]);
//! [`Reel::from_run`] gathers what is drawn, [`animate`] writes it.

mod canvas;
mod draw;
mod encode;
mod error;
mod reel;
mod view;

use std::path::{Path, PathBuf};

pub use canvas::{Canvas, Ink};
pub use draw::{clip_segment, corners, draw_frame, step_line};
pub use encode::{GifSink, Mp4Sink, find_ffmpeg};
pub use error::AnimateError;
pub use reel::{MAX_SHOTS, MAX_VEHICLE_M, PlannedStep, Reel, Shot};
pub use view::{AnimationSettings, CAPTION_PX, MAX_SIDE_PX, View, frame_size};

/// What [`animate`] wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Written {
    /// The GIF.
    pub gif: PathBuf,
    /// The MP4, when one was asked for.
    pub mp4: Option<PathBuf>,
    /// Frames (steps + 1).
    pub frames: usize,
    /// (width, height) of every frame (pixels).
    pub size: (u32, u32),
}

/// Draws every frame of `reel` under `settings` and writes them to the GIF `gif` and, when
/// `mp4` = (its path, the `ffmpeg` program) is given, to that MP4 (ffmpeg fed raw rgb24
/// frames). Frames are drawn one at a time (memory: one frame).
///
/// # Errors
/// [`AnimateError::Setting`] / [`AnimateError::Invalid`] before anything is written when a
/// setting is out of range or the reel is malformed; [`AnimateError::Io`],
/// [`AnimateError::Gif`], [`AnimateError::Ffmpeg`] when writing fails.
pub fn animate(
    reel: &Reel,
    settings: &AnimationSettings,
    gif: &Path,
    mp4: Option<(&Path, &Path)>,
) -> Result<Written, AnimateError> {
    settings.validate()?;
    reel.validate()?;
    let size = frame_size(reel, settings)?;
    let mut gif_sink = GifSink::create(gif, size, settings.frame_s)?;
    let mut mp4_sink = mp4
        .map(|(path, ffmpeg)| Mp4Sink::start(ffmpeg, path, size, settings.frame_s))
        .transpose()?;
    for k in 0..reel.shots.len() {
        let frame = draw_frame(reel, k, settings, size);
        gif_sink.push(&frame)?;
        if let Some(m) = &mut mp4_sink {
            m.push(&frame);
        }
    }
    gif_sink.finish()?;
    if let Some(m) = mp4_sink {
        m.finish()?;
    }
    Ok(Written {
        gif: gif.to_path_buf(),
        mp4: mp4.map(|(p, _)| p.to_path_buf()),
        frames: reel.shots.len(),
        size,
    })
}

#[cfg(test)]
mod tests;
