//! The Δ- and α-updates: each minimises the augmented Lagrangian over one input sequence
//! (the other and Z fixed), a box- and rate-constrained QP solved by Clarabel whose Hessian is
//! fixed for the call and whose linear term changes every iteration.

use std::time::Instant;

use crate::model::State;
use crate::qp::{BoxRateQp, QpFailure, QpName, RateBox};
use crate::settings::PlannerSettings;

use super::linearised::LinearisedProblem;
use super::workspace::Workspace;

/// Φ1 or Φ2 of an input sequence: w Σu² + w_d Σ(u_k − u_{k−1})², u_{−1} = `prev`.
pub(crate) fn input_cost(u: &[f64], prev: f64, w: f64, wd: f64) -> f64 {
    let mut p = prev;
    let mut c = 0.0;
    for &x in u {
        c += w * x * x + wd * (x - p) * (x - p);
        p = x;
    }
    c
}

/// Hessian (`[t, t]` row-major) of w Σu² + w_d Σ(u_k − u_{k−1})², plus `extra` on the
/// diagonal.
pub(crate) fn input_hessian(t: usize, w: f64, wd: f64, extra: &[f64]) -> Vec<f64> {
    let mut p = vec![0.0; t * t];
    for k in 0..t {
        let dd = 1.0 + if k + 1 < t { 1.0 } else { 0.0 };
        p[k * t + k] = 2.0 * (w + wd * dd) + extra[k];
        if k + 1 < t {
            p[k * t + k + 1] = -2.0 * wd;
            p[(k + 1) * t + k] = -2.0 * wd;
        }
    }
    p
}

/// One of the two input sequences.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Input {
    /// Δ = (δ_0..δ_{T−1}), rad; its column of F at step k is `jd[k]`.
    Steering,
    /// α = (a_0..a_{T−1}), m/s²; its column of F is the constant `ja`.
    Acceleration,
}

impl Input {
    /// The QP's name.
    pub(crate) fn qp(self) -> QpName {
        match self {
            Self::Steering => QpName::Delta,
            Self::Acceleration => QpName::Alpha,
        }
    }

    /// ∂F_k/∂u_k.
    fn column(self, lp: &LinearisedProblem, k: usize) -> State {
        match self {
            Self::Steering => lp.linearisation.jd[k],
            Self::Acceleration => lp.linearisation.ja,
        }
    }

    /// (w, w_d) of Φ1 or Φ2.
    fn weights(self, s: &PlannerSettings) -> (f64, f64) {
        match self {
            Self::Steering => (s.w_delta, s.w_ddelta),
            Self::Acceleration => (s.w_a, s.w_da),
        }
    }

    /// The box and rate bounds.
    fn bounds(self, lp: &LinearisedProblem) -> RateBox {
        match self {
            Self::Steering => lp.delta_box,
            Self::Acceleration => lp.accel_box,
        }
    }

    /// The QP of this input for one call: Hessian 2(w I + w_d DᵀD) + ρ diag(‖∂F_k/∂u_k‖²).
    pub(crate) fn build_qp(
        self,
        s: &PlannerSettings,
        lp: &LinearisedProblem,
    ) -> Result<BoxRateQp, QpFailure> {
        let t = lp.horizon;
        let curvature: Vec<f64> = (0..t)
            .map(|k| s.rho * self.column(lp, k).norm_squared())
            .collect();
        let (w, wd) = self.weights(s);
        let hessian = input_hessian(t, w, wd, &curvature);
        BoxRateQp::new(self.qp(), &hessian, t, self.bounds(lp))
    }
}

impl Workspace {
    /// The update of `input` (Δ or α) at ADMM iteration `iteration`: with F(Δ, α, Z)
    /// recomputed, u ← the minimiser over the box/rate set of ½uᵀPu + qᵀu with
    /// q_k = (∂F_k/∂u_k)ᵀ(μ_k + ρ(F_k − (∂F_k/∂u_k) u_k)) and q_0 −= 2 w_d u_{−1}. Its wall time
    /// is added to `elapsed_s`.
    ///
    /// # Errors
    /// The [`QpFailure`] when Clarabel gives no usable solution.
    pub(crate) fn update_input(
        &mut self,
        input: Input,
        s: &PlannerSettings,
        lp: &LinearisedProblem,
        iteration: usize,
        elapsed_s: &mut f64,
    ) -> Result<(), QpFailure> {
        let t0 = Instant::now();
        let it = &mut self.iterates;
        let x = &mut self.scratch;
        lp.linearisation
            .residual(&it.delta, &it.accel, &it.z, &mut x.residual);
        let (u, qp) = match input {
            Input::Steering => (&mut it.delta, &mut self.qps.delta),
            Input::Acceleration => (&mut it.accel, &mut self.qps.accel),
        };
        for (k, (q, uk)) in x.linear.iter_mut().zip(u.iter()).enumerate() {
            let column = input.column(lp, k);
            let wk = it.duals[k] + s.rho * (x.residual[k] - column * *uk);
            *q = column.dot(&wk);
        }
        let (_, wd) = input.weights(s);
        x.linear[0] -= 2.0 * wd * input.bounds(lp).prev;
        qp.solve(&x.linear, &mut x.solution, iteration)?;
        u.copy_from_slice(&x.solution);
        *elapsed_s += t0.elapsed().as_secs_f64();
        Ok(())
    }
}
