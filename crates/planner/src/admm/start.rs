//! The start of the ADMM loop. The iterates start from the nominal (the shifted previous
//! plan, [`Iterates::start`]); with `PlannerSettings::safe_start`, when the predictor finds
//! the nominal's Z unsafe at the Z-update's threshold, from the best safe simple candidate
//! instead: the fallbacks' keep-lane and steer-towards-the-goal input sequences
//! ([`super::repair::simple_inputs`]), each rolled out from the measured state, clamped into
//! the state bounds and checked by the predictor; the safe one with the least cost J
//! (its inputs, its clamped roll-out as Z, the warm duals) is the start. With none safe, the
//! nominal stays and the Z-update begins with the feasibility restoration.

use nudge_predictor::Predictor;

use crate::error::PlannerError;
use crate::model::{Bicycle, State};
use crate::settings::PlannerSettings;

use super::constraint::{Evaluation, SafetyEval};
use super::linearised::LinearisedProblem;
use super::repair::simple_inputs;
use super::workspace::Iterates;

/// The start of the loop and the evaluation of its Z (`safety`'s rows and violation gradient
/// are those of that Z on return).
pub(crate) fn start(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
    safety: &mut SafetyEval<'_>,
    predictor: &mut dyn Predictor,
) -> Result<(Iterates, Evaluation), PlannerError> {
    let nominal = Iterates::start(lp);
    let first = safety.eval(predictor, &nominal.z)?;
    if !s.safe_start || first.is_safe(safety.threshold()) {
        return Ok((nominal, first));
    }
    let (rows, gradient) = (safety.rows.clone(), safety.violation_gradient.clone());
    let Some(best) = best_safe_candidate(s, model, lp, safety, predictor)? else {
        // The evaluator's rows and violation gradient back to the nominal's.
        safety.rows = rows;
        safety.violation_gradient = gradient;
        return Ok((nominal, first));
    };
    let e = safety.eval(predictor, &best.z)?;
    Ok((
        Iterates {
            delta: best.delta,
            accel: best.accel,
            z: best.z,
            duals: nominal.duals,
        },
        e,
    ))
}

/// A candidate start: inputs `[T]` and their clamped roll-out `[T]`.
pub(crate) struct StartCandidate {
    /// Steering `[T]` (rad).
    pub delta: Vec<f64>,
    /// Acceleration `[T]` (m/s²).
    pub accel: Vec<f64>,
    /// The roll-out z_1..z_T `[T]` (call frame), clamped into the state bounds.
    pub z: Vec<State>,
}

/// The safe (at the Z-update's threshold) simple candidate with the least cost J, in
/// [`simple_inputs`] order on ties; `None` when none is safe.
pub(crate) fn best_safe_candidate(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
    safety: &mut SafetyEval<'_>,
    predictor: &mut dyn Predictor,
) -> Result<Option<StartCandidate>, PlannerError> {
    let mut best: Option<(f64, StartCandidate)> = None;
    for (delta, accel) in simple_inputs(s, model, lp) {
        let mut z = vec![State::zeros(); lp.horizon];
        model.rollout(&lp.start, &delta, &accel, &mut z);
        for (k, zk) in z.iter_mut().enumerate() {
            *zk = lp.clamp(k, zk);
        }
        let e = safety.eval(predictor, &z)?;
        if !e.is_safe(safety.threshold()) {
            continue;
        }
        let cost = lp.cost(s, &delta, &accel, &z);
        if best.as_ref().is_none_or(|(c, _)| cost < *c) {
            best = Some((cost, StartCandidate { delta, accel, z }));
        }
    }
    Ok(best.map(|(_, c)| c))
}
