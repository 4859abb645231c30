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
//! error is about 2e-6 m, the goldens' own float32 rounding; the [`reference`](mod@reference) module holds a
//! literal f64 implementation used to test the fast path. Results are bit-reproducible for a
//! given build (FMA is used only when the build targets it, e.g. `-C target-cpu=x86-64-v3`).
//!
//! Work that depends only on the history is cached per scene: the teacher's τ = 1 generator
//! call and the non-ego part of its τ = 2 call, the student's encoder, pooling, context and
//! first decoder step. `predict` allocates nothing; buffers grow in `set_scene` only.
//!
//! Conventions: metres in the road frame (x along travel, y lateral positive left), one step
//! = 0.3 s, [`T_OBS`] = 8 observed steps, agent 0 is the ego, 1..=[`MAX_AGENTS`] agents.

mod constant_velocity;
pub mod cost;
mod error;
mod generator;
mod history;
mod nn;
pub mod reference;
pub mod simd;
mod student;
mod teacher;
pub mod weights;

pub use constant_velocity::ConstantVelocity;
pub use cost::{MacCount, multiply_adds};
pub use error::{PredictorError, Result};
pub use history::History;
pub use simd::{SimdPath, best_simd_path, simd_path, supported_simd_paths};
pub use student::Student;
pub use teacher::Teacher;
pub use weights::{ModelConfig, ModelKind, ModelWeights};

/// Loads a [`Teacher`] or a [`Student`] from a `.safetensors` weights file, whichever its
/// config's `kind` names.
///
/// # Errors
/// Any loading error of [`ModelWeights::from_file`].
pub fn load_predictor(path: impl AsRef<std::path::Path>) -> Result<Box<dyn Predictor>> {
    let weights = ModelWeights::from_file(path)?;
    Ok(match weights.config().kind {
        ModelKind::Teacher => Box::new(Teacher::from_weights(&weights)?),
        ModelKind::Student => Box::new(Student::from_weights(&weights)?),
    })
}

/// Observed steps fed to every predictor (8 × 0.3 s = 2.4 s).
pub const T_OBS: usize = 8;
/// Most agents (ego included) one scene may hold.
pub const MAX_AGENTS: usize = 47;
/// Time step of the networks and the planner, seconds.
pub const DT: f64 = 0.3;

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
    /// [`PredictorError::NonFiniteInput`] on NaN/inf in `candidates`.
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> Result<()>;
}

/// Validates a candidate batch and the matching output buffer; returns the batch size.
///
/// # Errors
/// See [`Predictor::predict`].
pub fn check_batch(
    candidates: &[f64],
    out: &[f64],
    horizon: usize,
    n_agents: usize,
) -> Result<usize> {
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
    history::check_finite("candidates", candidates)?;
    history::check_len("out", out, &[batch, n_agents - 1, horizon, 2])?;
    Ok(batch)
}
