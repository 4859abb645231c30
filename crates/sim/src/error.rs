//! The typed errors of `nudge-sim`: closed-loop settings, world files and the simulation
//! itself, each variant naming the offending item.

use std::path::PathBuf;

use nudge_planner::{PlannerError, ScenarioError, SettingsError};
use nudge_predictor::PredictorError;

/// A [`crate::SimConfig`] field holds a value the simulator cannot work with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SimConfigError {
    /// A closed-loop settings file cannot be read (missing, not a regular file, too large, not
    /// UTF-8).
    #[error("cannot read closed-loop settings: {0}")]
    File(String),
    /// A numeric field lies outside its range in [`crate::SimConfig::FIELDS`].
    #[error(
        "invalid closed-loop setting `{field}` = {shown}: must be in {range}",
        shown = nudge_planner::settings::show(*.value)
    )]
    OutOfRange {
        /// Name of the field (as in the serde representation).
        field: &'static str,
        /// The value found.
        value: f64,
        /// Its admissible range.
        range: nudge_planner::settings::FieldRange,
    },
    /// The settings text does not parse.
    #[error("invalid closed-loop setting `{field}` = {value}: {reason}")]
    Invalid {
        /// Name of the field (as in the serde representation; `"<json>"` for a parse error).
        field: &'static str,
        /// The value found, formatted.
        value: String,
        /// What the value must satisfy.
        reason: &'static str,
    },
}

/// A world file (the `idm` world's "nudge.idm/1" parameters, [`crate::IdmPopulation`])
/// cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WorldFileError {
    /// The file could not be read.
    #[error("cannot read world file {path}: {source}")]
    Io {
        /// File that failed.
        path: PathBuf,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// Not a regular file (a FIFO, device, socket or directory): refused before opening.
    #[error("world file {path}: {kind}, not a regular file")]
    NotRegularFile {
        /// File that failed.
        path: PathBuf,
        /// What it is (`a FIFO`, `a character device`, ...).
        kind: &'static str,
    },
    /// Larger than [`crate::idm::MAX_WORLD_BYTES`]: refused before reading it all.
    #[error("world file {path}: {size} bytes, more than the {max}-byte budget")]
    TooLarge {
        /// File that failed.
        path: PathBuf,
        /// Its size (bytes; at least `max + 1`).
        size: u64,
        /// The budget (bytes).
        max: u64,
    },
    /// The text is not JSON.
    #[error("{path}: not JSON: {reason}")]
    NotJson {
        /// File that failed.
        path: PathBuf,
        /// What the JSON parser said.
        reason: String,
    },
    /// A field is missing or holds a value the world cannot use (schema, units, ranges).
    #[error("{path}: field `{field}`: {reason}")]
    Field {
        /// File that failed.
        path: PathBuf,
        /// The field, as a JSON path (`drivers[12][3]`, `intrusion.p_yield`).
        field: String,
        /// What is wrong with it.
        reason: String,
    },
}

/// A closed-loop simulation could not run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// The scenario offers no lane adjacent to the ego's that may be drawn as the target
    /// ([`crate::target_lane`]: one that exists, is open at the ego's x and does not end within
    /// [`crate::target_reach`]).
    #[error(
        "scenario {scene}: no lane adjacent to the ego's lane {ego_lane} that is open and runs on \
         (lanes: {lanes})"
    )]
    NoAdjacentLane {
        /// Scenario name.
        scene: String,
        /// The ego's lane index.
        ego_lane: usize,
        /// Number of lanes.
        lanes: usize,
    },
    /// The scenario cannot be turned into a planning problem.
    #[error("scenario {scene}: {source}")]
    Predictor {
        /// Scenario name.
        scene: String,
        /// The predictor's complaint (history shape, agent count...).
        source: PredictorError,
    },
    /// The planner failed in a way the simulator cannot recover from.
    #[error("scenario {scene}, step {step}: {source}")]
    Planner {
        /// Scenario name.
        scene: String,
        /// Closed-loop step (0-based).
        step: usize,
        /// The planner's error.
        source: PlannerError,
    },
    /// The planner settings do not validate.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// The closed-loop settings do not validate.
    #[error(transparent)]
    Config(#[from] SimConfigError),
    /// A predictor named for the planner or the world could not be loaded.
    #[error("{role}: {source}")]
    Model {
        /// `"predictor"` or `"world_predictor"`.
        role: &'static str,
        /// The loading error, naming the file.
        source: PredictorError,
    },
    /// The world file of an `idm` world cannot be used.
    #[error(transparent)]
    WorldFile(#[from] WorldFileError),
    /// The world model does not match the world: a `teacher` world needs a teacher, an `idm`
    /// world its driver population, a `log_replay` world neither.
    #[error("world {world}: {reason}")]
    WorldModel {
        /// The world's name.
        world: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The runs asked for cannot be laid out (no scene, no runs, wrong number of per-scene
    /// seeds, too many runs or threads, a seed that overflows).
    #[error("invalid argument `{field}`: {reason}")]
    Runs {
        /// The offending argument.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// A scenario of the batch cannot be read.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// A step of a [`crate::Session`] was asked of a run that has ended.
    #[error("scenario {scene}: the run ended after {steps} steps ({reason}); start a new one")]
    Ended {
        /// Scenario name.
        scene: String,
        /// Steps the run made.
        steps: usize,
        /// Why it ended ([`crate::EndReason::as_str`]).
        reason: &'static str,
    },
    /// A [`crate::Session`] was asked to advance with no plan made for the step.
    #[error("scenario {scene}, step {step}: no plan to apply (plan the step first)")]
    NoPlan {
        /// Scenario name.
        scene: String,
        /// Closed-loop step (0-based).
        step: usize,
    },
    /// The run was cancelled ([`crate::Cancel`]) before or during this closed-loop step (the
    /// step was not recorded).
    #[error("scenario {scene}: cancelled at step {step}")]
    Cancelled {
        /// Scenario name.
        scene: String,
        /// Closed-loop step (0-based) that did not finish.
        step: usize,
    },
}
