//! The teacher φ_T: a large Social-GAN generator run recursively over the planning horizon.

use std::path::Path;

use crate::error::{PredictorError, Result};
use crate::generator::{Generator, Scratch};
use crate::history::check_finite;
use crate::simd::{Isa, SimdPath, simd_path};
use crate::weights::{ModelConfig, ModelKind, ModelWeights};
use crate::{History, Predictor, T_OBS, check_batch, check_horizon, limits};

/// The teacher predictor (Social-GAN generator, one step per call, `t_plan` calls).
///
/// For τ = 1..=t_plan the whole generator runs on the last [`T_OBS`] positions of every
/// agent and predicts one step; the others' predictions are kept, the ego's is replaced by the
/// candidate's position at τ, and the window slides by one step. The τ = 1 call depends only
/// on the history and is computed once in [`Predictor::set_scene`]; so is most of the τ = 2
/// call: the non-ego agents' τ = 2 windows (history plus their τ = 1 predictions) do not
/// depend on the candidate, hence neither do their encodings nor their pooling pairs among
/// themselves. Per candidate only the ego's encoding and pairs are added at τ = 2, followed by
/// `t_plan - 2` full generator calls. All of this is exact (the max over agents is
/// associative); the tests compare with the uncached [`reference`](mod@crate::reference).
///
/// The noise `z` (`[noise_dim]`, the same for every agent: "global" noise) defaults to the
/// file's `fixed_noise`.
///
/// The kernels run on the instruction-set path [`simd_path`](crate::simd_path) chose at load
/// time; see [`Teacher::set_simd_path`].
#[derive(Debug, Clone)]
pub struct Teacher {
    generator: Generator,
    /// `[noise_dim]`.
    noise: Vec<f32>,
    s: Scratch,
    /// Agents of the current scene (0: no scene yet).
    n: usize,
    /// `[n, T_OBS, 2]` scene history (metres).
    win0: Vec<f64>,
    /// `[n, 2]` last observed positions (metres).
    last: Vec<f64>,
    /// `[n, 2]` candidate-independent τ = 1 prediction (entry 0 unused).
    q1: Vec<f64>,
    /// Working window `[n, T_OBS, 2]` and one-step prediction `[n, 2]` (metres).
    win: Vec<f64>,
    q: Vec<f64>,
    /// τ = 2 cache: encodings `[n, He]` and pool terms `[n, term_stride]` (slot 0, the ego's, is
    /// rewritten per candidate), running maxima over agents 1..n `[n, acc_len]`.
    h_enc2: Vec<f32>,
    terms2: Vec<f32>,
    max2: Vec<f32>,
}

impl Teacher {
    /// Loads a teacher from a `.safetensors` weights file.
    ///
    /// # Errors
    /// Any loading error of [`ModelWeights::from_file`];
    /// [`PredictorError::WrongModelKind`] if the file holds a student.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        Self::from_weights(&ModelWeights::from_file(path)?)
    }

    /// Loads a teacher from an in-memory `.safetensors` image.
    ///
    /// # Errors
    /// As [`Teacher::from_file`], without I/O errors.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        Self::from_weights(&ModelWeights::from_bytes(bytes)?)
    }

    /// Builds a teacher from validated weights and runs the load-time self-check
    /// ([`limits::canonical_scene`], with the file's noise).
    ///
    /// # Errors
    /// [`PredictorError::WrongModelKind`] if the weights are a student's;
    /// [`PredictorError::SelfCheck`] (naming the weights' file) if its predictions on the
    /// canonical scene are non-finite or implausible.
    /// [`PredictorError::SimdPath`] if `NUDGE_SIMD` names a path this CPU lacks.
    pub fn from_weights(weights: &ModelWeights) -> Result<Self> {
        weights.expect_kind(ModelKind::Teacher)?;
        let generator = Generator::new(weights, Isa::require(simd_path()?)?);
        let noise = generator.fixed_noise.clone();
        let mut teacher = Self {
            generator,
            noise,
            s: Scratch::default(),
            n: 0,
            win0: Vec::new(),
            last: Vec::new(),
            q1: Vec::new(),
            win: Vec::new(),
            q: Vec::new(),
            h_enc2: Vec::new(),
            terms2: Vec::new(),
            max2: Vec::new(),
        };
        limits::self_check(&mut teacher, weights.path())?;
        teacher.n = 0;
        Ok(teacher)
    }

    /// The network configuration.
    #[must_use]
    pub fn config(&self) -> &ModelConfig {
        &self.generator.cfg
    }

    /// Replaces the noise and returns the teacher (builder style). Clears the current scene.
    ///
    /// # Errors
    /// See [`Teacher::set_noise`].
    pub fn with_noise(mut self, z: &[f64]) -> Result<Self> {
        self.set_noise(z)?;
        Ok(self)
    }

    /// Sets the noise vector `z` (`[noise_dim]`, standard-normal units) used for every agent
    /// of every later scene. Clears the current scene (its cached τ = 1 step used the old z).
    ///
    /// # Errors
    /// [`PredictorError::InputShape`] if `z.len() != noise_dim`,
    /// [`PredictorError::NonFiniteInput`] on NaN/inf.
    pub fn set_noise(&mut self, z: &[f64]) -> Result<()> {
        let zd = self.generator.cfg.noise_dim;
        if z.len() != zd {
            return Err(PredictorError::InputShape {
                what: "noise",
                shape: format!("[{zd}]"),
                expected: zd,
                got: z.len(),
            });
        }
        check_finite("noise", z)?;
        limits::check_noise(z)?;
        self.noise.clear();
        self.noise.extend(z.iter().map(|&v| v as f32));
        self.n = 0;
        Ok(())
    }

    /// Sets the horizon and returns the teacher (builder style). Clears the current scene.
    ///
    /// # Errors
    /// See [`Teacher::set_horizon`].
    pub fn with_horizon(mut self, horizon: usize) -> Result<Self> {
        self.set_horizon(horizon)?;
        Ok(self)
    }

    /// Sets the number of recursive one-step generator calls per candidate, the prediction
    /// horizon (steps of [`DT`](crate::DT); the file's `t_plan` until changed). The network
    /// predicts one step per call, so any horizon is a longer or shorter roll-out of the same
    /// weights. Clears the current scene.
    ///
    /// # Errors
    /// [`PredictorError::Horizon`] unless `1 <= horizon <= MAX_HORIZON`.
    pub fn set_horizon(&mut self, horizon: usize) -> Result<()> {
        check_horizon(horizon)?;
        self.generator.cfg.t_plan = horizon;
        self.n = 0;
        Ok(())
    }

    /// The noise vector in use (`[noise_dim]`).
    #[must_use]
    pub fn noise(&self) -> Vec<f64> {
        self.noise.iter().map(|&v| f64::from(v)).collect()
    }

    /// The instruction-set path the kernels run on.
    #[must_use]
    pub fn simd_path(&self) -> SimdPath {
        self.generator.isa.path()
    }

    /// Runs the kernels on `path` from now on. Clears the current scene (its cache was
    /// computed on the old path; paths differ at the 1e-6 m level, see [`SimdPath`]).
    ///
    /// # Errors
    /// [`PredictorError::SimdPath`] if this CPU lacks `path`.
    pub fn set_simd_path(&mut self, path: SimdPath) -> Result<()> {
        self.generator.set_isa(Isa::require(path)?);
        self.n = 0;
        Ok(())
    }
}

/// Slides every agent's window `[n, T_OBS, 2]` one step and appends `q` (`[n, 2]`).
fn slide(win: &mut [f64], q: &[f64], n: usize) {
    for a in 0..n {
        let w = &mut win[a * T_OBS * 2..(a + 1) * T_OBS * 2];
        w.copy_within(2.., 0);
        w[2 * T_OBS - 2] = q[2 * a];
        w[2 * T_OBS - 1] = q[2 * a + 1];
    }
}

impl Predictor for Teacher {
    fn name(&self) -> &'static str {
        "teacher"
    }

    fn horizon(&self) -> usize {
        self.generator.cfg.t_plan
    }

    fn set_scene(&mut self, history: &History) -> Result<()> {
        let n = history.n_agents();
        self.n = 0;
        self.win0.clear();
        self.win0.extend_from_slice(history.positions());
        self.last.clear();
        for a in 0..n {
            self.last.extend_from_slice(&history.at(a, T_OBS - 1));
        }
        let g = &self.generator;
        let s = &mut self.s;
        g.reserve(s, n);
        self.win.resize(self.win0.len(), 0.0);
        self.q1.resize(2 * n, 0.0);
        self.q.resize(2 * n, 0.0);
        g.one_step(&self.win0, n, &self.noise, s, &mut self.q1);
        // τ = 2: everything that involves only the non-ego agents.
        let (he, ts, al) = (g.cfg.encoder_h_dim, g.pool.term_stride(), g.pool.acc_len());
        self.win.copy_from_slice(&self.win0);
        slide(&mut self.win, &self.q1, n);
        self.h_enc2.resize(n * he, 0.0);
        self.terms2.resize(n * ts, 0.0);
        self.max2.resize(n * al, 0.0);
        g.encode(&self.win, 1..n, &mut self.h_enc2, s);
        g.pool_terms(&g.pool, &self.h_enc2, he, 1..n, &mut self.terms2);
        g.pool.reset(&mut s.acc, 1..n);
        g.pool_fold(&g.pool, &self.q1, &self.terms2, 1..n, 1..n, s);
        self.max2[al..n * al].copy_from_slice(&s.acc[al..n * al]);
        self.n = n;
        Ok(())
    }

    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> Result<()> {
        let n = self.n;
        if n == 0 {
            return Err(PredictorError::NoScene);
        }
        let t = self.horizon();
        let batch = check_batch(candidates, out, t, n, [self.last[0], self.last[1]])?;
        if n == 1 {
            return Ok(());
        }
        let g = &self.generator;
        let s = &mut self.s;
        let (he, al) = (g.cfg.encoder_h_dim, g.pool.acc_len());
        let per = (n - 1) * t * 2;
        let write = |out: &mut [f64], q: &[f64], tau: usize| {
            for a in 1..n {
                let k = ((a - 1) * t + tau) * 2;
                out[k..k + 2].copy_from_slice(&q[2 * a..2 * a + 2]);
            }
        };
        for b in 0..batch {
            let cand = &candidates[b * t * 2..(b + 1) * t * 2];
            let out = &mut out[b * per..(b + 1) * per];
            write(out, &self.q1, 0);
            if t < 2 {
                limits::check_output("teacher", b, &self.last, out, t)?;
                continue;
            }
            // τ = 2 from the cache: the ego's encoding, term and pairs only.
            self.win.copy_from_slice(&self.win0);
            self.q.copy_from_slice(&self.q1);
            self.q[..2].copy_from_slice(&cand[..2]);
            slide(&mut self.win, &self.q, n);
            g.encode(&self.win, 0..1, &mut self.h_enc2, s);
            g.pool_terms(&g.pool, &self.h_enc2, he, 0..1, &mut self.terms2);
            s.acc[al..n * al].copy_from_slice(&self.max2[al..n * al]);
            g.pool_fold(&g.pool, &self.q, &self.terms2, 1..n, 0..1, s);
            Generator::pool_finish(&g.pool, 1..n, s);
            g.decode_one(&self.win, n, &self.h_enc2, &self.noise, s, &mut self.q);
            write(out, &self.q, 1);
            // τ = 3.. : full generator calls.
            for tau in 2..t {
                self.q[..2].copy_from_slice(&cand[2 * (tau - 1)..2 * tau]);
                slide(&mut self.win, &self.q, n);
                g.one_step(&self.win, n, &self.noise, s, &mut self.q);
                write(out, &self.q, tau);
            }
            limits::check_output("teacher", b, &self.last, out, t)?;
        }
        Ok(())
    }
}
