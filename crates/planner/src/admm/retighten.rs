//! The re-tightening of the Z-update's threshold (`PlannerSettings::z_retighten`). A loop
//! that converged has Z on (or near) the tightened boundary b = `safety_min + plan_buffer`
//! and inputs whose nonlinear roll-out differs from Z by the accumulated primal residual;
//! when the predictor finds that roll-out unsafe, the fixed `plan_buffer` was too small for
//! this call. The threshold is then raised by what the roll-out lost,
//!
//!   threshold⁺ = threshold + (min b(Z) − min b(roll-out)) + `z_step_margin`,
//!
//! and the loop goes on from its iterates, so Z moves that much further inside the safe set
//! and the inputs follow it.

use nudge_predictor::Predictor;

use crate::error::PlannerError;
use crate::model::{Bicycle, State};
use crate::settings::PlannerSettings;

use super::constraint::SafetyEval;
use super::linearised::LinearisedProblem;
use super::workspace::Workspace;

/// The raised threshold (units of b) when the nonlinear roll-out of the current inputs is
/// unsafe at `safety_min` (one predictor call), else `None`. The evaluator's rows are those of
/// the roll-out on return.
pub(crate) fn raised_threshold(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
    ws: &Workspace,
    safety: &mut SafetyEval<'_>,
    predictor: &mut dyn Predictor,
) -> Result<Option<f64>, PlannerError> {
    let Some(z_min_b) = ws.current.min_b else {
        return Ok(None);
    };
    let mut rollout = vec![State::zeros(); lp.horizon];
    model.rollout(
        &lp.start,
        &ws.iterates.delta,
        &ws.iterates.accel,
        &mut rollout,
    );
    let e = safety.eval(predictor, &rollout)?;
    Ok(raise(
        safety.threshold(),
        z_min_b,
        e.min_b,
        s.safety_min,
        s.z_step_margin,
    ))
}

/// The rule: `None` when the roll-out's `rollout_min_b` is above `safety_min` (or nothing is
/// checked), else `threshold` raised by the drop `z_min_b − rollout_min_b` (at least 0) plus
/// `margin`; `None` too for a non-finite drop (a threshold is never non-finite).
pub(crate) fn raise(
    threshold: f64,
    z_min_b: f64,
    rollout_min_b: Option<f64>,
    safety_min: f64,
    margin: f64,
) -> Option<f64> {
    let b = rollout_min_b?;
    if b > safety_min {
        return None;
    }
    let raised = threshold + (z_min_b - b).max(0.0) + margin;
    raised.is_finite().then_some(raised)
}
