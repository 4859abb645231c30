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
}

/// Shorthand result type of this crate.
pub type Result<T> = std::result::Result<T, PredictorError>;
