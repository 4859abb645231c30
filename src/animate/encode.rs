//! Writing frames: a looping GIF with the fixed palette ([`GifSink`]), and an MP4 by piping
//! raw rgb24 frames to an `ffmpeg` subprocess ([`Mp4Sink`]) when one is found
//! ([`find_ffmpeg`]).

use std::borrow::Cow;
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

use super::canvas::{Canvas, Ink};
use super::error::AnimateError;

/// The `ffmpeg` program on `PATH`, if any.
#[must_use]
pub fn find_ffmpeg() -> Option<PathBuf> {
    let name = if cfg!(windows) {
        "ffmpeg.exe"
    } else {
        "ffmpeg"
    };
    std::env::split_paths(&std::env::var_os("PATH")?)
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// A GIF being written: `width` × `height` frames, each shown for `delay_cs` hundredths of a
/// second, looping forever.
pub struct GifSink {
    path: PathBuf,
    encoder: gif::Encoder<BufWriter<File>>,
    size: (u16, u16),
    delay_cs: u16,
}

impl GifSink {
    /// Creates the file at `path` and writes the header and palette.
    ///
    /// # Errors
    /// [`AnimateError::Io`] when the file cannot be created, [`AnimateError::Gif`] when the
    /// header cannot be written or a side exceeds 65535 pixels.
    pub fn create(path: &Path, size: (u32, u32), frame_s: f64) -> Result<Self, AnimateError> {
        let gif_err = |source| AnimateError::Gif {
            path: path.to_path_buf(),
            source,
        };
        let side = |v: u32| {
            u16::try_from(v).map_err(|_| {
                gif_err(gif::EncodingError::from(std::io::Error::other(
                    "a side exceeds 65535 pixels",
                )))
            })
        };
        let size = (side(size.0)?, side(size.1)?);
        let file = File::create(path).map_err(|source| AnimateError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut encoder = gif::Encoder::new(BufWriter::new(file), size.0, size.1, &Ink::palette())
            .map_err(gif_err)?;
        encoder.set_repeat(gif::Repeat::Infinite).map_err(gif_err)?;
        // frame_s is validated to 0.01..=10 s: 1..=1000 hundredths.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let delay_cs = (frame_s * 100.0).round() as u16;
        Ok(Self {
            path: path.to_path_buf(),
            encoder,
            size,
            delay_cs,
        })
    }

    /// Appends `frame` (of the sink's size).
    ///
    /// # Errors
    /// [`AnimateError::Gif`] when writing fails.
    pub fn push(&mut self, frame: &Canvas) -> Result<(), AnimateError> {
        let f = gif::Frame {
            delay: self.delay_cs,
            width: self.size.0,
            height: self.size.1,
            buffer: Cow::Borrowed(frame.indices()),
            ..gif::Frame::default()
        };
        self.encoder
            .write_frame(&f)
            .map_err(|source| AnimateError::Gif {
                path: self.path.clone(),
                source,
            })
    }

    /// Writes the trailer and flushes the file.
    ///
    /// # Errors
    /// [`AnimateError::Gif`] / [`AnimateError::Io`] when writing fails.
    pub fn finish(self) -> Result<(), AnimateError> {
        let path = self.path;
        let mut w = self
            .encoder
            .into_inner()
            .map_err(|source| AnimateError::Gif {
                path: path.clone(),
                source,
            })?;
        w.flush()
            .map_err(|source| AnimateError::Io { path, source })
    }
}

/// An MP4 being written by an `ffmpeg` subprocess fed raw rgb24 frames on its stdin.
pub struct Mp4Sink {
    path: PathBuf,
    child: Child,
    stdin: Option<ChildStdin>,
    /// Reads ffmpeg's error output while it runs (a full pipe would stall it).
    stderr: Option<std::thread::JoinHandle<String>>,
}

impl Mp4Sink {
    /// Starts `ffmpeg` writing `path` from `size` = (width, height) rgb24 frames (even sides),
    /// each shown for `frame_s` seconds (H.264 or the build's default MP4 codec, yuv420p).
    ///
    /// # Errors
    /// [`AnimateError::Io`] when `ffmpeg` cannot be started.
    pub fn start(
        ffmpeg: &Path,
        path: &Path,
        size: (u32, u32),
        frame_s: f64,
    ) -> Result<Self, AnimateError> {
        // frame_s is validated to 0.01..=10 s.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let frame_ms = (frame_s * 1000.0).round() as u32;
        let mut child = Command::new(ffmpeg)
            .args(["-hide_banner", "-loglevel", "error", "-y"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
            .args(["-s", &format!("{}x{}", size.0, size.1)])
            .args(["-framerate", &format!("1000/{frame_ms}"), "-i", "-"])
            .args(["-pix_fmt", "yuv420p", "-movflags", "+faststart"])
            .arg(path)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|source| AnimateError::Io {
                path: ffmpeg.to_path_buf(),
                source,
            })?;
        let stdin = child.stdin.take();
        let stderr = child.stderr.take().map(|mut e| {
            std::thread::spawn(move || {
                let mut text = String::new();
                let _ = e.read_to_string(&mut text);
                text
            })
        });
        Ok(Self {
            path: path.to_path_buf(),
            child,
            stdin,
            stderr,
        })
    }

    /// Sends `frame` to `ffmpeg`. A write that fails (ffmpeg stopped) is reported by
    /// [`Mp4Sink::finish`] with ffmpeg's own message.
    pub fn push(&mut self, frame: &Canvas) {
        if let Some(stdin) = &mut self.stdin
            && stdin.write_all(&frame.rgb()).is_err()
        {
            self.stdin = None;
        }
    }

    /// Closes `ffmpeg`'s input and waits for it.
    ///
    /// # Errors
    /// [`AnimateError::Ffmpeg`] when it fails, or when its input was closed early;
    /// [`AnimateError::Io`] when it cannot be waited for.
    pub fn finish(mut self) -> Result<(), AnimateError> {
        let complete = self.stdin.take().is_some();
        let status = self.child.wait().map_err(|source| AnimateError::Io {
            path: self.path.clone(),
            source,
        })?;
        let stderr = self
            .stderr
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default();
        if status.success() && complete {
            return Ok(());
        }
        let tail: String = stderr
            .trim()
            .chars()
            .rev()
            .take(500)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        Err(AnimateError::Ffmpeg {
            path: self.path,
            status: status.to_string(),
            stderr: if complete {
                tail
            } else {
                format!("it stopped reading frames: {tail}")
            },
        })
    }
}
