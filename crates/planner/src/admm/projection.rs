//! The Z-update's projection onto the linearised safe set (`PlannerSettings::z_cuts`): the
//! linearised-safety step of [`super::safe_step`] (G's minimiser subject to the safety rows of
//! the current Z) whose trial point is checked by the predictor and, when that check finds it
//! unsafe, solved again with **cuts**: the rows violated at the trial point, linearised there
//! under the trial's own prediction and re-expressed around the current Z,
//!
//!   b_t + ∇b_t · (p − p_t) ≥ target  ⇔  (b_t − ∇b_t · (p_t − p_Z)) + ∇b_t · dp ≥ target,
//!
//! with p_t the trial's and p_Z the current Z's position at that step and dp = p − p_Z. The
//! rows of the current Z hold the prediction fixed, so a step along the boundary that makes
//! the other vehicles react (or turns the ellipse with the ego's heading) lands outside it;
//! each cut adds what that trial point taught, and the next solve stays on the safe side of
//! it. Without cuts the Z-update only halves the step along the one direction and stops
//! where the first halving is safe, short of the boundary's bend; with them Z slides along
//! the boundary.

use nudge_predictor::Predictor;

use crate::error::PlannerError;
use crate::model::State;

use super::constraint::{SafetyEval, SafetyRow};
use super::linearised::LinearisedProblem;
use super::safe_step::{StepRow, constrained_step};
use super::workspace::{CurrentSafety, Curvature, Scratch, max_diff};
use super::z_update::Lagrangian;

/// Rows the active-set method may add per step of the horizon (safety rows, cuts and bounds).
const ROUNDS_PER_STEP: usize = 4;

/// How a projection ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Projected {
    /// A safe trial that lowers G replaced Z.
    Moved,
    /// No step is defined (no Hessian scaling, a singular active set) or it does not move Z:
    /// nothing to halve.
    NoStep,
    /// Every solve's trial point was unsafe or did not lower G; `scratch.safe_step` holds the
    /// last step, for the halvings.
    Rejected,
}

/// The row `row`, evaluated at the trial point `trial` (`[T]`), as a row around `z` (`[T]`):
/// the same gradient, b shifted so that the linearisation at the trial point is expressed in
/// the step from `z` (see the module docs).
pub(crate) fn cut_row(row: &SafetyRow, trial: &[State], z: &[State]) -> SafetyRow {
    let k = row.step;
    let moved =
        row.gradient[0] * (trial[k][0] - z[k][0]) + row.gradient[1] * (trial[k][1] - z[k][1]);
    SafetyRow {
        step: k,
        b: row.b - moved,
        gradient: row.gradient,
    }
}

/// The state-bound rows of a step from `z` (`[T]`) within `lp`'s bounds: d_kj ≥ lower_kj − z_kj
/// and −d_kj ≥ z_kj − upper_kj for every finite bound, so that a solved step needs no
/// clamping (a clamped step lands back where the cut was made).
pub(crate) fn bound_rows(lp: &LinearisedProblem, z: &[State]) -> Vec<StepRow> {
    let mut rows = Vec::new();
    for (k, zk) in z.iter().enumerate() {
        for j in 0..4 {
            let (lo, hi) = (lp.lower[k][j], lp.upper[k][j]);
            if lo.is_finite() {
                rows.push(StepRow {
                    terms: [(4 * k + j, 1.0), (4 * k + j, 0.0)],
                    need: lo - zk[j],
                });
            }
            if hi.is_finite() {
                rows.push(StepRow {
                    terms: [(4 * k + j, -1.0), (4 * k + j, 0.0)],
                    need: zk[j] - hi,
                });
            }
        }
    }
    rows
}

/// The projection from the safe Z `z` (its safety, rows included, in `current`; ∇G in
/// `scratch.gradient`; G there `g_current`): up to `z_cuts + 1` solves of G's minimiser
/// subject to the safety rows of Z, the state bounds ([`bound_rows`]) and the cuts of the
/// rejected trial points so far; each trial point (Z⁺ = Π(Z − d), η = 1) is accepted when it
/// lowers G and the predictor finds it safe at the Z-update's threshold. A trial that does not
/// lower G ends the cuts (more rows only raise the minimum of G).
#[allow(clippy::too_many_arguments)]
pub(crate) fn project(
    g: &Lagrangian<'_>,
    curvature: &Curvature,
    z: &mut [State],
    g_current: f64,
    scratch: &mut Scratch,
    current: &mut CurrentSafety,
    safety: &mut SafetyEval<'_>,
    predictor: &mut dyn Predictor,
) -> Result<Projected, PlannerError> {
    let Some(inverse) = curvature.newton.as_ref() else {
        return Ok(Projected::NoStep);
    };
    let target = safety.threshold() + g.s.z_step_margin;
    let mut rows: Vec<StepRow> = current
        .rows
        .iter()
        .map(|r| StepRow::safety(r, target))
        .collect();
    rows.extend(bound_rows(g.lp, z));
    let rounds = ROUNDS_PER_STEP * z.len();
    for cut in 0..=g.s.z_cuts {
        if !constrained_step(
            inverse,
            &scratch.gradient,
            &rows,
            rounds,
            &mut scratch.safe_step,
        ) {
            return Ok(if cut == 0 {
                Projected::NoStep
            } else {
                Projected::Rejected
            });
        }
        g.lp.project_step(z, &scratch.safe_step, 1.0, &mut scratch.trial);
        if max_diff(&scratch.trial, z) < 1e-12 {
            return Ok(Projected::NoStep);
        }
        if g.value(&scratch.trial, &mut scratch.weighted) >= g_current {
            break;
        }
        let e = safety.eval(predictor, &scratch.trial)?;
        if e.is_safe(safety.threshold()) {
            z.copy_from_slice(&scratch.trial);
            current.min_b = e.min_b;
            current.violation = 0.0;
            current.rows.clone_from(&safety.rows);
            return Ok(Projected::Moved);
        }
        let before = rows.len();
        rows.extend(
            safety
                .rows
                .iter()
                .filter(|r| r.b < target)
                .map(|r| StepRow::safety(&cut_row(r, &scratch.trial, z), target)),
        );
        if rows.len() == before {
            break;
        }
    }
    Ok(Projected::Rejected)
}
