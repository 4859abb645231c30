//! Feasibility restoration: the Z-update's step from an unsafe Z. It tries, with shrinking
//! steps, moves that should reduce the total violation V = Σ max(0, b_min − b) and keeps the
//! one that reduces it most.

use nudge_predictor::Predictor;

use crate::error::PlannerError;
use crate::model::State;
use crate::settings::PlannerSettings;

use super::constraint::SafetyEval;
use super::lagrangian::Lagrangian;
use super::linearised::LinearisedProblem;
use super::workspace::{CurrentSafety, Curvature, Scratch, mat_vec};

/// A restoration move from Z.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Move {
    /// A descent step on G: Newton (η = 1, 1/2, ...) with Hessian scaling, else the gradient
    /// (η = 1/L, 1/(2L), ...).
    Descent,
    /// The positions pushed along the violation's descent direction −∇V/‖∇V‖∞ (prediction
    /// frozen) by a step of `restore_step`, `restore_step`/2, ... metres: through the pinned
    /// Newton step towards the pushed positions with Hessian scaling (ψ and v follow
    /// consistently), else by moving the positions alone.
    PushPositions,
}

/// The target of a push: `out = ∇G + w_pin·push·∇V/‖∇V‖∞` on the positions (the right-hand
/// side whose pinned Newton step moves the positions by about −push·∇V/‖∇V‖∞).
fn pushed_rhs(
    gradient: &[State],
    violation_gradient: &[[f64; 2]],
    pin_weight: f64,
    push: f64,
    norm: f64,
    out: &mut [State],
) {
    out.copy_from_slice(gradient);
    for (r, g) in out.iter_mut().zip(violation_gradient) {
        r[0] += pin_weight * push * g[0] / norm;
        r[1] += pin_weight * push * g[1] / norm;
    }
}

/// Writes the trial of `mv` (step sizes `eta` and `push`) into `scratch.trial`; `false` when
/// the move does not apply (no violation gradient to push along).
#[allow(clippy::too_many_arguments)]
fn trial_point(
    mv: Move,
    s: &PlannerSettings,
    lp: &LinearisedProblem,
    curvature: &Curvature,
    z: &[State],
    violation_gradient: &[[f64; 2]],
    (eta, push): (f64, f64),
    scratch: &mut Scratch,
) -> bool {
    match mv {
        Move::Descent => {
            let direction = if curvature.newton.is_some() {
                &scratch.newton_step
            } else {
                &scratch.gradient
            };
            lp.project_step(z, direction, eta, &mut scratch.trial);
        }
        Move::PushPositions => {
            let norm = violation_gradient
                .iter()
                .map(|g| g[0].abs().max(g[1].abs()))
                .fold(0.0, f64::max);
            if norm <= 0.0 || !norm.is_finite() {
                return false;
            }
            if let Some(pinned) = curvature.pinned.as_ref() {
                pushed_rhs(
                    &scratch.gradient,
                    violation_gradient,
                    s.admm.pin_weight,
                    push,
                    norm,
                    &mut scratch.pinned_rhs,
                );
                mat_vec(pinned, &scratch.pinned_rhs, &mut scratch.pinned_step);
                lp.project_step(z, &scratch.pinned_step, 1.0, &mut scratch.trial);
            } else {
                for (k, ((trial, zk), g)) in scratch
                    .trial
                    .iter_mut()
                    .zip(z)
                    .zip(violation_gradient)
                    .enumerate()
                {
                    *trial = *zk;
                    trial[0] -= push * g[0] / norm;
                    trial[1] -= push * g[1] / norm;
                    *trial = lp.clamp(k, trial);
                }
            }
        }
    }
    true
}

/// One restoration step from the unsafe Z: for `pgd_halvings + 1` rounds of halving step
/// sizes, every [`Move`]; the trial with the least total violation, if below the current one,
/// replaces Z (and `current`). Returns whether Z moved.
pub(crate) fn restore(
    g: &Lagrangian<'_>,
    curvature: &Curvature,
    z: &mut [State],
    scratch: &mut Scratch,
    current: &mut CurrentSafety,
    safety: &mut SafetyEval<'_>,
    predictor: &mut dyn Predictor,
) -> Result<bool, PlannerError> {
    let (s, lp) = (g.s, g.lp);
    let moves = [Move::Descent, Move::PushPositions];
    let mut best_violation = current.violation;
    let mut best_min_b = current.min_b;
    let mut found = false;
    let mut eta = if curvature.newton.is_some() {
        1.0
    } else {
        1.0 / curvature.lipschitz
    };
    let mut push = s.admm.restore_step;
    for _ in 0..=s.admm.pgd_halvings {
        for mv in moves {
            let (vg, step) = (&current.violation_gradient, (eta, push));
            if !trial_point(mv, s, lp, curvature, z, vg, step, scratch) {
                continue;
            }
            let e = safety.eval(predictor, &scratch.trial)?;
            if e.violation < best_violation {
                best_violation = e.violation;
                best_min_b = e.min_b;
                scratch.best.copy_from_slice(&scratch.trial);
                scratch
                    .best_violation_gradient
                    .copy_from_slice(&safety.violation_gradient);
                scratch.best_rows.clone_from(&safety.rows);
                found = true;
            }
        }
        eta *= 0.5;
        push *= 0.5;
    }
    if found {
        z.copy_from_slice(&scratch.best);
        current.violation = best_violation;
        current.min_b = best_min_b;
        current
            .violation_gradient
            .copy_from_slice(&scratch.best_violation_gradient);
        current.rows.clone_from(&scratch.best_rows);
    }
    Ok(found)
}
