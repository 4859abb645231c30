//! `provenance.json`: what made a folder of records — the nudge version and git commit, the
//! command line, the planner settings and `SimConfig` in force, every file the runs read
//! (scenes, models, the world file) with its sha256, the seeds, the machine and the threads.
//! Written beside the records by `nudge simulate --out` (schema in `docs/records.md`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nudge_planner::PlannerSettings;
use nudge_predictor::{PredictorKind, model_path};
use nudge_sim::{RunSpec, SimConfig, World, idm_path};
use serde::Serialize;
use sha2::{Digest, Sha256};

/// The schema tag of a `provenance.json`.
pub const SCHEMA: &str = "nudge.provenance/1";

/// The file name of the provenance record in an output folder.
pub const FILE_NAME: &str = "provenance.json";

/// The git commit this nudge was built from (`build.rs`: `$NUDGE_GIT_SHA`, else
/// `git rev-parse HEAD` of the checkout), `"unknown"` when built outside a git checkout.
pub const GIT_SHA: &str = env!("NUDGE_GIT_SHA");

/// This nudge's version (the workspace version).
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// Hex sha256 of `bytes`.
#[must_use]
pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    let mut s = String::with_capacity(64);
    for b in digest {
        let _ = write!(s, "{b:02x}");
    }
    s
}

/// A file the runs read: its path as given and the sha256 of its bytes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct FileRef {
    /// The path as the run named it.
    pub path: PathBuf,
    /// Hex sha256 of the file's bytes.
    pub sha256: String,
}

impl FileRef {
    /// Reads and hashes `path`.
    ///
    /// # Errors
    /// The path and the I/O error when the file cannot be read.
    pub fn of(path: &Path) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            sha256: sha256_hex(&bytes),
        })
    }
}

/// A predictor of the runs: its name or path as given, and its weights file (none for
/// constant velocity).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ModelRef {
    /// As given: `teacher`, `student`, `constant_velocity` or a weights path.
    pub name: String,
    /// The weights file it resolved to, with its sha256; `None` for constant velocity.
    pub file: Option<FileRef>,
}

impl ModelRef {
    /// Resolves `name_or_path` as [`nudge_predictor::PredictorSpec::resolve`] does (named
    /// models under `assets`) and hashes its weights file.
    ///
    /// # Errors
    /// When the weights file cannot be read.
    pub fn resolve(name_or_path: &Path, assets: &Path) -> Result<Self, String> {
        let name = name_or_path.to_string_lossy().into_owned();
        let file = match name.parse::<PredictorKind>() {
            Ok(kind) => kind.model().map(|m| model_path(assets, m)),
            Err(_) => Some(name_or_path.to_path_buf()),
        };
        Ok(Self {
            name,
            file: file.as_deref().map(FileRef::of).transpose()?,
        })
    }
}

/// The world that moved the other vehicles and the file it read (the teacher's weights, the
/// IDM driver population; none for log replay).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct WorldRef {
    /// `teacher`, `idm` or `log_replay`.
    pub world: World,
    /// The teacher world's model (`None` for the other worlds).
    pub model: Option<ModelRef>,
    /// The idm world's driver population file (`None` for the other worlds).
    pub file: Option<FileRef>,
}

/// The scenes of the runs, in run order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ScenesRef {
    /// Number of scenes.
    pub count: usize,
    /// Hex sha256 of the scene list: one line `<file name> <sha256 of the file>\n` per
    /// scene, in run order (the same scenes in the same order give the same hash wherever
    /// they lie).
    pub list_sha256: String,
    /// Every scene file with its sha256, in run order.
    pub files: Vec<FileRef>,
}

impl ScenesRef {
    /// Hashes every file of `paths`.
    ///
    /// # Errors
    /// When a file cannot be read.
    pub fn of(paths: &[PathBuf]) -> Result<Self, String> {
        let files = paths
            .iter()
            .map(|p| FileRef::of(p))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            count: files.len(),
            list_sha256: scene_list_sha256(&files),
            files,
        })
    }
}

/// The sha256 of a scene list ([`ScenesRef::list_sha256`]).
#[must_use]
pub fn scene_list_sha256(files: &[FileRef]) -> String {
    let mut text = String::new();
    for f in files {
        let name = f
            .path
            .file_name()
            .map_or_else(|| f.path.to_string_lossy(), |n| n.to_string_lossy());
        let _ = writeln!(text, "{name} {}", f.sha256);
    }
    sha256_hex(text.as_bytes())
}

/// The seeds of the runs.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Seeds {
    /// The base seed (`--seed`).
    pub base: u64,
    /// Runs per scene (`--runs`).
    pub runs_per_scene: usize,
    /// Every run's target-lane seed, in run order.
    pub runs: Vec<u64>,
}

impl Seeds {
    /// The seeds of `specs` from `base` with `runs_per_scene`.
    #[must_use]
    pub fn of(base: u64, runs_per_scene: usize, specs: &[RunSpec]) -> Self {
        Self {
            base,
            runs_per_scene,
            runs: specs.iter().map(|s| s.seed).collect(),
        }
    }
}

/// The machine the runs ran on.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Machine {
    /// Host name (`"unknown"` when it cannot be read).
    pub hostname: String,
    /// Operating system (`std::env::consts::OS`).
    pub os: String,
    /// CPU architecture (`std::env::consts::ARCH`).
    pub arch: String,
    /// CPU model (`/proc/cpuinfo` on Linux; `"unknown"` elsewhere).
    pub cpu: String,
    /// Logical cores available to the process.
    pub cores: usize,
}

impl Machine {
    /// This machine.
    #[must_use]
    pub fn this() -> Self {
        let read = |p: &str| std::fs::read_to_string(p).ok();
        let hostname = std::env::var("HOSTNAME")
            .ok()
            .filter(|h| !h.is_empty())
            .or_else(|| read("/proc/sys/kernel/hostname"))
            .or_else(|| read("/etc/hostname"))
            .map(|h| h.trim().to_string())
            .filter(|h| !h.is_empty())
            .unwrap_or_else(|| "unknown".into());
        let cpu = read("/proc/cpuinfo")
            .and_then(|text| {
                text.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split_once(':'))
                    .map(|(_, v)| v.trim().to_string())
            })
            .unwrap_or_else(|| "unknown".into());
        Self {
            hostname,
            os: std::env::consts::OS.into(),
            arch: std::env::consts::ARCH.into(),
            cpu,
            cores: std::thread::available_parallelism().map_or(1, usize::from),
        }
    }
}

/// Everything `provenance.json` holds (its schema: `docs/records.md`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Provenance {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// [`VERSION`].
    pub nudge_version: &'static str,
    /// [`GIT_SHA`].
    pub git_sha: &'static str,
    /// When the records were written: seconds since the Unix epoch (UTC).
    pub created_unix_s: u64,
    /// The command line, program name first.
    pub command: Vec<String>,
    /// The working directory the command ran in (relative paths above are relative to it).
    pub cwd: PathBuf,
    /// The planner settings in force (after `--settings` and the flags).
    pub settings: PlannerSettings,
    /// The `--settings` file with its sha256 (`None`: the defaults).
    pub settings_file: Option<FileRef>,
    /// The closed-loop settings in force (after `--config` and the flags).
    pub sim_config: SimConfig,
    /// The `--config` file with its sha256 (`None`: the defaults).
    pub config_file: Option<FileRef>,
    /// The assets directory the named models and the default world file resolved under.
    pub assets: PathBuf,
    /// The planning predictor.
    pub predictor: ModelRef,
    /// The planner that drove the ego when it was not nudge's own: a planner from outside nudge
    /// (Python's `nudge.simulate(..., planner=obj)`: `python:<class>`); `None`: nudge's planner.
    pub planner: Option<String>,
    /// The world and its file.
    pub world: WorldRef,
    /// The scenes.
    pub scenes: ScenesRef,
    /// The seeds.
    pub seeds: Seeds,
    /// Worker threads of the runs.
    pub threads: usize,
    /// The machine.
    pub machine: Machine,
}

/// What a run of `nudge simulate` resolved, to record.
#[derive(Debug, Clone, Copy)]
pub struct Inputs<'a> {
    /// The planner settings in force and the file they came from.
    pub settings: (&'a PlannerSettings, Option<&'a Path>),
    /// The closed-loop settings in force and the file they came from.
    pub config: (&'a SimConfig, Option<&'a Path>),
    /// The assets directory.
    pub assets: &'a Path,
    /// The planning predictor as given.
    pub predictor: &'a Path,
    /// The teacher world's model as given (`None`: the default teacher).
    pub world_predictor: Option<&'a Path>,
    /// The idm world's file as given (`None`: the default under the assets).
    pub idm: Option<&'a Path>,
    /// The scene files, in run order.
    pub scene_paths: &'a [PathBuf],
    /// The runs.
    pub specs: &'a [RunSpec],
    /// The base seed and runs per scene.
    pub seed: (u64, usize),
    /// Worker threads.
    pub threads: usize,
}

impl Provenance {
    /// The provenance of runs with `inputs`, started by `command` (program name first).
    ///
    /// # Errors
    /// When a file the runs read cannot be read again to be hashed.
    pub fn new(inputs: &Inputs<'_>, command: Vec<String>) -> Result<Self, String> {
        let (settings, settings_file) = inputs.settings;
        let (config, config_file) = inputs.config;
        let world = match config.world {
            World::Teacher => WorldRef {
                world: World::Teacher,
                model: Some(ModelRef::resolve(
                    inputs
                        .world_predictor
                        .unwrap_or(Path::new(nudge_sim::defaults::WORLD_PREDICTOR.as_str())),
                    inputs.assets,
                )?),
                file: None,
            },
            World::Idm => WorldRef {
                world: World::Idm,
                model: None,
                file: Some(FileRef::of(
                    &inputs
                        .idm
                        .map_or_else(|| idm_path(inputs.assets), Path::to_path_buf),
                )?),
            },
            other => WorldRef {
                world: other,
                model: None,
                file: None,
            },
        };
        Ok(Self {
            schema: SCHEMA,
            nudge_version: VERSION,
            git_sha: GIT_SHA,
            created_unix_s: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
            command,
            cwd: std::env::current_dir().unwrap_or_default(),
            settings: settings.clone(),
            settings_file: settings_file.map(FileRef::of).transpose()?,
            sim_config: *config,
            config_file: config_file.map(FileRef::of).transpose()?,
            assets: inputs.assets.to_path_buf(),
            predictor: ModelRef::resolve(inputs.predictor, inputs.assets)?,
            planner: None,
            world,
            scenes: ScenesRef::of(inputs.scene_paths)?,
            seeds: Seeds::of(inputs.seed.0, inputs.seed.1, inputs.specs),
            threads: inputs.threads,
            machine: Machine::this(),
        })
    }

    /// The text of `provenance.json` ([`FILE_NAME`]), written with the records as one set
    /// ([`crate::files::write_set`]).
    ///
    /// # Errors
    /// The serialiser's message.
    pub fn to_json(&self) -> Result<String, String> {
        serde_json::to_string_pretty(self)
            .map(|json| json + "\n")
            .map_err(|e| e.to_string())
    }

    /// `provenance.json` as a file of an output set: ([`FILE_NAME`], its text), for
    /// [`crate::records::write_records`].
    ///
    /// # Errors
    /// The serialiser's message.
    pub fn file(&self) -> Result<(String, Vec<u8>), String> {
        Ok((FILE_NAME.to_string(), self.to_json()?.into_bytes()))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn sha256_matches_the_standard_test_vector() {
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn the_scene_list_hash_depends_on_names_contents_and_order_not_folders() {
        let f = |path: &str, sha: &str| FileRef {
            path: PathBuf::from(path),
            sha256: sha.into(),
        };
        let a = [f("/x/a.safetensors", "11"), f("/x/b.safetensors", "22")];
        let moved = [f("/y/a.safetensors", "11"), f("/y/b.safetensors", "22")];
        let swapped = [f("/x/b.safetensors", "22"), f("/x/a.safetensors", "11")];
        let changed = [f("/x/a.safetensors", "11"), f("/x/b.safetensors", "23")];
        assert_eq!(scene_list_sha256(&a), scene_list_sha256(&moved));
        assert_ne!(scene_list_sha256(&a), scene_list_sha256(&swapped));
        assert_ne!(scene_list_sha256(&a), scene_list_sha256(&changed));
        assert_eq!(
            scene_list_sha256(&a),
            sha256_hex(b"a.safetensors 11\nb.safetensors 22\n")
        );
    }

    #[test]
    fn the_git_sha_is_a_commit_or_unknown() {
        assert!(
            GIT_SHA == "unknown"
                || (GIT_SHA.len() == 40 && GIT_SHA.chars().all(|c| c.is_ascii_hexdigit())),
            "{GIT_SHA}"
        );
    }
}
