//! The one error type of `nudge-predictor`.

use std::path::PathBuf;

/// Everything that can go wrong when loading weights or predicting.
///
/// Every variant names the offending item (file, tensor, agent, value) so the message alone is
/// enough to find the problem.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PredictorError {
    /// The weights file could not be read.
    #[error("cannot read weights file {path}: {source}")]
    Io {
        /// File that failed.
        path: PathBuf,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// The bytes are not a valid safetensors file (truncated, bad header, ...).
    #[error("{path}: not a valid safetensors file: {reason}")]
    NotSafetensors {
        /// File (or `<memory>`) that failed.
        path: PathBuf,
        /// What the safetensors parser said.
        reason: String,
    },
    /// The `config` metadata entry is missing or not valid JSON for a model config.
    #[error("{path}: bad model config metadata: {reason}")]
    BadConfig {
        /// File that failed.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// The config names a model kind this crate does not know.
    #[error("{path}: unknown model kind {kind:?} (expected \"teacher\" or \"student\")")]
    UnknownModelKind {
        /// File that failed.
        path: PathBuf,
        /// The kind found in the metadata.
        kind: String,
    },
    /// The file holds a valid network of the other kind (e.g. a student file given to
    /// `Teacher::from_file`).
    #[error("{path}: holds a {got} network, expected a {expected}")]
    WrongModelKind {
        /// File that failed.
        path: PathBuf,
        /// Kind the caller asked for.
        expected: &'static str,
        /// Kind found in the config.
        got: &'static str,
    },
    /// A tensor required by the config is absent.
    #[error("{path}: missing tensor {tensor:?}")]
    MissingTensor {
        /// File that failed.
        path: PathBuf,
        /// PyTorch state_dict name of the tensor.
        tensor: String,
    },
    /// The file holds a tensor the config does not call for.
    #[error("{path}: unexpected tensor {tensor:?} (not part of a {kind} with this config)")]
    UnexpectedTensor {
        /// File that failed.
        path: PathBuf,
        /// PyTorch state_dict name of the tensor.
        tensor: String,
        /// Model kind.
        kind: String,
    },
    /// A tensor has the wrong shape.
    #[error("{path}: tensor {tensor:?} has shape {got:?}, expected {expected:?}")]
    ShapeMismatch {
        /// File that failed.
        path: PathBuf,
        /// PyTorch state_dict name of the tensor.
        tensor: String,
        /// Shape implied by the config.
        expected: Vec<usize>,
        /// Shape found in the file.
        got: Vec<usize>,
    },
    /// A tensor has a dtype other than float32.
    #[error("{path}: tensor {tensor:?} has dtype {got}, expected F32")]
    WrongDtype {
        /// File that failed.
        path: PathBuf,
        /// PyTorch state_dict name of the tensor.
        tensor: String,
        /// The dtype found.
        got: String,
    },
    /// A weight is NaN or infinite.
    #[error("{path}: tensor {tensor:?} holds a non-finite value at flat index {index}")]
    NonFiniteWeight {
        /// File that failed.
        path: PathBuf,
        /// PyTorch state_dict name of the tensor.
        tensor: String,
        /// Flat (row-major) index of the first bad element.
        index: usize,
    },
    /// A scene holds no agent, or more than the supported maximum.
    #[error("scene has {got} agents; supported range is 1..={max}")]
    AgentCount {
        /// Agents supplied.
        got: usize,
        /// Maximum supported.
        max: usize,
    },
    /// More candidates in one `predict` call than [`crate::MAX_BATCH`].
    #[error("candidates: {got} candidates in one call; at most {max} are accepted")]
    BatchTooLarge {
        /// Candidates supplied.
        got: usize,
        /// The bound.
        max: usize,
    },
    /// An input buffer has the wrong length for the declared shape.
    #[error("{what}: expected {expected} values (shape {shape}), got {got}")]
    InputShape {
        /// Which input (history, candidates, output, noise).
        what: &'static str,
        /// Human-readable shape, e.g. `[3, 8, 2]`.
        shape: String,
        /// Expected element count.
        expected: usize,
        /// Supplied element count.
        got: usize,
    },
    /// An input holds NaN or infinity.
    #[error("{what}: non-finite value {value} at flat index {index}")]
    NonFiniteInput {
        /// Which input (history, candidates, noise).
        what: &'static str,
        /// Flat (row-major) index of the first bad element.
        index: usize,
        /// The value found.
        value: f64,
    },
    /// A vector instruction-set path was requested that is unknown or that this CPU lacks
    /// (`NUDGE_SIMD` or `set_simd_path`).
    #[error("SIMD path {requested:?}: {reason}")]
    SimdPath {
        /// The path as requested.
        requested: String,
        /// Why it cannot be used.
        reason: &'static str,
    },
    /// `predict` was called before any scene was set.
    #[error("no scene set: call set_scene before predict")]
    NoScene,
    /// An input value is finite but outside the range the networks represent faithfully
    /// (see [`crate::limits`] for each range and the measurement behind it).
    #[error(
        "{what}: {location}: {quantity} {shown} {unit} is outside the accepted range \
         (at most {max} {unit}; see nudge_predictor::limits)",
        shown = Num(*.value),
        unit = .quantity.unit()
    )]
    InputOutOfRange {
        /// Which input (history, candidates, noise).
        what: &'static str,
        /// Which quantity is too large.
        quantity: Quantity,
        /// Where: agent and observed step, candidate and step, or the pair of agents.
        location: String,
        /// The magnitude found.
        value: f64,
        /// The largest accepted magnitude.
        max: f64,
    },
    /// A prediction horizon outside `1..=MAX_HORIZON`.
    #[error("horizon {got} steps is outside the supported range 1..={max}")]
    Horizon {
        /// Horizon asked for (steps).
        got: usize,
        /// Largest supported horizon ([`crate::MAX_HORIZON`]).
        max: usize,
    },
    /// A model asked for a horizon its network cannot predict: the student decodes a fixed
    /// number of steps in one pass, so it can serve no other horizon (never truncated or padded).
    #[error("the {predictor} predicts exactly {predicts} steps; horizon {got} steps was asked for")]
    FixedHorizon {
        /// Predictor name (`"student"`).
        predictor: &'static str,
        /// Horizon asked for (steps).
        got: usize,
        /// The only horizon the network predicts (steps, its file's `t_plan`).
        predicts: usize,
    },
    /// The network predicted NaN or infinity: its output cannot be used (never "safe").
    #[error(
        "{predictor} predicted a non-finite position ({value}) for agent {agent} at step \
         {step} (candidate {candidate})"
    )]
    NonFiniteOutput {
        /// Predictor name (`"teacher"`, `"student"`, `"constant_velocity"`).
        predictor: &'static str,
        /// Candidate index in the batch (0-based).
        candidate: usize,
        /// Agent index in the scene (1..n; 0 is the ego).
        agent: usize,
        /// Predicted step (1..=horizon).
        step: usize,
        /// The non-finite coordinate.
        value: f64,
    },
    /// The network predicted a finite but physically impossible motion.
    #[error(
        "{predictor} predicted an implausible motion for agent {agent} at step {step} \
         (candidate {candidate}): {shown} m in one 0.3 s step, more than the {max} m \
         any road vehicle covers",
        shown = Num(*.displacement)
    )]
    ImplausibleOutput {
        /// Predictor name.
        predictor: &'static str,
        /// Candidate index in the batch (0-based).
        candidate: usize,
        /// Agent index in the scene (1..n).
        agent: usize,
        /// Predicted step (1..=horizon).
        step: usize,
        /// Distance moved in that step (m).
        displacement: f64,
        /// The plausibility bound ([`crate::limits::MAX_STEP`], m).
        max: f64,
    },
    /// A predictor implemented outside nudge (a Python object given to the bindings) failed:
    /// raised an exception, lacks a method, or returned a prediction of the wrong type or
    /// shape. `source` is its own error, kept whole so that the caller can hand it back (the
    /// Python bindings re-raise the original exception as the cause).
    #[error("{predictor} predictor: {source}")]
    Foreign {
        /// Predictor name (`"python"` for a Python object).
        predictor: &'static str,
        /// What went wrong, naming the method and the item.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The network failed its load-time self-check on the canonical scene (non-finite or
    /// implausible predictions): the weights load but cannot be used.
    #[error("{path}: the load-time self-check on the canonical highway scene failed: {source}")]
    SelfCheck {
        /// File whose network failed.
        path: PathBuf,
        /// What the prediction on the canonical scene gave.
        source: Box<PredictorError>,
    },
    /// The path is not a regular file (FIFO, device, directory, socket): refused before
    /// reading, since reading could block forever or never end.
    #[error("{path}: not a regular file ({kind}); refusing to read it")]
    NotRegularFile {
        /// The path.
        path: PathBuf,
        /// What it is instead.
        kind: &'static str,
    },
    /// The file is larger than the bound for its kind: refused before reading.
    #[error(
        "{path}: {size} bytes is larger than the {max}-byte limit for this kind of file; refusing to read it"
    )]
    FileTooLarge {
        /// The path.
        path: PathBuf,
        /// Its size (bytes).
        size: u64,
        /// The bound (bytes).
        max: u64,
    },
    /// The weights file carries no content hash, so its integrity cannot be checked.
    #[error(
        "{path}: no \"sha256\" metadata entry, so the weights' integrity cannot be checked \
         (export or re-stamp the file with python/train's nudge_train.export)"
    )]
    MissingHash {
        /// File that failed.
        path: PathBuf,
    },
    /// The content hash in the metadata does not match the tensors and config.
    #[error(
        "{path}: content sha256 mismatch: the metadata says {expected}, the tensors and config \
         hash to {found} (the file was corrupted or edited after export)"
    )]
    HashMismatch {
        /// File that failed.
        path: PathBuf,
        /// The hash stored in the `"sha256"` metadata entry.
        expected: String,
        /// The hash of the file's content.
        found: String,
    },
}

/// The quantity an [`PredictorError::InputOutOfRange`] refers to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Quantity {
    /// A position coordinate |x| or |y| (m).
    Coordinate,
    /// The distance one agent moves in one 0.3 s step (m).
    StepDisplacement,
    /// The distance between two agents at the last observed step (m).
    AgentOffset,
    /// A component of the generator's noise vector (standard-normal units).
    Noise,
}

impl Quantity {
    /// Unit of the quantity, for messages.
    #[must_use]
    pub fn unit(self) -> &'static str {
        match self {
            Self::Noise => "(standard deviations)",
            _ => "m",
        }
    }
}

impl std::fmt::Display for Quantity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Coordinate => "coordinate",
            Self::StepDisplacement => "displacement in one step",
            Self::AgentOffset => "distance between agents",
            Self::Noise => "noise value",
        })
    }
}

/// A number for messages: plain for ordinary magnitudes, scientific for huge or tiny ones.
struct Num(f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.0.abs();
        if a != 0.0 && !(1e-3..1e6).contains(&a) {
            write!(f, "{:.3e}", self.0)
        } else {
            write!(f, "{}", (self.0 * 1e3).round() / 1e3)
        }
    }
}

/// Shorthand result type of this crate.
pub type Result<T> = std::result::Result<T, PredictorError>;
