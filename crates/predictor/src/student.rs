//! The student φ_S: a small generator that reads the ego candidate and predicts the whole
//! horizon in one pass.

use std::path::Path;

use crate::error::{PredictorError, Result};
use crate::generator::{Generator, Scratch};
use crate::history::check_finite;
use crate::simd::{Isa, SimdPath, simd_path};
use crate::weights::{ModelConfig, ModelKind, ModelWeights};
use crate::{History, Predictor, T_OBS, check_batch, limits};

/// The student predictor.
///
/// Encoder, pooling and context depend only on the history and run once in
/// [`Predictor::set_scene`], together with the decoder's first LSTM step (its input is the
/// last observed displacement) and, when the decoder pools every step, the first pooling's
/// terms and its running max over the non-ego agents. Each candidate then costs the rest of
/// the `t_plan`-step decoder, in which the ego's predicted displacement and position are
/// overwritten by the candidate's after every step, before the pooling and the next input.
///
/// The kernels run on the instruction-set path [`simd_path`](crate::simd_path) chose at load
/// time; see [`Student::set_simd_path`].
#[derive(Debug, Clone)]
pub struct Student {
    generator: Generator,
    /// `[noise_dim]` (empty for the shipped student, noise_dim = 0).
    noise: Vec<f32>,
    s: Scratch,
    n: usize,
    /// Scene history `[n, T_OBS, 2]` (metres).
    win0: Vec<f64>,
    /// Last observed positions `[n, 2]` (metres).
    last: Vec<f64>,
    /// Decoder state after the candidate-independent step 1: rows `[d ; h ; pooled]`
    /// (`[n, dec_row_len]`, see `Generator::dec_row_len`; `d` the predicted displacement,
    /// f32 network output), cell states `[n, Hd]`, positions `[n, 2]` (f64 metres).
    rows1: Vec<f32>,
    c1: Vec<f32>,
    pos1: Vec<f64>,
    /// Pool terms of step 1 `[n, term_stride]` and running maxima over agents 1..n `[n, acc_len]`.
    terms1: Vec<f32>,
    max1: Vec<f32>,
    /// Working decoder rows `[n, dec_row_len]` and positions `[n, 2]` (f64 metres).
    rows: Vec<f32>,
    pos: Vec<f64>,
}

impl Student {
    /// Loads a student from a `.safetensors` weights file.
    ///
    /// # Errors
    /// Any loading error of [`ModelWeights::from_file`];
    /// [`PredictorError::WrongModelKind`] if the file holds a teacher.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        Self::from_weights(&ModelWeights::from_file(path)?)
    }

    /// Loads a student from an in-memory `.safetensors` image.
    ///
    /// # Errors
    /// As [`Student::from_file`], without I/O errors.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        Self::from_weights(&ModelWeights::from_bytes(bytes)?)
    }

    /// Builds a student from validated weights and runs the load-time self-check
    /// ([`limits::canonical_scene`]).
    ///
    /// # Errors
    /// [`PredictorError::WrongModelKind`] if the weights are a teacher's;
    /// [`PredictorError::SelfCheck`] (naming the weights' file) if its predictions on the
    /// canonical scene are non-finite or implausible.
    /// [`PredictorError::SimdPath`] if `NUDGE_SIMD` names a path this CPU lacks.
    pub fn from_weights(weights: &ModelWeights) -> Result<Self> {
        weights.expect_kind(ModelKind::Student)?;
        let generator = Generator::new(weights, Isa::require(simd_path()?)?);
        let noise = generator.fixed_noise.clone();
        let mut student = Self {
            generator,
            noise,
            s: Scratch::default(),
            n: 0,
            win0: Vec::new(),
            last: Vec::new(),
            rows1: Vec::new(),
            c1: Vec::new(),
            pos1: Vec::new(),
            terms1: Vec::new(),
            max1: Vec::new(),
            rows: Vec::new(),
            pos: Vec::new(),
        };
        limits::self_check(&mut student, weights.path())?;
        student.n = 0;
        Ok(student)
    }

    /// The network configuration.
    #[must_use]
    pub fn config(&self) -> &ModelConfig {
        &self.generator.cfg
    }

    /// Sets the noise vector (`[noise_dim]`; only meaningful for a student trained with
    /// noise). Clears the current scene.
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

impl Predictor for Student {
    fn name(&self) -> &'static str {
        "student"
    }

    fn horizon(&self) -> usize {
        self.generator.cfg.t_plan
    }

    fn set_scene(&mut self, history: &History) -> Result<()> {
        let n = history.n_agents();
        self.n = 0;
        self.win0.clear();
        self.win0.extend_from_slice(history.positions());
        let g = &self.generator;
        let s = &mut self.s;
        g.reserve(s, n);
        let (he, hd) = (g.cfg.encoder_h_dim, g.cfg.decoder_h_dim);
        let mut h_enc = std::mem::take(&mut s.h_enc);
        g.encode(&self.win0, 0..n, &mut h_enc, s);
        self.last.clear();
        for a in 0..n {
            let k = (a * T_OBS + T_OBS - 1) * 2;
            self.last.extend_from_slice(&self.win0[k..k + 2]);
        }
        let mut terms = std::mem::take(&mut s.terms);
        g.pool_terms(&g.pool, &h_enc, he, 0..n, &mut terms);
        g.pool_all(&g.pool, &self.last, &terms, n, 0..n, s);
        s.terms = terms;
        let ld = g.dec_row_len();
        self.rows1.resize(n * ld, 0.0);
        g.context(0..n, &h_enc, &self.noise, s, &mut self.rows1[2..], ld);
        s.h_enc = h_enc;
        s.cd[..n * hd].fill(0.0);
        // Decoder step 1: input is the last observed displacement, candidate-independent.
        for (i, row) in self.rows1.chunks_exact_mut(ld).enumerate() {
            let k = (i * T_OBS + T_OBS - 1) * 2;
            row[0] = (self.win0[k] - self.win0[k - 2]) as f32;
            row[1] = (self.win0[k + 1] - self.win0[k - 1]) as f32;
        }
        g.decode_rows(0..n, &mut self.rows1, s);
        self.pos1.clear();
        for (i, row) in self.rows1.chunks_exact(ld).enumerate() {
            self.pos1.extend_from_slice(&[
                self.last[2 * i] + f64::from(row[0]),
                self.last[2 * i + 1] + f64::from(row[1]),
            ]);
        }
        self.c1.clear();
        self.c1.extend_from_slice(&s.cd[..n * hd]);
        self.rows.resize(n * ld, 0.0);
        self.pos.resize(2 * n, 0.0);
        // Step-1 pooling among the non-ego agents is candidate-independent too.
        if let Some(pool) = &g.dec_pool
            && g.cfg.t_plan > 1
        {
            let (ts, al) = (pool.term_stride(), pool.acc_len());
            self.terms1.resize(n * ts, 0.0);
            g.pool_terms(pool, &self.rows1[2..], ld, 0..n, &mut self.terms1);
            self.max1.resize(n * al, 0.0);
            pool.reset(&mut s.acc, 1..n);
            g.pool_fold(pool, &self.pos1, &self.terms1, 1..n, 1..n, s);
            self.max1[al..n * al].copy_from_slice(&s.acc[al..n * al]);
        }
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
        let (hd, ld) = (g.cfg.decoder_h_dim, g.dec_row_len());
        let per = (n - 1) * t * 2;
        for b in 0..batch {
            let cand = &candidates[b * t * 2..(b + 1) * t * 2];
            let out = &mut out[b * per..(b + 1) * per];
            self.rows.copy_from_slice(&self.rows1);
            s.cd[..n * hd].copy_from_slice(&self.c1);
            self.pos.copy_from_slice(&self.pos1);
            let mut prev_ego = [self.last[0], self.last[1]];
            for k in 0..t {
                if k > 0 {
                    if let Some(pool) = &g.dec_pool {
                        let al = pool.acc_len();
                        // Pooled vectors go to the rows' pooled part.
                        let pooled = &mut self.rows[2 + hd..];
                        if k == 1 {
                            // Cached terms and maxima over the others; add the ego's pairs.
                            s.acc[al..n * al].copy_from_slice(&self.max1[al..n * al]);
                            g.pool_fold(pool, &self.pos, &self.terms1, 1..n, 0..1, s);
                            Generator::pool_finish_into(pool, 1..n, &s.acc, pooled, ld);
                            g.pool_all_into(pool, &self.pos, &self.terms1, n, 0..1, s, pooled, ld);
                        } else {
                            let mut terms = std::mem::take(&mut s.terms);
                            g.pool_terms(pool, &self.rows[2..], ld, 0..n, &mut terms);
                            let pooled = &mut self.rows[2 + hd..];
                            g.pool_all_into(pool, &self.pos, &terms, n, 0..n, s, pooled, ld);
                            s.terms = terms;
                        }
                        g.refine_rows(n, &mut self.rows, s);
                    }
                    // The ego's state is not needed after the last step.
                    let first = usize::from(k + 1 == t);
                    g.decode_rows(first..n, &mut self.rows, s);
                    for i in first..n {
                        self.pos[2 * i] += f64::from(self.rows[i * ld]);
                        self.pos[2 * i + 1] += f64::from(self.rows[i * ld + 1]);
                    }
                }
                // Ego override: displacement and position from the candidate.
                let c = [cand[2 * k], cand[2 * k + 1]];
                self.rows[0] = (c[0] - prev_ego[0]) as f32;
                self.rows[1] = (c[1] - prev_ego[1]) as f32;
                self.pos[..2].copy_from_slice(&c);
                prev_ego = c;
                for a in 1..n {
                    let o = ((a - 1) * t + k) * 2;
                    out[o..o + 2].copy_from_slice(&self.pos[2 * a..2 * a + 2]);
                }
            }
            limits::check_output("student", b, &self.last, out, t)?;
        }
        Ok(())
    }
}
