//! The Z-update: projected descent on G(Z) = Φ3(Z) + μᵀF + ρ/2‖F‖² whose every trial point is
//! checked by the predictor. From a safe Z it accepts the first safe trial that lowers G
//! ([`Trial`] kinds in order, step halvings within a kind); from an unsafe Z it runs the
//! feasibility restoration of [`super::restoration`].

use std::time::Instant;

use nudge_predictor::Predictor;

use crate::error::PlannerError;
use crate::model::State;
use crate::settings::PlannerSettings;

use super::constraint::SafetyEval;
use super::linearised::LinearisedProblem;
use super::problem::PhaseTimings;
use super::projection::{Projected, project};
use super::restoration::restore;
use super::safe_step::linearised_step;
use super::workspace::{CurrentSafety, Curvature, Scratch, Workspace, mat_vec, max_diff};

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
            g += mu.dot(f) + 0.5 * self.s.rho * f.norm_squared();
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
            *w = mu + self.s.rho * f;
        }
        self.lp.linearisation.apply_ct(weighted, gradient);
        for (g, zk) in gradient.iter_mut().zip(z) {
            let e = zk - self.lp.reference;
            *g += 2.0 * self.lp.weights.component_mul(&e);
        }
    }
}

/// A kind of trial direction d of the descent from a safe Z (Z⁺ = Π(Z − η·d)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Trial {
    /// d = H⁻¹∇G with η = 1, 1/2, ...: η = 1 is G's exact minimiser when no bound is active.
    Newton,
    /// d = the linearised-safety step ([`super::safe_step`]) with η = 1, 1/2, ...: G's
    /// minimiser subject to the safety rows of the current Z, so that Z slides along the
    /// constraint boundary instead of stalling on it.
    SafeStep,
    /// With `z_cuts`: the projection onto the linearised safe set ([`super::projection`]):
    /// the linearised-safety step at η = 1, solved again with the cuts of its unsafe trial
    /// points, then halved (η = 1/2, ...).
    Projection,
    /// With `z_cuts`: the Newton step's halvings (η = 1/2, ...), after the projection.
    NewtonHalved,
    /// d = Z − Π(roll-out of the current (Δ, α)) with η = 1 only: the nonlinear roll-out of
    /// the inputs as a trial point (F there is the linearisation error alone).
    RollOut,
    /// d = H_pin⁻¹∇G with η = 1 only: minimises G while holding the positions near the current
    /// (safe) ones, so that ψ and v become consistent with them.
    PinnedNewton,
    /// d = ∇G with η = 1/L, 1/(2L), ... (when Hessian scaling is off).
    Gradient,
}

impl Trial {
    /// The kinds tried in order: the roll-out trial (used only with `z_rollout_trial`, in a
    /// Z-update's first step), then the Newton pair with Hessian scaling, else the gradient;
    /// with `z_safe_step` the safe step after the Newton step (after the gradient step).
    /// With `z_cuts` (and `z_safe_step`, Hessian scaling) the full Newton step, then the
    /// projection, then the Newton step's halvings.
    fn sequence(s: &PlannerSettings, curvature: &Curvature) -> &'static [Trial] {
        if curvature.newton.is_some() && s.z_safe_step && s.z_cuts > 0 {
            return &[
                Self::RollOut,
                Self::Newton,
                Self::Projection,
                Self::NewtonHalved,
                Self::PinnedNewton,
            ];
        }
        match (curvature.newton.is_some(), s.z_safe_step) {
            (true, true) => &[
                Self::RollOut,
                Self::Newton,
                Self::SafeStep,
                Self::PinnedNewton,
            ],
            (true, false) => &[Self::RollOut, Self::Newton, Self::PinnedNewton],
            (false, true) => &[Self::RollOut, Self::Gradient, Self::SafeStep],
            (false, false) => &[Self::RollOut, Self::Gradient],
        }
    }

    /// The first step length η.
    fn first_step(self, curvature: &Curvature) -> f64 {
        match self {
            Self::Newton | Self::PinnedNewton | Self::SafeStep | Self::RollOut => 1.0,
            Self::Gradient => 1.0 / curvature.lipschitz,
            Self::Projection | Self::NewtonHalved => 0.5,
        }
    }

    /// How many times η is halved after the first trial.
    fn halvings(self, s: &PlannerSettings) -> usize {
        match self {
            Self::PinnedNewton | Self::RollOut => 0,
            Self::Newton if s.z_safe_step && s.z_cuts > 0 => 0,
            Self::Newton | Self::Gradient | Self::SafeStep => s.pgd_halvings,
            Self::Projection | Self::NewtonHalved => s.pgd_halvings.saturating_sub(1),
        }
    }
}

/// Descent from a safe Z: the first trial (kinds in [`Trial::sequence`] order, η halved within
/// a kind) that lowers G and is safe replaces Z. A trial that does not move Z (every step
/// component held by the bounds) ends the search. Returns whether Z moved.
#[allow(clippy::too_many_arguments)]
fn descend(
    g: &Lagrangian<'_>,
    curvature: &Curvature,
    z: &mut [State],
    g_current: f64,
    scratch: &mut Scratch,
    current: &mut CurrentSafety,
    safety: &mut SafetyEval<'_>,
    predictor: &mut dyn Predictor,
    first: bool,
) -> Result<bool, PlannerError> {
    for &trial in Trial::sequence(g.s, curvature) {
        if trial == Trial::SafeStep && !safe_direction(g, curvature, current, safety, scratch) {
            continue;
        }
        if trial == Trial::Projection {
            match project(
                g, curvature, z, g_current, scratch, current, safety, predictor,
            )? {
                Projected::Moved => return Ok(true),
                Projected::NoStep => continue,
                Projected::Rejected => {}
            }
        }
        if trial == Trial::RollOut {
            if !g.s.z_rollout_trial || !first {
                continue;
            }
            for ((d, zk), r) in scratch
                .rollout_step
                .iter_mut()
                .zip(z.iter())
                .zip(&scratch.input_rollout)
            {
                *d = zk - r;
            }
        }
        let direction = match trial {
            Trial::Newton | Trial::NewtonHalved => &scratch.newton_step,
            Trial::Projection => &scratch.safe_step,
            Trial::PinnedNewton => &scratch.pinned_step,
            Trial::Gradient => &scratch.gradient,
            Trial::SafeStep => &scratch.safe_step,
            Trial::RollOut => &scratch.rollout_step,
        };
        let mut eta = trial.first_step(curvature);
        for _ in 0..=trial.halvings(g.s) {
            g.lp.project_step(z, direction, eta, &mut scratch.trial);
            if max_diff(&scratch.trial, z) < 1e-12 {
                if trial == Trial::RollOut {
                    break;
                }
                return Ok(false);
            }
            if g.value(&scratch.trial, &mut scratch.weighted) < g_current {
                let e = safety.eval(predictor, &scratch.trial)?;
                if e.is_safe(safety.threshold()) {
                    z.copy_from_slice(&scratch.trial);
                    current.min_b = e.min_b;
                    current.violation = 0.0;
                    current.rows.clone_from(&safety.rows);
                    return Ok(true);
                }
            }
            eta *= 0.5;
        }
    }
    Ok(false)
}

/// Writes the linearised-safety step ([`super::safe_step`]) from the current Z (whose safety,
/// rows included, is `current`, and whose ∇G is in `scratch.gradient`) into
/// `scratch.safe_step`; `false` without Hessian scaling or when no step is defined.
pub(crate) fn safe_direction(
    g: &Lagrangian<'_>,
    curvature: &Curvature,
    current: &CurrentSafety,
    safety: &SafetyEval<'_>,
    scratch: &mut Scratch,
) -> bool {
    let Some(inverse) = curvature.newton.as_ref() else {
        return false;
    };
    linearised_step(
        inverse,
        &scratch.gradient,
        &current.rows,
        safety.threshold() + g.s.z_step_margin,
        &mut scratch.safe_step,
    )
}

impl Workspace {
    /// One Z-update (`pgd_steps` descent or restoration steps at most, ending early when Z
    /// does not move); its wall time is added to `timings`.
    pub(crate) fn update_z(
        &mut self,
        s: &PlannerSettings,
        lp: &LinearisedProblem,
        safety: &mut SafetyEval<'_>,
        predictor: &mut dyn Predictor,
        timings: &mut PhaseTimings,
    ) -> Result<(), PlannerError> {
        let t0 = Instant::now();
        let Self {
            iterates,
            curvature,
            scratch,
            current,
            ..
        } = self;
        scratch.z_prev.copy_from_slice(&iterates.z);
        let g = Lagrangian {
            s,
            lp,
            delta: &iterates.delta,
            accel: &iterates.accel,
            duals: &iterates.duals,
        };
        let z = &mut iterates.z;
        let mut g_current = g.value(z, &mut scratch.residual);
        for step in 0..s.pgd_steps {
            g.gradient(
                z,
                &scratch.residual,
                &mut scratch.weighted,
                &mut scratch.gradient,
            );
            if let Some(h) = curvature.newton.as_ref() {
                mat_vec(h, &scratch.gradient, &mut scratch.newton_step);
            }
            if let Some(h) = curvature.pinned.as_ref() {
                mat_vec(h, &scratch.gradient, &mut scratch.pinned_step);
            }
            let moved = if current.is_safe(safety.threshold()) {
                descend(
                    &g,
                    curvature,
                    z,
                    g_current,
                    scratch,
                    current,
                    safety,
                    predictor,
                    step == 0,
                )?
            } else {
                restore(&g, curvature, z, scratch, current, safety, predictor)?
            };
            if !moved {
                break;
            }
            g_current = g.value(z, &mut scratch.residual);
        }
        let dz = t0.elapsed().as_secs_f64();
        timings.z_s += dz;
        timings.z_updates_s.push(dz);
        Ok(())
    }
}
