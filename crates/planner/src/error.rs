//! The typed errors of `nudge-planner`: one enum per concern (settings, scenario files,
//! planning), each variant naming the offending item.

use std::path::PathBuf;

use nudge_predictor::PredictorError;

use crate::qp::{QpFailure, QpName, QpStatus};

/// A [`crate::PlannerSettings`] field holds a value the planner cannot work with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SettingsError {
    /// A numeric field lies outside its documented range ([`crate::settings::FieldSpec`]).
    #[error(
        "invalid planner setting `{field}` = {shown}: must be in {range}",
        shown = crate::settings::schema::show(*.value)
    )]
    OutOfRange {
        /// Dotted name of the field (as in JSON).
        field: &'static str,
        /// The value found.
        value: f64,
        /// Its admissible range.
        range: crate::settings::schema::FieldRange,
    },
    /// A key of the flat settings of earlier versions that moved into a group.
    #[error("planner setting `{key}` moved: it is now `{to}` (settings are grouped by phase)")]
    Moved {
        /// The old key.
        key: &'static str,
        /// Its dotted path now.
        to: &'static str,
    },
    /// A key of earlier versions that was removed.
    #[error("planner setting `{key}` was removed ({why})")]
    Removed {
        /// The old key.
        key: &'static str,
        /// Why, and where its evidence lives.
        why: &'static str,
    },
    /// A settings file cannot be read (missing, not a regular file, too large, not UTF-8).
    #[error("cannot read planner settings: {0}")]
    File(String),
    /// The settings are valid on their own but do not fit the predictors or the scenes they
    /// are used with (see [`crate::fit`]).
    #[error("planner setting `{field}` = {value} does not fit: {reason}")]
    Incompatible {
        /// Name of the field (`"horizon"` or `"dt"`).
        field: &'static str,
        /// The value found.
        value: f64,
        /// What it must match, and why.
        reason: String,
    },
    /// One field is out of its admissible range.
    #[error("invalid planner setting `{field}` = {value}: {reason}")]
    Invalid {
        /// Name of the field (as in the serde representation).
        field: &'static str,
        /// The value found, formatted.
        value: String,
        /// What the value must satisfy.
        reason: &'static str,
    },
}

/// A scenario file ("nudge.scenario/1" or "nudge.scenario/2") cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("cannot read scenario file {path}: {source}")]
    Io {
        /// File that failed.
        path: PathBuf,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// The bytes are not a valid safetensors file.
    #[error("{path}: not a valid safetensors file: {reason}")]
    NotSafetensors {
        /// File (or `<memory>`) that failed.
        path: PathBuf,
        /// What the safetensors parser said.
        reason: String,
    },
    /// The metadata has no "schema" entry or names another schema.
    #[error("{path}: schema is {found:?}, expected \"nudge.scenario/1\" or \"nudge.scenario/2\"")]
    WrongSchema {
        /// File that failed.
        path: PathBuf,
        /// The schema string found (`None` when absent).
        found: Option<String>,
    },
    /// A metadata entry is missing or cannot be parsed.
    #[error("{path}: bad metadata {key:?}: {reason}")]
    BadMetadata {
        /// File that failed.
        path: PathBuf,
        /// Metadata key.
        key: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A required tensor is absent.
    #[error("{path}: missing tensor {tensor:?}")]
    MissingTensor {
        /// File that failed.
        path: PathBuf,
        /// Tensor name.
        tensor: &'static str,
    },
    /// A tensor has the wrong dtype.
    #[error("{path}: tensor {tensor:?} has dtype {got}, expected {expected}")]
    WrongDtype {
        /// File that failed.
        path: PathBuf,
        /// Tensor name.
        tensor: &'static str,
        /// Dtype required by the schema.
        expected: &'static str,
        /// Dtype found.
        got: String,
    },
    /// A tensor has the wrong shape.
    #[error("{path}: tensor {tensor:?} has shape {got:?}, expected {expected}")]
    WrongShape {
        /// File that failed.
        path: PathBuf,
        /// Tensor name.
        tensor: &'static str,
        /// Shape required by the schema, human readable.
        expected: String,
        /// Shape found.
        got: Vec<usize>,
    },
    /// A tensor holds NaN or infinity.
    #[error("{path}: tensor {tensor:?} holds non-finite value {value} at flat index {index}")]
    NonFinite {
        /// File that failed.
        path: PathBuf,
        /// Tensor name.
        tensor: &'static str,
        /// Flat (row-major) index of the first bad element.
        index: usize,
        /// The value found.
        value: f64,
    },
    /// A value is finite but impossible (non-positive size, unordered lanes, bad lane index...).
    #[error("{path}: tensor {tensor:?}: {reason}")]
    BadValue {
        /// File that failed.
        path: PathBuf,
        /// Tensor name.
        tensor: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The path is not a regular file (FIFO, device, directory): refused before reading.
    #[error("{path}: not a regular file ({kind}); refusing to read it")]
    NotRegularFile {
        /// The path.
        path: PathBuf,
        /// What it is instead.
        kind: &'static str,
    },
    /// The file is larger than [`crate::scenario::MAX_SCENARIO_BYTES`]: refused before reading.
    #[error(
        "{path}: {size} bytes is larger than the {max}-byte limit for scenario files; refusing to read it"
    )]
    FileTooLarge {
        /// The path.
        path: PathBuf,
        /// Its size (bytes).
        size: u64,
        /// The bound (bytes).
        max: u64,
    },
    /// A value of one agent is finite but physically implausible (off the road, absurd
    /// heading, speed, size or motion; see [`crate::scenario`] for every range).
    #[error("{path}: agent {agent} (source id {id}): {field} {detail}")]
    Implausible {
        /// File that failed.
        path: PathBuf,
        /// Agent index in the scenario (0 = ego).
        agent: usize,
        /// Its source vehicle id.
        id: i64,
        /// The field (tensor) holding the value.
        field: &'static str,
        /// The value and the range it violates.
        detail: String,
    },
    /// `ego_lane` names a lane the ego is not in.
    #[error(
        "{path}: ego_lane {ego_lane} spans y in [{lo}, {hi}] m but agent 0 (the ego) is at \
         y = {y} m at the last observed step (tolerance {tolerance} m)"
    )]
    EgoLane {
        /// File that failed.
        path: PathBuf,
        /// The lane index in the file.
        ego_lane: usize,
        /// The ego's lateral position (m).
        y: f64,
        /// The lane's right boundary (m).
        lo: f64,
        /// The lane's left boundary (m).
        hi: f64,
        /// The accepted distance outside the lane (m).
        tolerance: f64,
    },
    /// The ego's bounding box already overlaps another vehicle's at the last observed step.
    #[error("{path}: ego overlaps agent {agent} (source id {id}) at the last observed step")]
    EgoOverlap {
        /// File that failed.
        path: PathBuf,
        /// Index of the overlapped agent in the scenario (1..n).
        agent: usize,
        /// Its source vehicle id.
        id: i64,
    },
}

/// One MPC call failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlannerError {
    /// The settings do not validate.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// The predictor failed (bad scene, bad candidate, ...).
    #[error("predictor failed: {0}")]
    Predictor(#[from] PredictorError),
    /// The predictor's horizon differs from the planner's.
    #[error("predictor horizon {predictor} differs from the planner horizon {planner}")]
    HorizonMismatch {
        /// Predictor horizon (steps).
        predictor: usize,
        /// `PlannerSettings::horizon`.
        planner: usize,
    },
    /// The planning problem handed to the planner is malformed.
    #[error("bad planning problem: {field}: {reason}")]
    BadProblem {
        /// The offending field.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The lane layout of the planning problem ([`crate::PlanningProblem::lanes`]) is
    /// malformed.
    #[error("bad planning problem: lane {lane} {field}: {reason}")]
    BadLane {
        /// Index of the offending lane.
        lane: usize,
        /// The offending field of it (`bounds`, `begin`, `end`).
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// Clarabel could not set up the joint reference QP ([`crate::Planner::reference_qp`];
    /// inside [`crate::Planner::plan`] a QP failure ends in status
    /// [`crate::PlanStatus::SolverFailed`] instead).
    #[error("Clarabel setup of the {qp} QP failed: {reason}")]
    QpSetup {
        /// Which QP.
        qp: QpName,
        /// Clarabel's message.
        reason: String,
    },
    /// Clarabel returned a status other than Solved/AlmostSolved on the joint reference QP,
    /// also after the equilibration-off retry.
    #[error("Clarabel failed on the {qp} QP at ADMM iteration {iteration}: status {status:?}")]
    QpFailed {
        /// Which QP.
        qp: QpName,
        /// ADMM iteration (0-based) at which it failed (0 for the joint QP).
        iteration: usize,
        /// Clarabel's status.
        status: QpStatus,
    },
    /// The call was cancelled ([`crate::Cancel`], [`crate::Planner::set_cancel`]) and ended
    /// within one predictor call, without a plan.
    #[error("planning cancelled")]
    Cancelled,
    /// A planner implemented outside nudge (a closed-loop policy such as a Python object)
    /// failed or returned a plan that cannot be used; `source` says what happened.
    #[error("{policy} failed: {source}")]
    Foreign {
        /// Which planner (e.g. `"Python planner MyPlanner"`).
        policy: String,
        /// What went wrong.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

impl From<QpFailure> for PlannerError {
    fn from(f: QpFailure) -> Self {
        match f.detail {
            Some(reason) if f.status == QpStatus::Setup => Self::QpSetup { qp: f.qp, reason },
            _ => Self::QpFailed {
                qp: f.qp,
                iteration: f.iteration,
                status: f.status,
            },
        }
    }
}
