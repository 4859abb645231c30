//! The Δ- and α-updates: each minimises the augmented Lagrangian over one input sequence
//! (the other and Z fixed), a box- and rate-constrained QP solved by Clarabel whose Hessian is
//! fixed for the call and whose linear term changes every iteration.

use std::time::Instant;

use crate::model::State;
use crate::qp::{BoxRateQp, QpFailure, QpName, RateBox};
use crate::settings::PlannerSettings;

use super::linearised::{LinearisedProblem, input_hessian};
use super::workspace::Workspace;

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
            Self::Steering => (s.cost.w_delta, s.cost.w_ddelta),
            Self::Acceleration => (s.cost.w_a, s.cost.w_da),
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
            .map(|k| s.admm.rho * self.column(lp, k).norm_squared())
            .collect();
        let (w, wd) = self.weights(s);
        let hessian = input_hessian(t, w, wd, &curvature);
        BoxRateQp::new(self.qp(), &hessian, t, self.bounds(lp))
    }
}

/// The two input QPs of the call.
pub(crate) struct InputQps {
    /// The Δ-update.
    pub delta: BoxRateQp,
    /// The α-update.
    pub accel: BoxRateQp,
}

impl InputQps {
    /// Builds both QPs (Hessians fixed for the call).
    ///
    /// # Errors
    /// The [`QpFailure`] of a QP Clarabel cannot set up.
    pub(crate) fn new(s: &PlannerSettings, lp: &LinearisedProblem) -> Result<Self, QpFailure> {
        Ok(Self {
            delta: Input::Steering.build_qp(s, lp)?,
            accel: Input::Acceleration.build_qp(s, lp)?,
        })
    }

    /// Clarabel solves so far (retries included).
    pub(crate) fn solves(&self) -> usize {
        self.delta.solves + self.accel.solves
    }

    /// The update of `input` (Δ or α) at ADMM iteration `iteration` on the workspace `ws`:
    /// with F(Δ, α, Z) recomputed, u ← the minimiser over the box/rate set of ½uᵀPu + qᵀu with
    /// q_k = (∂F_k/∂u_k)ᵀ(μ_k + ρ(F_k − (∂F_k/∂u_k) u_k)) and q_0 −= 2 w_d u_{−1}. Its wall time
    /// is added to `elapsed_s`.
    ///
    /// # Errors
    /// The [`QpFailure`] when Clarabel gives no usable solution.
    pub(crate) fn update(
        &mut self,
        input: Input,
        s: &PlannerSettings,
        lp: &LinearisedProblem,
        ws: &mut Workspace,
        iteration: usize,
        elapsed_s: &mut f64,
    ) -> Result<(), QpFailure> {
        let t0 = Instant::now();
        let it = &mut ws.iterates;
        let x = &mut ws.scratch;
        lp.linearisation
            .residual(&it.delta, &it.accel, &it.z, &mut x.residual);
        let (u, qp) = match input {
            Input::Steering => (&mut it.delta, &mut self.delta),
            Input::Acceleration => (&mut it.accel, &mut self.accel),
        };
        for (k, (q, uk)) in x.linear.iter_mut().zip(u.iter()).enumerate() {
            let column = input.column(lp, k);
            let wk = it.duals[k] + s.admm.rho * (x.residual[k] - column * *uk);
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
