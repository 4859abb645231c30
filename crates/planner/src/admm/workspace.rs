//! The per-call workspace (allocated once per MPC call, reused by every iteration): the ADMM
//! iterates, the Z-update's curvature (H = 2W + ρCᵀC, its Gershgorin bound and Cholesky
//! inverses), the two input QPs and the scratch buffers.

use nalgebra::DMatrix;

use crate::model::State;
use crate::settings::PlannerSettings;

use super::constraint::{Evaluation, SafetyEval, SafetyRow};
use super::linearised::LinearisedProblem;

/// The ADMM iterates (Δ, α, Z, μ) in the call's frame.
pub(crate) struct Iterates {
    /// Steering `[T]` (rad).
    pub delta: Vec<f64>,
    /// Acceleration `[T]` (m/s²).
    pub accel: Vec<f64>,
    /// States z_1..z_T `[T]`.
    pub z: Vec<State>,
    /// Duals μ `[T]`.
    pub duals: Vec<State>,
}

impl Iterates {
    /// The start: nominal inputs, the nominal roll-out clamped into the state bounds, the warm
    /// duals.
    pub(crate) fn start(lp: &LinearisedProblem) -> Self {
        Self {
            delta: lp.nominal_delta.clone(),
            accel: lp.nominal_accel.clone(),
            z: lp
                .nominal_rollout
                .iter()
                .enumerate()
                .map(|(k, r)| lp.clamp(k, r))
                .collect(),
            duals: lp.warm_duals.clone(),
        }
    }
}

/// Curvature of G(Z) = Φ3(Z) + μᵀF + ρ/2‖F‖²: its Hessian H = 2W + ρCᵀC is constant for the
/// call.
pub(crate) struct Curvature {
    /// Gershgorin bound L ≥ λ_max(H) (the plain gradient step is 1/L).
    pub lipschitz: f64,
    /// H⁻¹ (`[4T, 4T]` row-major) for the Newton step; `None` without Hessian scaling (or when
    /// the Cholesky factorisation fails).
    pub newton: Option<Vec<f64>>,
    /// H_pin⁻¹ with H_pin = H + w_pin·P (P selects the positions): minimising G plus a pull of
    /// the positions towards a target keeps the states dynamically consistent.
    pub pinned: Option<Vec<f64>>,
}

impl Curvature {
    pub(crate) fn new(s: &PlannerSettings, lp: &LinearisedProblem) -> Self {
        let t = lp.horizon;
        let m4 = 4 * t;
        let h = hessian(s, lp);
        let lipschitz = (0..m4)
            .map(|i| (0..m4).map(|j| h[(i, j)].abs()).sum::<f64>())
            .fold(0.0, f64::max)
            .max(1e-9);
        let mut pinned = h.clone();
        for k in 0..t {
            pinned[(4 * k, 4 * k)] += s.admm.pin_weight;
            pinned[(4 * k + 1, 4 * k + 1)] += s.admm.pin_weight;
        }
        Self {
            lipschitz,
            newton: flat_inverse(h),
            pinned: flat_inverse(pinned),
        }
    }
}

/// H = 2W + ρCᵀC of the call (`[4T, 4T]`, T = `lp.horizon`): the Hessian of G in Z, with W
/// the state weights and C the matrix of Z in the linearised dynamics residual F.
pub(crate) fn hessian(s: &PlannerSettings, lp: &LinearisedProblem) -> DMatrix<f64> {
    let m4 = 4 * lp.horizon;
    let c = lp.linearisation.dense_c();
    let mut h = DMatrix::<f64>::zeros(m4, m4);
    for i in 0..m4 {
        for j in 0..m4 {
            let mut v: f64 = (0..m4).map(|r| c[r * m4 + i] * c[r * m4 + j]).sum();
            v *= s.admm.rho;
            if i == j {
                v += 2.0 * lp.weights[i % 4];
            }
            h[(i, j)] = v;
        }
    }
    h
}

/// The inverse of a symmetric positive-definite matrix, flat row-major; `None` when the
/// Cholesky factorisation fails.
fn flat_inverse(m: DMatrix<f64>) -> Option<Vec<f64>> {
    let n = m.nrows();
    m.cholesky().map(|ch| {
        let inv = ch.inverse();
        (0..n * n).map(|k| inv[(k / n, k % n)]).collect()
    })
}

/// `out = M v` for a flat row-major `[4T, 4T]` matrix and stacked states.
pub(crate) fn mat_vec(m: &[f64], v: &[State], out: &mut [State]) {
    let n = 4 * v.len();
    for r in 0..n {
        let row = &m[r * n..(r + 1) * n];
        let mut acc = 0.0;
        for (c, mv) in row.iter().enumerate() {
            acc += mv * v[c / 4][c % 4];
        }
        out[r / 4][r % 4] = acc;
    }
}

/// Scratch buffers, `[T]` each.
pub(crate) struct Scratch {
    /// F(Δ, α, Z) at the current iterates.
    pub residual: Vec<State>,
    /// μ + ρF, and F at a trial point.
    pub weighted: Vec<State>,
    /// ∇G at the current Z.
    pub gradient: Vec<State>,
    /// H⁻¹∇G.
    pub newton_step: Vec<State>,
    /// H_pin⁻¹ times `pinned_rhs`.
    pub pinned_step: Vec<State>,
    /// ∇G plus the pull of the positions towards a pushed target.
    pub pinned_rhs: Vec<State>,
    /// The safety rows of `best`.
    pub best_rows: Vec<SafetyRow>,
    /// A trial Z.
    pub trial: Vec<State>,
    /// The best trial of a restoration step.
    pub best: Vec<State>,
    /// ∂(violation)/∂(x, y) at `best`.
    pub best_violation_gradient: Vec<[f64; 2]>,
    /// Z before the current Z-update.
    pub z_prev: Vec<State>,
    /// Linear term of an input QP.
    pub linear: Vec<f64>,
    /// Solution of an input QP.
    pub solution: Vec<f64>,
}

impl Scratch {
    pub(crate) fn new(t: usize) -> Self {
        let states = || vec![State::zeros(); t];
        Self {
            residual: states(),
            weighted: states(),
            gradient: states(),
            newton_step: states(),
            pinned_step: states(),
            pinned_rhs: states(),
            best_rows: Vec::new(),
            trial: states(),
            best: states(),
            best_violation_gradient: vec![[0.0; 2]; t],
            z_prev: states(),
            linear: vec![0.0; t],
            solution: vec![0.0; t],
        }
    }
}

/// Everything one MPC call's ADMM loop reads and writes, allocated once per call.
pub(crate) struct Workspace {
    /// (Δ, α, Z, μ).
    pub iterates: Iterates,
    /// H, its bound and inverses.
    pub curvature: Curvature,
    /// Safety of the current Z.
    pub current: CurrentSafety,
    /// Scratch buffers.
    pub scratch: Scratch,
    /// ‖Z − Z_prev‖∞ of the last Z-update (∞ before the first).
    pub change: f64,
}

impl Workspace {
    /// The workspace of one call starting from `iterates`, whose Z has safety `current`.
    pub(crate) fn new(
        s: &PlannerSettings,
        lp: &LinearisedProblem,
        iterates: Iterates,
        current: CurrentSafety,
    ) -> Self {
        Self {
            curvature: Curvature::new(s, lp),
            iterates,
            current,
            scratch: Scratch::new(lp.horizon),
            change: f64::INFINITY,
        }
    }

    /// The dual update μ ← μ + ρF(Δ, α, Z); returns whether ADMM converged
    /// (‖F‖∞ ≤ eps_primal and ‖Z − Z_prev‖∞ ≤ eps_change).
    pub(crate) fn update_duals(&mut self, s: &PlannerSettings, lp: &LinearisedProblem) -> bool {
        let it = &mut self.iterates;
        let f = &mut self.scratch.residual;
        lp.linearisation.residual(&it.delta, &it.accel, &it.z, f);
        for (mu, fk) in it.duals.iter_mut().zip(f.iter()) {
            *mu += s.admm.rho * fk;
        }
        let primal = max_abs(f);
        self.change = max_diff(&it.z, &self.scratch.z_prev);
        primal <= s.admm.eps_primal && self.change <= s.admm.eps_change
    }
}

/// ‖v‖∞ over stacked states.
pub(crate) fn max_abs(v: &[State]) -> f64 {
    v.iter().map(|s| s.amax()).fold(0.0, f64::max)
}

/// ‖a − b‖∞ over stacked states.
pub(crate) fn max_diff(a: &[State], b: &[State]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).amax())
        .fold(0.0, f64::max)
}

/// The safety of the current Z, carried from one Z-update to the next.
pub(crate) struct CurrentSafety {
    /// Minimum b (`None` when nothing is checked).
    pub min_b: Option<f64>,
    /// Total violation at the Z-update's threshold.
    pub violation: f64,
    /// ∂(violation)/∂(x_k, y_k) `[T]`, prediction frozen.
    pub violation_gradient: Vec<[f64; 2]>,
    /// The safety rows of Z (pairs with b below `ROW_B`, linearised in the ego's position).
    pub rows: Vec<SafetyRow>,
}

impl CurrentSafety {
    /// The safety of the starting Z, evaluated by `safety`.
    pub(crate) fn new(evaluation: Evaluation, safety: &SafetyEval<'_>) -> Self {
        Self {
            min_b: evaluation.min_b,
            violation: evaluation.violation,
            violation_gradient: safety.violation_gradient.clone(),
            rows: safety.rows.clone(),
        }
    }

    pub(crate) fn is_safe(&self, threshold: f64) -> bool {
        self.min_b.is_none_or(|b| b > threshold)
    }
}
