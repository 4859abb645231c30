//! A slow, literal reference implementation of the networks, for tests and verification.
//!
//! It follows the PyTorch modules operation by operation (embedding, then concatenation,
//! unsplit pooling over every pair, separate LSTM biases, no caching, no folding) and
//! allocates freely. It computes in **f64** (the f32 weights widened), like the golden
//! generator `nudge-train goldens`, so it is a precision reference as well:
//! [`Teacher`](crate::Teacher) and [`Student`](crate::Student) (f32) must agree with it to
//! ≤ 1e-5 m; the property tests check that.

use crate::error::{PredictorError, Result};
use crate::weights::{ModelKind, ModelWeights};
use crate::{History, T_OBS, check_batch};

/// `W x + b` with `W` row-major `[out, in]`, summed in input order.
fn linear(w: &[f32], b: &[f32], x: &[f64]) -> Vec<f64> {
    let n_in = x.len();
    b.iter()
        .enumerate()
        .map(|(o, &bo)| {
            let row = &w[o * n_in..(o + 1) * n_in];
            let mut s = 0.0f64;
            for (wk, xk) in row.iter().zip(x) {
                s += f64::from(*wk) * xk;
            }
            s + f64::from(bo)
        })
        .collect()
}

/// `max(x, 0)` per element, NaN kept (PyTorch's `relu`; [`f64::max`] would return 0).
fn relu(mut v: Vec<f64>) -> Vec<f64> {
    for x in &mut v {
        *x = nan_max(*x, 0.0);
    }
    v
}

/// The larger of `a` and `b`, NaN when either is NaN (PyTorch's `max`).
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// `relu(L2(relu(L1 x)))` for the `nn.Sequential` under `prefix` (`.0` and `.2`).
fn mlp(w: &ModelWeights, prefix: &str, x: &[f64]) -> Vec<f64> {
    let h = relu(linear(
        w.get(&format!("{prefix}.0.weight")),
        w.get(&format!("{prefix}.0.bias")),
        x,
    ));
    relu(linear(
        w.get(&format!("{prefix}.2.weight")),
        w.get(&format!("{prefix}.2.bias")),
        &h,
    ))
}

fn embed(w: &ModelWeights, prefix: &str, d: [f64; 2]) -> Vec<f64> {
    linear(
        w.get(&format!("{prefix}.spatial_embedding.weight")),
        w.get(&format!("{prefix}.spatial_embedding.bias")),
        &d,
    )
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// PyTorch `nn.LSTM` cell `lstm` (e.g. `encoder.encoder`), gate order i, f, g, o.
fn lstm_step(w: &ModelWeights, lstm: &str, x: &[f64], h: &mut [f64], c: &mut [f64]) {
    let a = linear(
        w.get(&format!("{lstm}.weight_ih_l0")),
        w.get(&format!("{lstm}.bias_ih_l0")),
        x,
    );
    let b = linear(
        w.get(&format!("{lstm}.weight_hh_l0")),
        w.get(&format!("{lstm}.bias_hh_l0")),
        h,
    );
    let n = h.len();
    let g: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x + y).collect();
    for k in 0..n {
        let i = sigmoid(g[k]);
        let f = sigmoid(g[n + k]);
        let gg = g[2 * n + k].tanh();
        let o = sigmoid(g[3 * n + k]);
        c[k] = f * c[k] + i * gg;
        h[k] = o * c[k].tanh();
    }
}

/// Unsplit `PoolHiddenNet` under `prefix`: `hs` `[n][H]`, `pos` `[n][2]` → `[n][B]`.
fn pool(w: &ModelWeights, prefix: &str, hs: &[Vec<f64>], pos: &[[f64; 2]]) -> Vec<Vec<f64>> {
    let n = hs.len();
    (0..n)
        .map(|i| {
            let mut best: Option<Vec<f64>> = None;
            for j in 0..n {
                let d = [pos[j][0] - pos[i][0], pos[j][1] - pos[i][1]];
                let mut x = embed(w, prefix, d);
                x.extend_from_slice(&hs[j]);
                let u = mlp(w, &format!("{prefix}.mlp_pre_pool"), &x);
                best = Some(match best {
                    None => u,
                    Some(m) => m.iter().zip(&u).map(|(a, b)| nan_max(*a, *b)).collect(),
                });
            }
            best.unwrap_or_default()
        })
        .collect()
}

/// One full generator call (in f64) on window `win` (`[n][T_OBS][2]`, metres): predicts `pred_len`
/// positions per agent (`[n][pred_len][2]`). If `ego_future` is given (`[pred_len][2]`), the
/// ego's displacement and position are overwritten by it after every decoder step (the
/// student's interactive mode).
#[must_use]
pub fn generator(
    w: &ModelWeights,
    z: &[f32],
    win: &[Vec<[f64; 2]>],
    ego_future: Option<&[[f64; 2]]>,
) -> Vec<Vec<[f64; 2]>> {
    let cfg = w.config();
    let n = win.len();
    // Encoder over relative displacements, rel[0] = 0.
    let h_enc: Vec<Vec<f64>> = win
        .iter()
        .map(|traj| {
            let mut h = vec![0.0f64; cfg.encoder_h_dim];
            let mut c = vec![0.0f64; cfg.encoder_h_dim];
            for t in 0..T_OBS {
                let d = if t == 0 {
                    [0.0, 0.0]
                } else {
                    [traj[t][0] - traj[t - 1][0], traj[t][1] - traj[t - 1][1]]
                };
                let x = embed(w, "encoder", d);
                lstm_step(w, "encoder.encoder", &x, &mut h, &mut c);
            }
            h
        })
        .collect();
    let mut pos: Vec<[f64; 2]> = win.iter().map(|t| t[T_OBS - 1]).collect();
    let pooled = pool(w, "pool_net", &h_enc, &pos);
    let mut h: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            let mut x = h_enc[i].clone();
            x.extend_from_slice(&pooled[i]);
            let mut h0 = mlp(w, "mlp_decoder_context", &x);
            h0.extend(z.iter().map(|&v| f64::from(v)));
            h0
        })
        .collect();
    let mut c: Vec<Vec<f64>> = vec![vec![0.0f64; cfg.decoder_h_dim]; n];
    let mut d: Vec<[f64; 2]> = win
        .iter()
        .map(|t| {
            [
                t[T_OBS - 1][0] - t[T_OBS - 2][0],
                t[T_OBS - 1][1] - t[T_OBS - 2][1],
            ]
        })
        .collect();
    let mut out = vec![Vec::with_capacity(cfg.pred_len); n];
    for step in 0..cfg.pred_len {
        let prev_ego = pos[0];
        for i in 0..n {
            let x = embed(w, "decoder", d[i]);
            lstm_step(w, "decoder.decoder", &x, &mut h[i], &mut c[i]);
            let dp = linear(
                w.get("decoder.hidden2pos.weight"),
                w.get("decoder.hidden2pos.bias"),
                &h[i],
            );
            d[i] = [dp[0], dp[1]];
            pos[i] = [pos[i][0] + dp[0], pos[i][1] + dp[1]];
        }
        if let Some(ego) = ego_future {
            d[0] = [ego[step][0] - prev_ego[0], ego[step][1] - prev_ego[1]];
            pos[0] = ego[step];
        }
        out.iter_mut().zip(&pos).for_each(|(o, p)| o.push(*p));
        if cfg.pool_every_timestep {
            let pooled = pool(w, "decoder.pool_net", &h, &pos);
            for i in 0..n {
                let mut x = h[i].clone();
                x.extend_from_slice(&pooled[i]);
                h[i] = mlp(w, "decoder.mlp", &x);
            }
        }
    }
    out
}

/// Converts a history to the `[n][T_OBS][2]` window of [`generator`].
fn window(history: &History) -> Vec<Vec<[f64; 2]>> {
    (0..history.n_agents())
        .map(|a| (0..T_OBS).map(|t| history.at(a, t)).collect())
        .collect()
}

/// Interactive prediction by the literal networks: the teacher's recursion (a full
/// generator call per step, ego replaced by the candidate) or the student's one pass with
/// ego substitution, whichever `w` holds. `z` is the noise (`[noise_dim]`), `candidates`
/// `[batch, t_plan, 2]` metres; returns `[batch, n_agents - 1, t_plan, 2]` metres.
///
/// # Errors
/// The input errors of [`Predictor::predict`](crate::Predictor::predict), and
/// [`PredictorError::InputShape`] if `z` has the wrong length.
pub fn predict(
    w: &ModelWeights,
    z: &[f32],
    history: &History,
    candidates: &[f64],
) -> Result<Vec<f64>> {
    predict_over(w, z, history, candidates, w.config().t_plan)
}

/// [`predict`] over `horizon` steps: a teacher's recursion rolled out `horizon` times
/// (`candidates` `[batch, horizon, 2]` metres; returns `[batch, n_agents - 1, horizon, 2]`
/// metres); a student only over its own `t_plan`.
///
/// # Errors
/// As [`predict`]; [`PredictorError::Horizon`] outside `1..=MAX_HORIZON`;
/// [`PredictorError::FixedHorizon`] for a student asked for another horizon.
pub fn predict_over(
    w: &ModelWeights,
    z: &[f32],
    history: &History,
    candidates: &[f64],
    horizon: usize,
) -> Result<Vec<f64>> {
    let cfg = w.config();
    crate::check_horizon(horizon)?;
    if cfg.kind == ModelKind::Student && horizon != cfg.t_plan {
        return Err(PredictorError::FixedHorizon {
            predictor: "student",
            got: horizon,
            predicts: cfg.t_plan,
        });
    }
    if z.len() != cfg.noise_dim {
        return Err(PredictorError::InputShape {
            what: "noise",
            shape: format!("[{}]", cfg.noise_dim),
            expected: cfg.noise_dim,
            got: z.len(),
        });
    }
    let n = history.n_agents();
    let t = horizon;
    let mut out = vec![0.0f64; (candidates.len() / (2 * t).max(1)) * (n - 1) * t * 2];
    let batch = check_batch(candidates, &out, t, n, history.at(0, T_OBS - 1))?;
    let win0 = window(history);
    for b in 0..batch {
        let cand: Vec<[f64; 2]> = (0..t)
            .map(|k| {
                let o = (b * t + k) * 2;
                [candidates[o], candidates[o + 1]]
            })
            .collect();
        let future: Vec<Vec<[f64; 2]>> = match cfg.kind {
            ModelKind::Student => generator(w, z, &win0, Some(&cand)),
            ModelKind::Teacher => {
                let mut win = win0.clone();
                let mut fut = vec![Vec::with_capacity(t); n];
                for c in &cand {
                    let q = generator(w, z, &win, None);
                    for a in 0..n {
                        let p = if a == 0 { *c } else { q[a][0] };
                        fut[a].push(p);
                        win[a].remove(0);
                        win[a].push(p);
                    }
                }
                fut
            }
        };
        for (a, traj) in future.iter().enumerate().skip(1) {
            for (k, p) in traj.iter().enumerate() {
                let o = (((b * (n - 1)) + a - 1) * t + k) * 2;
                out[o..o + 2].copy_from_slice(p);
            }
        }
    }
    Ok(out)
}
