//! The SQP refinement of the ADMM inputs on the nonlinear model (single shooting).
//!
//! ADMM returns (Δ, α) and states Z that satisfy the *linearised* dynamics only up to
//! `eps_primal`, linearised around the shifted previous plan; Z tends to lie on the safety
//! boundary, and the nonlinear roll-out of (Δ, α), which is what the vehicle does, drifts off
//! it over the horizon (by ~0.1 in b at the last step on validation scenes). When that
//! roll-out is not admissible, the refinement takes sequential-QP steps on the original
//! problem with the states eliminated: u = (Δ, α) ← u + du where du solves
//!
//! min J(u) + ∇J(u)·du + ½ duᵀ H du  (Gauss-Newton: Φ1, Φ2 exact, Φ3 through the roll-out's
//! sensitivities S_k = ∂z_k/∂u)
//! s.t. the input box and rate bounds, |du| ≤ the trust region,
//!      lower_k ≤ z_k + S_k du ≤ upper_k (y and ψ),
//!      b_ik + ∇b_ik · S_k^{xy} du ≥ safety_min + refine_margin for every (vehicle, step)
//!      with b_ik < [`ROW_B`](super::constraint::ROW_B) — the prediction and the ellipse
//!      held at the current roll-out.
//!
//! The state-bound and safety rows are elastic: each has a slack s ≥ 0 penalised by
//! [`SLACK_PENALTY`]·s, so the step is always defined and moves towards admissibility even
//! when the trust region cannot reach it at once (the input bounds and the trust region stay
//! hard). Each step is followed by a predictor call on the new roll-out (the prediction
//! depends on the ego's trajectory); the first admissible roll-out ends the refinement. One
//! step is a Clarabel QP in the 2T input changes and one slack per elastic row.

use clarabel::solver::{DefaultSolver, IPSolver, NonnegativeConeT};

use crate::model::{Bicycle, State};
use crate::qp::{
    box_rate_rows, clarabel_settings, repair_box_rate, triplets_csc, upper_csc, usable,
};
use crate::settings::PlannerSettings;

use super::constraint::SafetyRow;

/// Cost per unit of violation of an elastic row (units of J per m, rad or unit of b): large
/// against the cost changes a step makes, so a step removes violations first.
const SLACK_PENALTY: f64 = 1e4;
use super::linearised::{LinearisedProblem, half_extent_at, input_hessian};

/// The nonlinear roll-out (speed clamped at 0) of `delta`, `accel` (`[T]` each) from `start`
/// and its sensitivities: `sens[k][j]` = ∂z_{k+1}/∂u_j for u = (δ_0..δ_{T−1}, a_0..a_{T−1}),
/// exact (the bicycle's Jacobians along the roll-out), zero through a clamped speed.
pub(crate) fn rollout_sensitivities(
    model: &Bicycle,
    start: &State,
    delta: &[f64],
    accel: &[f64],
) -> (Vec<State>, Vec<Vec<State>>) {
    let t = delta.len();
    let mut rollout = Vec::with_capacity(t);
    let mut sens: Vec<Vec<State>> = vec![vec![State::zeros(); 2 * t]; t];
    let mut z = *start;
    for k in 0..t {
        let (jz, jd, ja) = model.jacobians(&z, delta[k]);
        if k > 0 {
            let (done, rest) = sens.split_at_mut(k);
            for (now, before) in rest[0].iter_mut().zip(&done[k - 1]) {
                *now = jz * *before;
            }
        }
        sens[k][k] += jd;
        sens[k][t + k] += ja;
        let raw = model.step(&z, delta[k], accel[k]);
        if raw[3] < 0.0 {
            for s in &mut sens[k] {
                s[3] = 0.0;
            }
        }
        z = model.advance(&z, delta[k], accel[k]);
        rollout.push(z);
    }
    (rollout, sens)
}

/// ∂/∂u of w Σu² + w_d Σ(u_k − u_{k−1})², u_{−1} = `prev`.
fn input_gradient(u: &[f64], prev: f64, w: f64, wd: f64) -> Vec<f64> {
    let t = u.len();
    (0..t)
        .map(|k| {
            let before = if k == 0 { prev } else { u[k - 1] };
            let mut g = 2.0 * w * u[k] + 2.0 * wd * (u[k] - before);
            if k + 1 < t {
                g -= 2.0 * wd * (u[k + 1] - u[k]);
            }
            g
        })
        .collect()
}

/// Sparse constraint rows as (row, column, value) triplets.
type Triplets = Vec<(usize, usize, f64)>;

/// One elastic row g·du ≤ h over the 2T input changes: (`g` `[2T]`, `h`), in the units of the
/// constrained quantity (m, rad or units of b).
type ElasticRow = (Vec<f64>, f64);

/// One refinement step from (`delta`, `accel`) with the safety `rows` of its roll-out; the
/// new inputs (within their box and rate bounds), or `None` when the QP has no usable
/// solution (e.g. the linearised constraints are infeasible within the trust region).
pub(crate) fn step(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
    delta: &[f64],
    accel: &[f64],
    rows: &[SafetyRow],
) -> Option<(Vec<f64>, Vec<f64>)> {
    let t = delta.len();
    let (rollout, sens) = rollout_sensitivities(model, &lp.start, delta, accel);
    let (p, q) = gauss_newton_objective(s, lp, delta, accel, &rollout, &sens);
    let (a, b) = hard_rows(s, lp, delta, accel);
    let mut elastic = state_bound_rows(lp, &rollout, &sens);
    elastic.extend(road_edge_rows(lp, &rollout, &sens));
    elastic.extend(safety_rows(s, &sens, rows));
    let qp = StepQp::with_slacks(p, q, a, b, &elastic);
    let x = qp.solve()?;
    let mut nd: Vec<f64> = delta.iter().zip(&x).map(|(u, d)| u + d).collect();
    let mut na: Vec<f64> = accel.iter().zip(&x[t..]).map(|(u, d)| u + d).collect();
    repair_box_rate(&mut nd, lp.delta_box);
    repair_box_rate(&mut na, lp.accel_box);
    Some((nd, na))
}

/// The Gauss-Newton model of J around u = (`delta`, `accel`) in du: (P `[2T, 2T]` dense
/// row-major, q `[2T]`) with J(u + du) ≈ J(u) + q·du + ½ duᵀ P du; the input terms exact,
/// the state terms through the roll-out's sensitivities `sens`.
fn gauss_newton_objective(
    s: &PlannerSettings,
    lp: &LinearisedProblem,
    delta: &[f64],
    accel: &[f64],
    rollout: &[State],
    sens: &[Vec<State>],
) -> (Vec<f64>, Vec<f64>) {
    let t = delta.len();
    let nv = 2 * t;
    let mut p = vec![0.0; nv * nv];
    let mut q = vec![0.0; nv];
    let zeros = vec![0.0; t];
    let hd = input_hessian(t, s.cost.w_delta, s.cost.w_ddelta, &zeros);
    let ha = input_hessian(t, s.cost.w_a, s.cost.w_da, &zeros);
    let gd = input_gradient(delta, lp.delta_box.prev, s.cost.w_delta, s.cost.w_ddelta);
    let ga = input_gradient(accel, lp.accel_box.prev, s.cost.w_a, s.cost.w_da);
    for i in 0..t {
        q[i] += gd[i];
        q[t + i] += ga[i];
        for j in 0..t {
            p[i * nv + j] += hd[i * t + j];
            p[(t + i) * nv + t + j] += ha[i * t + j];
        }
    }
    for (zk, sk) in rollout.iter().zip(sens) {
        for c in 1..4 {
            let w = lp.weights[c];
            if w == 0.0 {
                continue;
            }
            let e = zk[c] - lp.reference[c];
            for i in 0..nv {
                q[i] += 2.0 * w * e * sk[i][c];
                for j in 0..nv {
                    p[i * nv + j] += 2.0 * w * sk[i][c] * sk[j][c];
                }
            }
        }
    }
    (p, q)
}

/// The hard rows A du ≤ b on du `[2T]`: the input box and rate bounds on u + du (the rows of
/// u, shifted by A·u), then the trust region |du_i| ≤ `refine_trust_delta` (rad) or
/// `refine_trust_accel` (m/s²).
fn hard_rows(
    s: &PlannerSettings,
    lp: &LinearisedProblem,
    delta: &[f64],
    accel: &[f64],
) -> (Triplets, Vec<f64>) {
    let t = delta.len();
    let mut a = Vec::new();
    let mut b = Vec::new();
    box_rate_rows(&mut a, &mut b, 0, t, lp.delta_box);
    box_rate_rows(&mut a, &mut b, t, t, lp.accel_box);
    let u: Vec<f64> = delta.iter().chain(accel).copied().collect();
    for &(r, c, v) in &a {
        b[r] -= v * u[c];
    }
    for i in 0..2 * t {
        let r = if i < t {
            s.repair.refine_trust_delta
        } else {
            s.repair.refine_trust_accel
        };
        let row = b.len();
        a.push((row, i, 1.0));
        b.push(r);
        a.push((row + 1, i, -1.0));
        b.push(r);
    }
    (a, b)
}

/// Elastic rows of the finite state bounds on y (m) and ψ (rad), linearised at the roll-out:
/// per step, upper then lower bound of y, then of ψ.
fn state_bound_rows(
    lp: &LinearisedProblem,
    rollout: &[State],
    sens: &[Vec<State>],
) -> Vec<ElasticRow> {
    let mut elastic = Vec::new();
    for (k, (zk, sk)) in rollout.iter().zip(sens).enumerate() {
        for c in [1usize, 2] {
            for (sign, bound) in [(1.0, lp.upper[k][c]), (-1.0, lp.lower[k][c])] {
                if bound.is_finite() {
                    let g = sk.iter().map(|si| sign * si[c]).collect();
                    elastic.push((g, sign * (bound - zk[c])));
                }
            }
        }
    }
    elastic
}

/// Elastic rows (m) keeping the box's corners on the road, linearised at the roll-out: per
/// step, y ∓ e(ψ) against the right and left edges, e(ψ) = ½(L|sin ψ| + W|cos ψ|).
fn road_edge_rows(
    lp: &LinearisedProblem,
    rollout: &[State],
    sens: &[Vec<State>],
) -> Vec<ElasticRow> {
    let [length, width] = lp.ego_size;
    let mut elastic = Vec::with_capacity(2 * rollout.len());
    for (zk, sk) in rollout.iter().zip(sens) {
        let e = half_extent_at(lp.ego_size, zk[2]);
        let (sn, cs) = zk[2].sin_cos();
        let de = 0.5 * (length * cs * sn.signum() - width * sn * cs.signum());
        // Right edge: edges[0] − (y − e) ≤ 0; left edge: (y + e) − edges[1] ≤ 0.
        let right: Vec<f64> = sk.iter().map(|si| -(si[1] - de * si[2])).collect();
        elastic.push((right, (zk[1] - e) - lp.edges[0]));
        let left: Vec<f64> = sk.iter().map(|si| si[1] + de * si[2]).collect();
        elastic.push((left, lp.edges[1] - (zk[1] + e)));
    }
    elastic
}

/// Elastic rows (units of b) of the linearised safety b_ik + ∇b_ik · S_k^{xy} du ≥
/// `safety_min` + `refine_margin`, one per safety row, prediction and ellipse held.
fn safety_rows(s: &PlannerSettings, sens: &[Vec<State>], rows: &[SafetyRow]) -> Vec<ElasticRow> {
    let target = s.safety.safety_min + s.repair.refine_margin;
    rows.iter()
        .map(|r| {
            let g = sens[r.step]
                .iter()
                .map(|si| -(r.gradient[0] * si[0] + r.gradient[1] * si[1]))
                .collect();
            (g, r.b - target)
        })
        .collect()
}

/// The step's QP in x = (du `[2T]`, one slack per elastic row `[E]`): min ½ xᵀ P x + q·x
/// s.t. A x ≤ b.
struct StepQp {
    /// Dense P `[n, n]`, row-major.
    p: Vec<f64>,
    /// Linear cost `[n]`.
    q: Vec<f64>,
    /// The rows of A as triplets.
    a: Triplets,
    /// Right-hand sides `[m]`.
    b: Vec<f64>,
    /// Variables n = 2T + E.
    n: usize,
}

impl StepQp {
    /// Appends the `elastic` rows to the hard rows (`a`, `b`) of the objective (`p`
    /// `[2T, 2T]`, `q` `[2T]`), each as g·du − s ≤ h and −s ≤ 0 with its slack s costing
    /// [`SLACK_PENALTY`] per unit.
    fn with_slacks(
        p: Vec<f64>,
        mut q: Vec<f64>,
        mut a: Triplets,
        mut b: Vec<f64>,
        elastic: &[ElasticRow],
    ) -> Self {
        let nv = q.len();
        let n_all = nv + elastic.len();
        for (j, (g, h)) in elastic.iter().enumerate() {
            let row = b.len();
            for (i, gi) in g.iter().enumerate() {
                if *gi != 0.0 {
                    a.push((row, i, *gi));
                }
            }
            a.push((row, nv + j, -1.0));
            b.push(*h);
            a.push((row + 1, nv + j, -1.0));
            b.push(0.0);
        }
        let mut p_all = vec![0.0; n_all * n_all];
        for i in 0..nv {
            for j in 0..nv {
                p_all[i * n_all + j] = p[i * nv + j];
            }
        }
        q.resize(n_all, SLACK_PENALTY);
        Self {
            p: p_all,
            q,
            a,
            b,
            n: n_all,
        }
    }

    /// Solves with Clarabel (equilibrated first, then without); x `[n]`, or `None` when
    /// neither solve is usable.
    fn solve(self) -> Option<Vec<f64>> {
        let m = self.b.len();
        let pm = upper_csc(&self.p, self.n);
        let am = triplets_csc(m, self.n, self.a);
        let cones = [NonnegativeConeT(m)];
        for equilibrate in [true, false] {
            let Ok(mut solver) = DefaultSolver::new(
                &pm,
                &self.q,
                &am,
                &self.b,
                &cones,
                clarabel_settings(equilibrate),
            ) else {
                continue;
            };
            solver.solve();
            if usable(solver.solution.status) {
                return Some(std::mem::take(&mut solver.solution.x));
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sensitivities match central finite differences of the roll-out.
    #[test]
    fn sensitivities_match_finite_differences() {
        let model = Bicycle {
            l_f: 1.4,
            l_r: 1.4,
            dt: 0.3,
        };
        let start = State::new(0.0, 0.2, 0.05, 12.0);
        let delta = [0.03, 0.01, -0.02, 0.0, 0.04, -0.01];
        let accel = [0.5, -1.0, 0.2, 0.0, 1.0, -0.5];
        let (roll, sens) = rollout_sensitivities(&model, &start, &delta, &accel);
        let h = 1e-6;
        for j in 0..12 {
            let (mut dp, mut ap, mut dm, mut am) = (delta, accel, delta, accel);
            if j < 6 {
                dp[j] += h;
                dm[j] -= h;
            } else {
                ap[j - 6] += h;
                am[j - 6] -= h;
            }
            let (rp, _) = rollout_sensitivities(&model, &start, &dp, &ap);
            let (rm, _) = rollout_sensitivities(&model, &start, &dm, &am);
            for k in 0..6 {
                let fd = (rp[k] - rm[k]) / (2.0 * h);
                let err = (fd - sens[k][j]).amax();
                assert!(err < 1e-6 * (1.0 + fd.amax()), "k {k} j {j}: {err}");
            }
        }
        // The roll-out is the clamped one.
        let mut out = vec![State::zeros(); 6];
        model.rollout(&start, &delta, &accel, &mut out);
        assert_eq!(out, roll);
    }

    #[test]
    fn input_gradient_matches_finite_differences() {
        let u = [0.1, -0.2, 0.3, 0.0];
        let g = input_gradient(&u, 0.05, 3.0, 2.0);
        let cost = |u: &[f64]| super::super::linearised::input_cost(u, 0.05, 3.0, 2.0);
        for k in 0..4 {
            let (mut up, mut um) = (u, u);
            up[k] += 1e-6;
            um[k] -= 1e-6;
            let fd = (cost(&up) - cost(&um)) / 2e-6;
            assert!((fd - g[k]).abs() < 1e-6, "{k}: {fd} vs {}", g[k]);
        }
    }
}
