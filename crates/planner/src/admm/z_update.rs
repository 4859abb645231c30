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
use super::lagrangian::Lagrangian;
use super::linearised::LinearisedProblem;
use super::problem::PhaseTimings;
use super::restoration::restore;
use super::workspace::{CurrentSafety, Curvature, Scratch, Workspace, mat_vec, max_diff};

/// A kind of trial direction d of the descent from a safe Z (Z⁺ = Π(Z − η·d)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Trial {
    /// d = H⁻¹∇G with η = 1, 1/2, ...: η = 1 is G's exact minimiser when no bound is active.
    Newton,
    /// d = H_pin⁻¹∇G with η = 1 only: minimises G while holding the positions near the current
    /// (safe) ones, so that ψ and v become consistent with them.
    PinnedNewton,
    /// d = ∇G with η = 1/L, 1/(2L), ... (when H could not be inverted).
    Gradient,
}

impl Trial {
    /// The kinds tried in order: the Newton pair when H was inverted, else the gradient.
    fn sequence(curvature: &Curvature) -> &'static [Trial] {
        if curvature.newton.is_some() {
            &[Self::Newton, Self::PinnedNewton]
        } else {
            &[Self::Gradient]
        }
    }

    fn first_step(self, curvature: &Curvature) -> f64 {
        match self {
            Self::Newton | Self::PinnedNewton => 1.0,
            Self::Gradient => 1.0 / curvature.lipschitz,
        }
    }

    fn halvings(self, s: &PlannerSettings) -> usize {
        match self {
            Self::PinnedNewton => 0,
            Self::Newton | Self::Gradient => s.admm.pgd_halvings,
        }
    }
}

/// One descent step from a safe Z: the first trial of [`Trial::sequence`] whose point lowers G
/// and is safe by the predictor moves Z (`true`); `false` when none does.
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
) -> Result<bool, PlannerError> {
    for &trial in Trial::sequence(curvature) {
        let direction = match trial {
            Trial::Newton => &scratch.newton_step,
            Trial::PinnedNewton => &scratch.pinned_step,
            Trial::Gradient => &scratch.gradient,
        };
        let mut eta = trial.first_step(curvature);
        for _ in 0..=trial.halvings(g.s) {
            g.lp.project_step(z, direction, eta, &mut scratch.trial);
            if max_diff(&scratch.trial, z) < 1e-12 {
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
        for _ in 0..s.admm.pgd_steps {
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
                    &g, curvature, z, g_current, scratch, current, safety, predictor,
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
