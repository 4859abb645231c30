//! Analytical multiply-add counts of the predictors, from the model config alone.
//!
//! One multiply-add (MAC) is one `w · x` term of a linear layer (an output times an input,
//! padding excluded); activations, max-pooling and copies are not counted. The counts follow
//! the work the predictors actually do, caching included (see [`Teacher`](crate::Teacher) and
//! [`Student`](crate::Student)), and are checked against a counter in the kernels in the tests.
//!
//! With `E` the embedding, `He`/`Hd` the encoder/decoder hidden sizes, `P` the pre-pool width,
//! `B` the bottleneck, `M` the mlp width, `Z` the noise size, `T` = [`T_OBS`] and `t` the
//! horizon, the building blocks are (the spatial embeddings are folded into the next layer, so
//! `E` does not appear):
//!
//! | block | MACs |
//! |---|---|
//! | LSTM step, hidden `H` | `lstm(H) = 4H (2 + H)` |
//! | encoder, one agent (the first step is cached at load) | `enc = (T - 1) lstm(He)` |
//! | pool agent term from hidden `H` | `term(H) = H P` |
//! | pool pair | `pair = 2P + P B` |
//! | decoder context | `ctx = (He + B) M + M (Hd - Z)` |
//! | decoder step (LSTM + hidden2pos) | `dec = lstm(Hd) + 2 Hd` |
//! | decoder refinement (pool every step) | `ref = (Hd + B) M + M Hd` |
//!
//! Teacher, `n` agents: one generator call is
//! `call(n) = n enc + n term(He) + (n-1) n pair + (n-1)(ctx + dec)`;
//! `set_scene = call(n) + (n-1) enc + (n-1) term(He) + (n-1)² pair` (τ = 1 and the non-ego
//! part of τ = 2); per candidate (`n ≥ 2`, `t ≥ 2`):
//! `enc + term(He) + (n-1) pair + (n-1)(ctx + dec) + (t-2) call(n)`.
//!
//! Student, `n` agents: `set_scene = n enc + n term(He) + n² pair + n ctx + n dec`, plus
//! `n term(Hd) + (n-1)² pair` when it pools every step; per candidate (`n ≥ 2`): for each
//! decoder step `k = 1..t-1`, the pooling (`k = 1`: `(2n - 1)` pairs; later: `n term(Hd) +
//! n² pair`) and `n ref` when it pools every step, then `dec` for `n` agents (`n - 1` at the
//! last step).
//!
//! For the shipped teacher (`He = Hd = 32`, `P = 512`, `B = 32`, `M = 64`, `Z = 8`) a pair costs
//! 17 408 MACs, so the pooling's second layer dominates from a few agents on.

use crate::T_OBS;
use crate::weights::{ModelConfig, ModelKind};

/// Multiply-adds of one scene: the history-only part and each candidate's part.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MacCount {
    /// MACs of `set_scene`.
    pub set_scene: u64,
    /// MACs of `predict` per candidate.
    pub per_candidate: u64,
}

impl MacCount {
    /// MACs of `set_scene` followed by `predict` of `batch` candidates.
    #[must_use]
    pub fn total(&self, batch: u64) -> u64 {
        self.set_scene + batch * self.per_candidate
    }
}

/// The multiply-adds a [`Teacher`](crate::Teacher) or [`Student`](crate::Student) with config
/// `cfg` performs for a scene of `n_agents` agents (see the [module docs](self)).
#[must_use]
pub fn multiply_adds(cfg: &ModelConfig, n_agents: usize) -> MacCount {
    let n = n_agents as u64;
    let (he, hd) = (cfg.encoder_h_dim as u64, cfg.decoder_h_dim as u64);
    let (p, b, m, z) = (
        cfg.pool_hidden_dim as u64,
        cfg.bottleneck_dim as u64,
        cfg.mlp_dim as u64,
        cfg.noise_dim as u64,
    );
    let t = cfg.t_plan as u64;
    let lstm = |h: u64| 4 * h * (2 + h);
    let enc = (T_OBS as u64 - 1) * lstm(he);
    let term = |h: u64| h * p;
    let pair = 2 * p + p * b;
    let ctx = (he + b) * m + m * (hd - z);
    let dec = lstm(hd) + 2 * hd;
    let refine = (hd + b) * m + m * hd;
    let n1 = n.saturating_sub(1);
    match cfg.kind {
        ModelKind::Teacher => {
            let call = n * enc + n * term(he) + n1 * n * pair + n1 * (ctx + dec);
            let set_scene = call + n1 * enc + n1 * term(he) + n1 * n1 * pair;
            let per_candidate = if n < 2 || t < 2 {
                0
            } else {
                enc + term(he) + n1 * pair + n1 * (ctx + dec) + (t - 2) * call
            };
            MacCount {
                set_scene,
                per_candidate,
            }
        }
        ModelKind::Student => {
            let pools = cfg.pool_every_timestep;
            let mut set_scene = n * enc + n * term(he) + n * n * pair + n * ctx + n * dec;
            if pools && t > 1 {
                set_scene += n * term(hd) + n1 * n1 * pair;
            }
            let mut per_candidate = 0;
            if n >= 2 {
                for k in 1..t {
                    if pools {
                        per_candidate += if k == 1 {
                            (2 * n - 1) * pair
                        } else {
                            n * term(hd) + n * n * pair
                        };
                        per_candidate += n * refine;
                    }
                    per_candidate += if k + 1 == t { n1 } else { n } * dec;
                }
            }
            MacCount {
                set_scene,
                per_candidate,
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::nn::counter;
    use crate::weights::{ModelWeights, synthetic_weights};
    use crate::{History, Predictor, Student, Teacher};

    fn scene(n: usize) -> History {
        let mut pos = Vec::new();
        for a in 0..n {
            for t in 0..T_OBS {
                pos.push(a as f64 * 7.0 - 10.0 + t as f64 * (2.0 + a as f64 * 0.1));
                pos.push((a % 3) as f64 * 3.5 - 3.5 + t as f64 * 0.01);
            }
        }
        History::new(pos, n).unwrap_or_else(|e| panic!("{e}"))
    }

    /// The kernels' own count equals the formula, for both kinds, several sizes, with and
    /// without decoder pooling, on every supported path.
    #[test]
    fn formula_matches_kernel_counter() {
        let odd = ModelConfig {
            embedding_dim: 5,
            encoder_h_dim: 7,
            decoder_h_dim: 9,
            mlp_dim: 11,
            bottleneck_dim: 13,
            pool_hidden_dim: 40,
            noise_dim: 3,
            ..ModelConfig::teacher()
        };
        let configs = [
            ModelConfig::teacher(),
            ModelConfig::student(),
            ModelConfig {
                pool_every_timestep: true,
                ..odd.clone()
            },
            ModelConfig {
                kind: ModelKind::Student,
                pred_len: 6,
                pool_every_timestep: false,
                noise_dim: 2,
                ..odd
            },
        ];
        for cfg in configs {
            let bytes = synthetic_weights(&cfg, 3).unwrap_or_else(|e| panic!("{e}"));
            let w = ModelWeights::from_bytes(&bytes).unwrap_or_else(|e| panic!("{e}"));
            for path in crate::supported_simd_paths() {
                let mut model: Box<dyn Predictor> = match cfg.kind {
                    ModelKind::Teacher => {
                        let mut m = Teacher::from_weights(&w).unwrap_or_else(|e| panic!("{e}"));
                        m.set_simd_path(path).unwrap_or_else(|e| panic!("{e}"));
                        Box::new(m)
                    }
                    ModelKind::Student => {
                        let mut m = Student::from_weights(&w).unwrap_or_else(|e| panic!("{e}"));
                        m.set_simd_path(path).unwrap_or_else(|e| panic!("{e}"));
                        Box::new(m)
                    }
                };
                for n in [1usize, 2, 3, 6] {
                    let want = multiply_adds(&cfg, n);
                    counter::take();
                    model.set_scene(&scene(n)).unwrap_or_else(|e| panic!("{e}"));
                    assert_eq!(
                        counter::take(),
                        want.set_scene,
                        "{:?} n={n} set_scene",
                        cfg.kind
                    );
                    let t = model.horizon();
                    let cand: Vec<f64> =
                        (0..2 * t * 2).map(|i| (i % (2 * t)) as f64 * 0.7).collect();
                    let mut out = vec![0.0; 2 * (n - 1) * t * 2];
                    model
                        .predict(&cand, &mut out)
                        .unwrap_or_else(|e| panic!("{e}"));
                    assert_eq!(
                        counter::take(),
                        2 * want.per_candidate,
                        "{:?} n={n} predict",
                        cfg.kind
                    );
                }
            }
        }
    }

    /// The shipped teacher's figure quoted in the docs: a pair is 17 408 MACs, and at N = 8
    /// one prediction is about 8 M MACs.
    #[test]
    fn shipped_teacher_order_of_magnitude() {
        let c = multiply_adds(&ModelConfig::teacher(), 8);
        let total = c.total(1);
        assert!((7_000_000..9_000_000).contains(&total), "{total}");
        assert_eq!(2 * 512 + 512 * 32, 17_408);
    }
}
