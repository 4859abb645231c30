//! The teacher φ_T: a large Social-GAN generator run recursively over the planning horizon.

use crate::error::Result;
use crate::generator::Generator;
use crate::network::{Net, network_api};
use crate::{History, Predictor, T_OBS, check_horizon, limits};

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
    /// The generator, the noise `z` (`[noise_dim]`), scratch and scene size.
    net: Net,
    /// τ = 1 and τ = 2 caches and working buffers of the current scene.
    scene: TeacherScene,
}

/// The scene caches of a [`Teacher`] (see there), grown to the scene size.
#[derive(Debug, Clone, Default)]
struct TeacherScene {
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

network_api!(Teacher, "teacher", "student");

impl Teacher {
    /// Replaces the noise and returns the teacher (builder style). Clears the current scene.
    ///
    /// # Errors
    /// See [`Teacher::set_noise`].
    pub fn with_noise(mut self, z: &[f64]) -> Result<Self> {
        self.set_noise(z)?;
        Ok(self)
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
    /// [`PredictorError::Horizon`](crate::PredictorError::Horizon) unless
    /// `1 <= horizon <= MAX_HORIZON`.
    pub fn set_horizon(&mut self, horizon: usize) -> Result<()> {
        check_horizon(horizon)?;
        self.net.generator.cfg.t_plan = horizon;
        self.net.n = 0;
        Ok(())
    }

    /// The noise vector in use (`[noise_dim]`).
    #[must_use]
    pub fn noise(&self) -> Vec<f64> {
        self.net.noise.iter().map(|&v| f64::from(v)).collect()
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
        self.net.generator.cfg.t_plan
    }

    fn set_scene(&mut self, history: &History) -> Result<()> {
        let n = self.net.start_scene(history);
        let g = &self.net.generator;
        let s = &mut self.net.s;
        self.scene.win.resize(self.net.win0.len(), 0.0);
        self.scene.q1.resize(2 * n, 0.0);
        self.scene.q.resize(2 * n, 0.0);
        g.one_step(&self.net.win0, n, &self.net.noise, s, &mut self.scene.q1);
        // τ = 2: everything that involves only the non-ego agents.
        let (he, ts, al) = (g.cfg.encoder_h_dim, g.pool.term_stride(), g.pool.acc_len());
        self.scene.win.copy_from_slice(&self.net.win0);
        slide(&mut self.scene.win, &self.scene.q1, n);
        self.scene.h_enc2.resize(n * he, 0.0);
        self.scene.terms2.resize(n * ts, 0.0);
        self.scene.max2.resize(n * al, 0.0);
        g.encode(&self.scene.win, 1..n, &mut self.scene.h_enc2, s);
        g.pool_terms(
            &g.pool,
            &self.scene.h_enc2,
            he,
            1..n,
            &mut self.scene.terms2,
        );
        g.pool.reset(&mut s.acc, 1..n);
        g.pool_fold(&g.pool, &self.scene.q1, &self.scene.terms2, 1..n, 1..n, s);
        self.scene.max2[al..n * al].copy_from_slice(&s.acc[al..n * al]);
        self.net.n = n;
        Ok(())
    }

    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> Result<()> {
        let t = self.horizon();
        let Some((n, batch)) = self.net.batch(candidates, out, t)? else {
            return Ok(());
        };
        let g = &self.net.generator;
        let s = &mut self.net.s;
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
            write(out, &self.scene.q1, 0);
            if t < 2 {
                limits::check_output("teacher", b, &self.net.last, out, t)?;
                continue;
            }
            // τ = 2 from the cache: the ego's encoding, term and pairs only.
            self.scene.win.copy_from_slice(&self.net.win0);
            self.scene.q.copy_from_slice(&self.scene.q1);
            self.scene.q[..2].copy_from_slice(&cand[..2]);
            slide(&mut self.scene.win, &self.scene.q, n);
            g.encode(&self.scene.win, 0..1, &mut self.scene.h_enc2, s);
            g.pool_terms(
                &g.pool,
                &self.scene.h_enc2,
                he,
                0..1,
                &mut self.scene.terms2,
            );
            s.acc[al..n * al].copy_from_slice(&self.scene.max2[al..n * al]);
            g.pool_fold(&g.pool, &self.scene.q, &self.scene.terms2, 1..n, 0..1, s);
            Generator::pool_finish(&g.pool, 1..n, s);
            g.decode_one(
                &self.scene.win,
                n,
                &self.scene.h_enc2,
                &self.net.noise,
                s,
                &mut self.scene.q,
            );
            write(out, &self.scene.q, 1);
            // τ = 3.. : full generator calls.
            for tau in 2..t {
                self.scene.q[..2].copy_from_slice(&cand[2 * (tau - 1)..2 * tau]);
                slide(&mut self.scene.win, &self.scene.q, n);
                g.one_step(&self.scene.win, n, &self.net.noise, s, &mut self.scene.q);
                write(out, &self.scene.q, tau);
            }
            limits::check_output("teacher", b, &self.net.last, out, t)?;
        }
        Ok(())
    }
}
