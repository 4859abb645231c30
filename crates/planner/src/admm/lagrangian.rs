//! The augmented Lagrangian G(Z) = Φ3(Z) + μᵀF + ρ/2‖F‖² of the Z-update, the inputs and the
//! duals fixed: its value and gradient, shared by the descent ([`super::z_update`]) and the
//! feasibility restoration ([`super::restoration`]).

use crate::model::State;
use crate::settings::PlannerSettings;

use super::linearised::LinearisedProblem;

/// The augmented Lagrangian as a function of Z, the inputs and duals fixed.
pub(crate) struct Lagrangian<'a> {
    pub s: &'a PlannerSettings,
    pub lp: &'a LinearisedProblem,
    pub delta: &'a [f64],
    pub accel: &'a [f64],
    pub duals: &'a [State],
}

impl Lagrangian<'_> {
    /// G(Z); leaves F(Δ, α, Z) in `residual`.
    pub(crate) fn value(&self, z: &[State], residual: &mut [State]) -> f64 {
        self.lp
            .linearisation
            .residual(self.delta, self.accel, z, residual);
        let mut g = self.lp.tracking_cost(z);
        for (mu, f) in self.duals.iter().zip(residual.iter()) {
            g += mu.dot(f) + 0.5 * self.s.admm.rho * f.norm_squared();
        }
        g
    }

    /// ∇G = 2W(Z − Z_ref) + Cᵀ(μ + ρF) into `gradient`, F = `residual` (at `z`), using
    /// `weighted` as scratch.
    pub(crate) fn gradient(
        &self,
        z: &[State],
        residual: &[State],
        weighted: &mut [State],
        gradient: &mut [State],
    ) {
        for ((w, mu), f) in weighted.iter_mut().zip(self.duals).zip(residual) {
            *w = mu + self.s.admm.rho * f;
        }
        self.lp.linearisation.apply_ct(weighted, gradient);
        for (g, zk) in gradient.iter_mut().zip(z) {
            let e = zk - self.lp.reference;
            *g += 2.0 * self.lp.weights.component_mul(&e);
        }
    }
}
