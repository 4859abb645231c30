//! The student φ_S: a small generator that reads the ego candidate and predicts the whole
//! horizon in one pass.

use std::path::Path;

use crate::error::{PredictorError, Result};
use crate::generator::{Generator, Scratch};
use crate::history::check_finite;
use crate::nn::Pool;
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
    /// After the candidate-independent decoder step 1: states `[n, Hd]`, displacements
    /// `[n, 2]` (f32, network outputs), positions `[n, 2]` (f64 metres).
    h1: Vec<f32>,
    c1: Vec<f32>,
    d1: Vec<f32>,
    pos1: Vec<f64>,
    /// Pool terms of step 1 `[n, P]` and running maxima over agents 1..n `[n, acc_len]`.
    terms1: Vec<f32>,
    max1: Vec<f32>,
    /// Working displacements `[n, 2]` (f32) and positions `[n, 2]` (f64 metres).
    d: Vec<f32>,
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
    pub fn from_weights(weights: &ModelWeights) -> Result<Self> {
        weights.expect_kind(ModelKind::Student)?;
        let generator = Generator::new(weights);
        let noise = generator.fixed_noise.clone();
        let mut student = Self {
            generator,
            noise,
            s: Scratch::default(),
            n: 0,
            win0: Vec::new(),
            last: Vec::new(),
            h1: Vec::new(),
            c1: Vec::new(),
            d1: Vec::new(),
            pos1: Vec::new(),
            terms1: Vec::new(),
            max1: Vec::new(),
            d: Vec::new(),
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
        for a in 0..n {
            g.encode_agent(&self.win0, a, &mut s.h_enc, &mut s.ls);
        }
        self.last.clear();
        for a in 0..n {
            let k = (a * T_OBS + T_OBS - 1) * 2;
            self.last.extend_from_slice(&self.win0[k..k + 2]);
        }
        for a in 0..n {
            Generator::pool_term(&g.pool, &s.h_enc, he, a, &mut s.terms);
        }
        Generator::pool_all(
            &g.pool,
            &self.last,
            &s.terms,
            n,
            0..n,
            &mut s.ps,
            &mut s.pooled,
        );
        let mut h0 = std::mem::take(&mut s.h);
        let h_enc = std::mem::take(&mut s.h_enc);
        for i in 0..n {
            g.context(i, &h_enc, &self.noise, s, &mut h0[i * hd..(i + 1) * hd]);
        }
        s.h_enc = h_enc;
        s.h = h0;
        s.cd[..n * hd].fill(0.0);
        // Decoder step 1: input is the last observed displacement, candidate-independent.
        self.d1.clear();
        self.pos1.clear();
        for i in 0..n {
            let k = (i * T_OBS + T_OBS - 1) * 2;
            let d = [
                (self.win0[k] - self.win0[k - 2]) as f32,
                (self.win0[k + 1] - self.win0[k - 1]) as f32,
            ];
            let dp = g.decode_step(i, d, s);
            self.d1.extend_from_slice(&dp);
            self.pos1.extend_from_slice(&[
                self.last[2 * i] + f64::from(dp[0]),
                self.last[2 * i + 1] + f64::from(dp[1]),
            ]);
        }
        self.h1.clear();
        self.h1.extend_from_slice(&s.h[..n * hd]);
        self.c1.clear();
        self.c1.extend_from_slice(&s.cd[..n * hd]);
        self.d.resize(2 * n, 0.0);
        self.pos.resize(2 * n, 0.0);
        // Step-1 pooling among the non-ego agents is candidate-independent too.
        if let Some(pool) = &g.dec_pool
            && g.cfg.t_plan > 1
        {
            let (p, al) = (pool.hidden(), pool.acc_len());
            self.terms1.resize(n * p, 0.0);
            for a in 0..n {
                Generator::pool_term(pool, &self.h1, hd, a, &mut self.terms1);
            }
            self.max1.resize(n * al, 0.0);
            for i in 1..n {
                Pool::reset(&mut s.ps.acc);
                Generator::pool_fold(pool, &self.pos1, &self.terms1, i, 1..n, &mut s.ps);
                self.max1[i * al..(i + 1) * al].copy_from_slice(&s.ps.acc[..al]);
            }
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
        let hd = g.cfg.decoder_h_dim;
        let per = (n - 1) * t * 2;
        for b in 0..batch {
            let cand = &candidates[b * t * 2..(b + 1) * t * 2];
            let out = &mut out[b * per..(b + 1) * per];
            s.h[..n * hd].copy_from_slice(&self.h1);
            s.cd[..n * hd].copy_from_slice(&self.c1);
            self.d.copy_from_slice(&self.d1);
            self.pos.copy_from_slice(&self.pos1);
            let mut prev_ego = [self.last[0], self.last[1]];
            for k in 0..t {
                if k > 0 {
                    if let Some(pool) = &g.dec_pool {
                        let (b_dim, al) = (pool.out_dim(), pool.acc_len());
                        if k == 1 {
                            // Cached terms and maxima over the others; add the ego's pairs.
                            for i in 1..n {
                                s.ps.acc[..al].copy_from_slice(&self.max1[i * al..(i + 1) * al]);
                                Generator::pool_fold(
                                    pool,
                                    &self.pos,
                                    &self.terms1,
                                    i,
                                    0..1,
                                    &mut s.ps,
                                );
                                pool.finish(&s.ps.acc, &mut s.pooled[i * b_dim..(i + 1) * b_dim]);
                            }
                            Generator::pool_all(
                                pool,
                                &self.pos,
                                &self.terms1,
                                n,
                                0..1,
                                &mut s.ps,
                                &mut s.pooled,
                            );
                        } else {
                            for a in 0..n {
                                Generator::pool_term(pool, &s.h, hd, a, &mut s.terms);
                            }
                            Generator::pool_all(
                                pool,
                                &self.pos,
                                &s.terms,
                                n,
                                0..n,
                                &mut s.ps,
                                &mut s.pooled,
                            );
                        }
                        g.refine_all(n, s);
                    }
                    // The ego's state is not needed after the last step.
                    let first = usize::from(k + 1 == t);
                    for i in first..n {
                        let d = [self.d[2 * i], self.d[2 * i + 1]];
                        let dp = g.decode_step(i, d, s);
                        self.d[2 * i] = dp[0];
                        self.d[2 * i + 1] = dp[1];
                        self.pos[2 * i] += f64::from(dp[0]);
                        self.pos[2 * i + 1] += f64::from(dp[1]);
                    }
                }
                // Ego override: displacement and position from the candidate.
                let c = [cand[2 * k], cand[2 * k + 1]];
                self.d[0] = (c[0] - prev_ego[0]) as f32;
                self.d[1] = (c[1] - prev_ego[1]) as f32;
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
