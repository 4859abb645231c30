//! # nudge-predictor
//!
//! Interaction-aware trajectory prediction for the nudge planner, in pure Rust:
//!
//! * [`Teacher`]: a Social-GAN generator run recursively over the planning horizon, the ego's
//!   prediction replaced by the ego candidate at every step (6 generator calls);
//! * [`Student`]: the distilled network that reads the ego candidate and predicts the whole
//!   reaction in one pass (its history-only part is computed once per scene);
//! * [`ConstantVelocity`]: the interaction-unaware baseline.
//!
//! All three implement [`Predictor`]. Networks load from `.safetensors` files exported by the
//! PyTorch code in `python/train` (PyTorch `state_dict` names, float32, config JSON in the
//! metadata; see [`weights`]) or via [`load_predictor`], which picks the kind from the file.
//!
//! Numerics: the networks run in f32 with weights repacked at load time (spatial embeddings
//! folded into the LSTM input weights and the pooling's first layer, LSTM biases summed, the
//! pooling's first layer split into a per-agent term plus a per-pair 2-column product), while
//! positions stay in f64: only differences (displacements, offsets between agents) are rounded
//! to f32, and predicted positions accumulate in f64. On the golden cases
//! (`tests/golden`, a float64 evaluation of the PyTorch model rounded to float32) the largest
//! error is about 2e-6 m, the goldens' own float32 rounding; a literal f64 implementation (the
//! hidden `reference` module) tests the fast path. Results are bit-reproducible for a
//! given build (FMA is used only when the build targets it, e.g. `-C target-cpu=x86-64-v3`).
//!
//! Work that depends only on the history is cached per scene: the teacher's τ = 1 generator
//! call and the non-ego part of its τ = 2 call, the student's encoder, pooling, context and
//! first decoder step. `predict` allocates nothing; buffers grow in `set_scene` only.
//!
//! Conventions: metres in the road frame (x along travel, y lateral positive left), one step
//! = 0.3 s, [`T_OBS`] = 8 observed steps, agent 0 is the ego, 1..=[`MAX_AGENTS`] agents.
//!
//! Reliability: inputs beyond the ranges of [`limits`] (coordinates, per-step displacements,
//! distances between agents) are refused with a typed error stating the range; every
//! prediction is checked to be finite and physically plausible before it is returned; a
//! network is run on a canonical scene when it is loaded, so weights whose output is NaN or
//! absurd fail at load, naming the file; weights files carry a content hash that the loader
//! verifies; files are read only when regular and of bounded size ([`mod@file`]). Nothing in this
//! crate panics on any input (property-tested in `tests/reliability.rs`).

mod checked;
mod constant_velocity;
pub mod cost;
mod error;
pub mod file;
mod generator;
mod history;
pub mod json;
pub mod limits;
mod network;
mod nn;
mod recording;
#[doc(hidden)]
pub mod reference;
pub mod simd;
mod spec;
mod student;
mod teacher;
#[path = "weights.rs"]
mod weights_file;

/// Loading and validating network weights exported by `python/train` as `.safetensors`
/// (PyTorch `state_dict` names, float32, the JSON [`ModelConfig`] in the `"config"` metadata
/// entry); [`ModelWeights::from_file`] checks the config, then every tensor's presence,
/// dtype, shape and finiteness, naming the file and tensor of the first problem.
pub mod weights {
    /// Seeded random weights of a valid file (a test oracle).
    #[doc(hidden)]
    pub use crate::weights_file::synthetic_weights;
    pub use crate::weights_file::{
        ModelConfig, ModelKind, ModelWeights, Tensor, WEIGHTS_FORMAT, content_sha256,
        expected_tensors, restamp,
    };
}

pub use checked::Checked;
pub use constant_velocity::ConstantVelocity;
pub use cost::{MacCount, multiply_adds};
pub use error::{PredictorError, Quantity, Result};
pub use history::History;
pub use recording::{Recording, Records};
pub use simd::{SimdPath, best_simd_path, simd_path, supported_simd_paths};
pub use spec::{
    ASSETS_ENV, CHECKOUT_ASSETS, PredictorKind, PredictorSpec, UnknownPredictor, assets_dir,
    default_assets_dir, model_path, scenes_dir,
};
pub use student::Student;
pub use teacher::Teacher;
pub use weights::{ModelConfig, ModelKind, ModelWeights};

/// Loads a [`Teacher`] or a [`Student`] from a `.safetensors` weights file, whichever its
/// config's `kind` names (see [`PredictorSpec`] to build several from one read).
///
/// # Errors
/// Any loading error of [`ModelWeights::from_file`] (missing file, bad config, wrong tensor
/// shape or dtype, non-finite weight, content hash mismatch), naming the file and tensor;
/// [`PredictorError::SelfCheck`] when the network's predictions on the canonical scene are
/// non-finite or implausible.
///
/// # Examples
///
/// Predict how the other vehicles of a scene react to one ego candidate:
///
/// ```
/// use nudge_predictor::{History, T_OBS, load_predictor};
///
/// let weights = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
///     .join("../../assets/models/student.safetensors");
/// let mut student = load_predictor(&weights)?;
/// // Two vehicles driving at 10 m/s, 3.7 m apart, observed for T_OBS steps of 0.3 s.
/// let mut history = Vec::new();
/// for y in [0.0, 3.7] {
///     for t in 0..T_OBS {
///         history.extend([3.0 * t as f64, y]);
///     }
/// }
/// student.set_scene(&History::new(history, 2)?)?;
/// // One candidate [1, 6, 2] (m): the ego keeps its lane and speed.
/// let candidate: Vec<f64> = (1..=6).flat_map(|k| [21.0 + 3.0 * k as f64, 0.0]).collect();
/// let mut out = vec![0.0; 6 * 2]; // [1, n - 1, 6, 2]
/// student.predict(&candidate, &mut out)?;
/// assert!(out[10] > 21.0, "the other vehicle keeps moving forward");
/// # Ok::<(), nudge_predictor::PredictorError>(())
/// ```
pub fn load_predictor(path: impl AsRef<std::path::Path>) -> Result<Box<dyn Predictor>> {
    Ok(PredictorSpec::from_file(path)?.build())
}

/// Observed steps fed to every predictor (8 × 0.3 s = 2.4 s).
pub const T_OBS: usize = 8;
/// Most agents (ego included) one scene may hold.
pub const MAX_AGENTS: usize = 47;
/// Time step of the networks and the planner, seconds.
pub const DT: f64 = 0.3;
/// Largest prediction horizon (steps) any predictor accepts (18 s).
pub const MAX_HORIZON: usize = 60;
/// Most ego candidates one [`Predictor::predict`] call accepts: bounds the output a caller
/// allocates (at most 16,384 × 46 agents × 60 steps × 2 f64 = 724 MB; 72 MB at the shipped
/// 6 steps). The planner asks for one at a time.
pub const MAX_BATCH: usize = 1 << 14;

/// An interactive predictor: given a scene history and a batch of ego candidate trajectories,
/// predicts where every other agent goes under each candidate.
///
/// Usage is two-phase so that work depending only on the history is done once per planning
/// step: [`Predictor::set_scene`] once, then [`Predictor::predict`] for every batch of
/// candidates the optimiser proposes. Implementations keep their scratch buffers between calls
/// (no allocation per candidate), hence `&mut self`.
pub trait Predictor: Send {
    /// Short name for tables and benchmark ids (`"teacher"`, `"student"`, `"constant_velocity"`).
    fn name(&self) -> &'static str;

    /// Prediction horizon t_plan in steps (6 for the shipped models).
    fn horizon(&self) -> usize;

    /// Sets the scene whose other agents will be predicted; caches history-only work.
    ///
    /// # Errors
    /// Implementations may reject a history they cannot handle.
    fn set_scene(&mut self, history: &History) -> Result<()>;

    /// Predicts the other agents' positions for each ego candidate.
    ///
    /// * `candidates`: `[batch, horizon, 2]` row-major, the ego's future positions (metres) at
    ///   steps 1..=horizon after the last observed step.
    /// * `out`: `[batch, n_agents - 1, horizon, 2]` row-major, overwritten with the predicted
    ///   positions (metres) of agents 1..n_agents.
    ///
    /// # Errors
    /// [`PredictorError::NoScene`] before any [`Predictor::set_scene`];
    /// [`PredictorError::InputShape`] when `candidates` is not a whole number of
    /// `[horizon, 2]` trajectories or `out` has the wrong length;
    /// [`PredictorError::NonFiniteInput`] on NaN/inf in `candidates`;
    /// [`PredictorError::InputOutOfRange`] when a candidate leaves the accepted ranges of
    /// [`limits`] (coordinates, per-step displacement from the ego's last observed position);
    /// [`PredictorError::NonFiniteOutput`] / [`PredictorError::ImplausibleOutput`] when a
    /// prediction is non-finite or moves an agent more than [`limits::MAX_STEP`] in one step
    /// (`out` then holds unchecked values and must not be used).
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> Result<()>;
}

/// Validates a candidate batch and the matching output buffer; returns the batch size.
/// `ego_last` is the ego's last observed position (m), from which the first step of each
/// candidate is measured.
///
/// # Errors
/// [`PredictorError::Horizon`] for horizon 0 or above [`MAX_HORIZON`],
/// [`PredictorError::AgentCount`] for 0 agents or more than [`MAX_AGENTS`],
/// [`PredictorError::BatchTooLarge`] for more than [`MAX_BATCH`] candidates; otherwise the
/// input errors of [`Predictor::predict`].
pub fn check_batch(
    candidates: &[f64],
    out: &[f64],
    horizon: usize,
    n_agents: usize,
    ego_last: [f64; 2],
) -> Result<usize> {
    check_horizon(horizon)?;
    if n_agents == 0 || n_agents > MAX_AGENTS {
        return Err(PredictorError::AgentCount {
            got: n_agents,
            max: MAX_AGENTS,
        });
    }
    let per = horizon * 2;
    if candidates.is_empty() || !candidates.len().is_multiple_of(per) {
        return Err(PredictorError::InputShape {
            what: "candidates",
            shape: format!("[batch, {horizon}, 2]"),
            expected: per * (candidates.len() / per).max(1),
            got: candidates.len(),
        });
    }
    let batch = candidates.len() / per;
    check_batch_size(batch)?;
    history::check_finite("candidates", candidates)?;
    limits::check_candidates(candidates, horizon, ego_last)?;
    // batch * (n - 1) * horizon * 2 ≤ candidates.len() * MAX_AGENTS: cannot overflow.
    history::check_len("out", out, &[batch, n_agents - 1, horizon, 2])?;
    Ok(batch)
}

/// Checks a number of candidates for one [`Predictor::predict`] call.
///
/// # Errors
/// [`PredictorError::BatchTooLarge`] above [`MAX_BATCH`].
pub fn check_batch_size(batch: usize) -> Result<()> {
    if batch > MAX_BATCH {
        return Err(PredictorError::BatchTooLarge {
            got: batch,
            max: MAX_BATCH,
        });
    }
    Ok(())
}

/// Checks a prediction horizon (steps).
///
/// # Errors
/// [`PredictorError::Horizon`] unless `1 <= horizon <= MAX_HORIZON`.
pub fn check_horizon(horizon: usize) -> Result<()> {
    if horizon == 0 || horizon > MAX_HORIZON {
        return Err(PredictorError::Horizon {
            got: horizon,
            max: MAX_HORIZON,
        });
    }
    Ok(())
}
