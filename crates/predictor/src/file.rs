//! Bounded reading of input files: regular files only, size checked before reading.
//!
//! Used for weights here and for scenario files by `nudge-planner`, so that a FIFO (which
//! blocks a reader forever), a device such as `/dev/zero` (endless) or a huge file never
//! reaches `read`.

use std::io::Read;
use std::path::Path;

use crate::error::{PredictorError, Result};

/// Largest weights file accepted (bytes): 64 MiB. The shipped teacher is 0.24 MB and the
/// largest configuration the training code builds is a few MB.
pub const MAX_WEIGHTS_BYTES: u64 = 64 << 20;

/// What a non-regular file is, for messages.
fn kind(ft: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return "a FIFO";
        }
        if ft.is_char_device() {
            return "a character device";
        }
        if ft.is_block_device() {
            return "a block device";
        }
        if ft.is_socket() {
            return "a socket";
        }
    }
    if ft.is_dir() {
        "a directory"
    } else {
        "not a file"
    }
}

/// Reads `path` whole if it is a regular file (symbolic links followed) of at most
/// `max_bytes` bytes.
///
/// The type and size are checked on the path before opening (so a FIFO is never opened) and
/// again on the open handle; the read itself stops after `max_bytes + 1` bytes, so a file that
/// grows meanwhile is refused too.
///
/// # Errors
/// [`PredictorError::Io`] when the file cannot be inspected or read,
/// [`PredictorError::NotRegularFile`] for a FIFO, device, socket or directory,
/// [`PredictorError::FileTooLarge`] above `max_bytes`; every error names `path`.
pub fn read_bounded(path: &Path, max_bytes: u64) -> Result<Vec<u8>> {
    let io = |source| PredictorError::Io {
        path: path.to_path_buf(),
        source,
    };
    let check = |meta: std::fs::Metadata| -> Result<u64> {
        if !meta.is_file() {
            return Err(PredictorError::NotRegularFile {
                path: path.to_path_buf(),
                kind: kind(meta.file_type()),
            });
        }
        if meta.len() > max_bytes {
            return Err(PredictorError::FileTooLarge {
                path: path.to_path_buf(),
                size: meta.len(),
                max: max_bytes,
            });
        }
        Ok(meta.len())
    };
    check(std::fs::metadata(path).map_err(io)?)?;
    let file = std::fs::File::open(path).map_err(io)?;
    let len = check(file.metadata().map_err(io)?)?;
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(io)?;
    let read = bytes.len() as u64;
    if read > max_bytes {
        return Err(PredictorError::FileTooLarge {
            path: path.to_path_buf(),
            size: read,
            max: max_bytes,
        });
    }
    Ok(bytes)
}
