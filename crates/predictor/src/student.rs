//! The student φ_S: a small generator that reads the ego candidate and predicts the whole
//! horizon in one pass.

use crate::error::Result;
use crate::generator::Generator;
use crate::network::{Net, network_api};
use crate::{History, Predictor, T_OBS, limits};

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
    /// The generator, its noise (`[noise_dim]`, empty for the shipped student), scratch and
    /// scene size.
    net: Net,
    /// Step-1 decoder state and working buffers of the current scene.
    scene: StudentScene,
}

/// The scene caches of a [`Student`] (see there), grown to the scene size.
#[derive(Debug, Clone, Default)]
struct StudentScene {
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

network_api!(Student, "student", "teacher");

impl Predictor for Student {
    fn name(&self) -> &'static str {
        "student"
    }

    fn horizon(&self) -> usize {
        self.net.generator.cfg.t_plan
    }

    fn set_scene(&mut self, history: &History) -> Result<()> {
        let n = self.net.start_scene(history);
        let g = &self.net.generator;
        let s = &mut self.net.s;
        let (he, hd) = (g.cfg.encoder_h_dim, g.cfg.decoder_h_dim);
        let mut h_enc = std::mem::take(&mut s.h_enc);
        g.encode(&self.net.win0, 0..n, &mut h_enc, s);
        let mut terms = std::mem::take(&mut s.terms);
        g.pool_terms(&g.pool, &h_enc, he, 0..n, &mut terms);
        g.pool_all(&g.pool, &self.net.last, &terms, n, 0..n, s);
        s.terms = terms;
        let ld = g.dec_row_len();
        self.scene.rows1.resize(n * ld, 0.0);
        g.context(
            0..n,
            &h_enc,
            &self.net.noise,
            s,
            &mut self.scene.rows1[2..],
            ld,
        );
        s.h_enc = h_enc;
        s.cd[..n * hd].fill(0.0);
        // Decoder step 1: input is the last observed displacement, candidate-independent.
        for (i, row) in self.scene.rows1.chunks_exact_mut(ld).enumerate() {
            let k = (i * T_OBS + T_OBS - 1) * 2;
            row[0] = (self.net.win0[k] - self.net.win0[k - 2]) as f32;
            row[1] = (self.net.win0[k + 1] - self.net.win0[k - 1]) as f32;
        }
        g.decode_rows(0..n, &mut self.scene.rows1, s);
        self.scene.pos1.clear();
        for (i, row) in self.scene.rows1.chunks_exact(ld).enumerate() {
            self.scene.pos1.extend_from_slice(&[
                self.net.last[2 * i] + f64::from(row[0]),
                self.net.last[2 * i + 1] + f64::from(row[1]),
            ]);
        }
        self.scene.c1.clear();
        self.scene.c1.extend_from_slice(&s.cd[..n * hd]);
        self.scene.rows.resize(n * ld, 0.0);
        self.scene.pos.resize(2 * n, 0.0);
        // Step-1 pooling among the non-ego agents is candidate-independent too.
        if let Some(pool) = &g.dec_pool
            && g.cfg.t_plan > 1
        {
            let (ts, al) = (pool.term_stride(), pool.acc_len());
            self.scene.terms1.resize(n * ts, 0.0);
            g.pool_terms(
                pool,
                &self.scene.rows1[2..],
                ld,
                0..n,
                &mut self.scene.terms1,
            );
            self.scene.max1.resize(n * al, 0.0);
            pool.reset(&mut s.acc, 1..n);
            g.pool_fold(pool, &self.scene.pos1, &self.scene.terms1, 1..n, 1..n, s);
            self.scene.max1[al..n * al].copy_from_slice(&s.acc[al..n * al]);
        }
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
        let (hd, ld) = (g.cfg.decoder_h_dim, g.dec_row_len());
        let per = (n - 1) * t * 2;
        for b in 0..batch {
            let cand = &candidates[b * t * 2..(b + 1) * t * 2];
            let out = &mut out[b * per..(b + 1) * per];
            self.scene.rows.copy_from_slice(&self.scene.rows1);
            s.cd[..n * hd].copy_from_slice(&self.scene.c1);
            self.scene.pos.copy_from_slice(&self.scene.pos1);
            let mut prev_ego = [self.net.last[0], self.net.last[1]];
            for k in 0..t {
                if k > 0 {
                    if let Some(pool) = &g.dec_pool {
                        let al = pool.acc_len();
                        // Pooled vectors go to the rows' pooled part.
                        let pooled = &mut self.scene.rows[2 + hd..];
                        if k == 1 {
                            // Cached terms and maxima over the others; add the ego's pairs.
                            s.acc[al..n * al].copy_from_slice(&self.scene.max1[al..n * al]);
                            g.pool_fold(pool, &self.scene.pos, &self.scene.terms1, 1..n, 0..1, s);
                            Generator::pool_finish_into(pool, 1..n, &s.acc, pooled, ld);
                            g.pool_all_into(
                                pool,
                                &self.scene.pos,
                                &self.scene.terms1,
                                n,
                                0..1,
                                s,
                                pooled,
                                ld,
                            );
                        } else {
                            let mut terms = std::mem::take(&mut s.terms);
                            g.pool_terms(pool, &self.scene.rows[2..], ld, 0..n, &mut terms);
                            let pooled = &mut self.scene.rows[2 + hd..];
                            g.pool_all_into(pool, &self.scene.pos, &terms, n, 0..n, s, pooled, ld);
                            s.terms = terms;
                        }
                        g.refine_rows(n, &mut self.scene.rows, s);
                    }
                    // The ego's state is not needed after the last step.
                    let first = usize::from(k + 1 == t);
                    g.decode_rows(first..n, &mut self.scene.rows, s);
                    for i in first..n {
                        self.scene.pos[2 * i] += f64::from(self.scene.rows[i * ld]);
                        self.scene.pos[2 * i + 1] += f64::from(self.scene.rows[i * ld + 1]);
                    }
                }
                // Ego override: displacement and position from the candidate.
                let c = [cand[2 * k], cand[2 * k + 1]];
                self.scene.rows[0] = (c[0] - prev_ego[0]) as f32;
                self.scene.rows[1] = (c[1] - prev_ego[1]) as f32;
                self.scene.pos[..2].copy_from_slice(&c);
                prev_ego = c;
                for a in 1..n {
                    let o = ((a - 1) * t + k) * 2;
                    out[o..o + 2].copy_from_slice(&self.scene.pos[2 * a..2 * a + 2]);
                }
            }
            limits::check_output("student", b, &self.net.last, out, t)?;
        }
        Ok(())
    }
}
