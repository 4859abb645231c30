//! Writing output files atomically, as a set, never through a symbolic link.
//!
//! [`write_set`] writes every file of a set (records, tables, solutions) to a fresh temporary
//! file in the destination directory (created with `O_CREAT | O_EXCL`, so a name planted
//! there, a symbolic link included, is never opened or followed), flushes each to disk, and
//! only then renames them into place one after the other. `rename` replaces the directory
//! entry, so a symbolic link at a destination name is replaced by the new file and its target
//! is left untouched.
//!
//! **What a `kill -9` leaves.** Every file is at all times either its whole old version (or
//! absent) or its whole new version: never empty, truncated or mixed. The set as a whole is
//! described by a manifest, [`MANIFEST`] (`sha256sum -c` format: one `<sha256>  <name>` line
//! per file), renamed into place after every file of the set. So:
//! - killed before the renames: the old set, with its old manifest, untouched;
//! - killed during the renames (a window of a few `rename` calls): a mix of old and new files
//!   under the old manifest, which they no longer match, so the mix is detectable;
//! - finished: the new set and its manifest.
//!
//! A set is therefore known to be consistent exactly when [`MANIFEST`] is present and every
//! file matches it ([`verify_set`]; `sha256sum -c outputs.sha256` in the directory). Stray
//! temporary files of a killed write (`.<name>.tmp-<pid>-<n>`) are hidden files that the
//! next [`write_set`] in the directory removes.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use sha2::{Digest, Sha256};

/// The set's manifest file name: `sha256sum -c` lines of every file of the set.
pub const MANIFEST: &str = "outputs.sha256";

/// Why a set could not be written or verified: names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FilesError {
    /// A file could not be created, written, flushed or renamed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A name of the set is not a plain file name (empty, a path, `.` or `..`, or the
    /// manifest's own name).
    #[error("{name:?} is not a plain file name for an output set")]
    BadName {
        /// The name.
        name: String,
    },
    /// The manifest is absent, or a file does not match it.
    #[error("{path}: {reason}")]
    Inconsistent {
        /// The manifest or the file that does not match it.
        path: PathBuf,
        /// What does not match.
        reason: String,
    },
}

static COUNTER: AtomicU64 = AtomicU64::new(0);

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> FilesError + '_ {
    move |source| FilesError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// A fresh temporary name in `dir` for `name`, created exclusively and written with `bytes`,
/// flushed to disk.
fn write_temp(dir: &Path, name: &str, bytes: &[u8]) -> Result<PathBuf, FilesError> {
    loop {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.tmp-{}-{n}", std::process::id()));
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp);
        let mut file = match file {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(io(&tmp)(e)),
        };
        file.write_all(bytes).map_err(io(&tmp))?;
        file.sync_all().map_err(io(&tmp))?;
        return Ok(tmp);
    }
}

/// Removes the hidden temporary files a killed [`write_set`] left in `dir`.
fn remove_stale_temps(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let name = name.to_string_lossy();
        if name.starts_with('.')
            && name.contains(".tmp-")
            && e.file_type().is_ok_and(|t| t.is_file())
        {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

fn check_name(name: &str) -> Result<(), FilesError> {
    let plain = !name.is_empty()
        && name != "."
        && name != ".."
        && name != MANIFEST
        && !name.contains('/')
        && !name.contains('\0');
    if plain {
        Ok(())
    } else {
        Err(FilesError::BadName {
            name: name.to_string(),
        })
    }
}

fn hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .fold(String::with_capacity(64), |mut s, b| {
            let _ = std::fmt::Write::write_fmt(&mut s, format_args!("{b:02x}"));
            s
        })
}

/// Writes the files `(name, bytes)` into the existing directory `dir` as one set, with its
/// [`MANIFEST`] (see the module docs for what a crash leaves).
///
/// # Errors
/// [`FilesError::BadName`] for a name that is not a plain file name (nothing is written);
/// [`FilesError::Io`] naming the file that could not be written or renamed (the temporary
/// files written so far are removed; the old set is untouched unless the renames had begun).
pub fn write_set(dir: &Path, files: &[(&str, &[u8])]) -> Result<(), FilesError> {
    write_set_until(dir, files, usize::MAX)
}

/// [`write_set`] stopping, as a `kill -9` would, after `steps` of its disk operations (each
/// temporary file, then each rename); `usize::MAX` runs to the end. For
/// the crash tests.
#[doc(hidden)]
pub fn write_set_until(
    dir: &Path,
    files: &[(&str, &[u8])],
    steps: usize,
) -> Result<(), FilesError> {
    for (name, _) in files {
        check_name(name)?;
    }
    remove_stale_temps(dir);
    let manifest: String = files
        .iter()
        .map(|(name, bytes)| format!("{}  {name}\n", hex(bytes)))
        .collect();
    let all: Vec<(&str, &[u8])> = files
        .iter()
        .copied()
        .chain([(MANIFEST, manifest.as_bytes())])
        .collect();
    let mut done = 0usize;
    let mut temps: Vec<(PathBuf, PathBuf)> = Vec::with_capacity(all.len());
    for (name, bytes) in &all {
        if done == steps {
            return Ok(());
        }
        match write_temp(dir, name, bytes) {
            Ok(tmp) => temps.push((tmp, dir.join(name))),
            Err(e) => {
                for (tmp, _) in &temps {
                    let _ = std::fs::remove_file(tmp);
                }
                return Err(e);
            }
        }
        done += 1;
    }
    // The manifest is last in `temps`: renamed into place after every file of the set.
    for (tmp, dest) in &temps {
        if done == steps {
            return Ok(());
        }
        std::fs::rename(tmp, dest).map_err(io(dest))?;
        done += 1;
    }
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Writes one file atomically, as [`write_set`] writes each file of a set (temporary file in
/// the same directory, flushed, renamed into place; a symbolic link at `path` is replaced),
/// without a manifest.
///
/// # Errors
/// [`FilesError::BadName`] when `path` has no file name; [`FilesError::Io`] naming the file.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), FilesError> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    check_name(&name)?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let tmp = write_temp(dir, &name, bytes)?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        io(path)(e)
    })
}

/// Checks that `dir` holds a complete set: [`MANIFEST`] present and every file it names
/// matching its hash. Returns the names of the set.
///
/// # Errors
/// [`FilesError::Inconsistent`] naming the manifest (absent, malformed) or the first file
/// that is missing or does not match; [`FilesError::Io`] when a file cannot be read.
pub fn verify_set(dir: &Path) -> Result<Vec<String>, FilesError> {
    let manifest_path = dir.join(MANIFEST);
    let text = match std::fs::read_to_string(&manifest_path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(FilesError::Inconsistent {
                path: manifest_path,
                reason: "absent: the set was not completely written".into(),
            });
        }
        Err(e) => return Err(io(&manifest_path)(e)),
    };
    let mut names = Vec::new();
    for line in text.lines() {
        let Some((hash, name)) = line.split_once("  ") else {
            return Err(FilesError::Inconsistent {
                path: manifest_path,
                reason: format!("malformed line {line:?}"),
            });
        };
        let path = dir.join(name);
        let bytes = std::fs::read(&path).map_err(io(&path))?;
        if hex(&bytes) != hash {
            return Err(FilesError::Inconsistent {
                path,
                reason: "does not match the manifest".into(),
            });
        }
        names.push(name.to_string());
    }
    Ok(names)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("nudge-files-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("dir");
        d
    }

    /// At every point a `kill -9` could stop the write, each file is whole (old or new) and the
    /// set verifies only when it is entirely old or entirely new: the old set before the
    /// renames, the new one after them, never a mix.
    #[test]
    fn a_crash_at_any_step_leaves_whole_files_and_a_detectable_set() {
        let old: [(&str, &[u8]); 3] =
            [("a.csv", b"old a"), ("b.csv", b"old b"), ("r.json", b"[1]")];
        let new: [(&str, &[u8]); 3] = [
            ("a.csv", b"new a, longer"),
            ("b.csv", b""),
            ("r.json", b"[2, 3]"),
        ];
        // 4 temporaries, then 4 renames.
        for steps in 0..=9 {
            let d = dir(&format!("crash{steps}"));
            write_set(&d, &old).expect("old set");
            write_set_until(&d, &new, steps).expect("partial");
            let mut all_old = true;
            let mut all_new = true;
            for ((name, o), (_, n)) in old.iter().zip(&new) {
                let got = std::fs::read(d.join(name)).expect("file");
                assert!(got == *o || got == *n, "{steps}: {name} is {got:?}");
                all_old &= got == *o;
                all_new &= got == *n;
            }
            let verified = verify_set(&d).is_ok();
            assert!(
                !verified || all_old || all_new,
                "steps {steps}: a mix verifies"
            );
            assert_eq!(steps <= 4, all_old && verified, "steps {steps}");
            assert_eq!(steps >= 8, all_new && verified, "steps {steps}");
            write_set(&d, &new).expect("rewrite");
            assert!(verify_set(&d).is_ok());
            let stray = std::fs::read_dir(&d)
                .expect("list")
                .filter(|e| {
                    e.as_ref()
                        .is_ok_and(|e| e.file_name().to_string_lossy().contains(".tmp-"))
                })
                .count();
            assert_eq!(stray, 0, "steps {steps}");
            std::fs::remove_dir_all(&d).expect("clean");
        }
    }

    /// A symbolic link planted at a destination is replaced, its target untouched; names that
    /// are paths are refused before anything is written.
    #[cfg(unix)]
    #[test]
    fn planted_links_are_replaced_and_paths_refused() {
        let d = dir("links");
        let victim = d.join("victim");
        std::fs::write(&victim, "keep").expect("victim");
        std::os::unix::fs::symlink(&victim, d.join("out.csv")).expect("link");
        std::os::unix::fs::symlink(&victim, d.join(MANIFEST)).expect("link");
        write_set(&d, &[("out.csv", b"x")]).expect("write");
        assert_eq!(std::fs::read_to_string(&victim).expect("read"), "keep");
        assert!(
            std::fs::symlink_metadata(d.join("out.csv"))
                .expect("meta")
                .is_file()
        );
        for bad in ["", "..", "a/b", MANIFEST] {
            assert!(
                matches!(
                    write_set(&d, &[(bad, b"x")]),
                    Err(FilesError::BadName { .. })
                ),
                "{bad:?}"
            );
        }
        std::fs::remove_dir_all(&d).expect("clean");
    }
}
