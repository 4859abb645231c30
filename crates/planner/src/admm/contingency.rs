//! The contingency rule (`PlannerSettings::contingency`): a plan that puts the ego across the
//! line between its own lane and the target lane is admissible only if a fixed retreat from
//! the plan back into the own lane is safe against the predictor's prediction for it.
//!
//! * **When it applies**: while the problem offers the own lane as a retreat
//!   ([`crate::PlanningProblem::y_retreat`]: before the ego's centre crosses the line, or while
//!   it is stuck across it, [`crate::lane::LaneChange::retreat`]) and the call's lateral goal
//!   lies in another lane (at least [`MIN_LANE_OFFSET`] from the own lane's centre); to a plan
//!   one of whose states has the ego's box across the line (the box's half extent across the
//!   road at its heading beyond the line, the line being the midpoint of the two lanes'
//!   centres, as in [`crate::lane::LaneChange`]).
//! * **The retreat** ([`Contingency::path`]): it branches off the plan at the plan's first
//!   state across the line z_k, but no later than step T − `contingency_steps` (so it is
//!   checked for at least that many predicted steps; step 0 is the measured state), and from
//!   there brakes at the constant `contingency_accel` (within the acceleration box and jerk
//!   bound from the plan's acceleration at the branch), or, when that retreat is not safe,
//!   holds its acceleration at 0 (behind a slower own-lane leader braking is the safe way
//!   back, in front of a closing target-lane follower holding the speed), while steering
//!   back towards the own lane's centre with the fallbacks' `steer_towards` (heading aim
//!   0.05 rad per m of lateral error, at most 0.08 rad, within the steering box and rate bound from
//!   the plan's steering at the branch), rolled out on the nonlinear model. The path the
//!   predictor sees is the plan up to the branch, then the retreat: `[T]` states, one
//!   predictor call per retreat tried (counted in `predictor_calls` and the budget).
//! * **The verdict**: one of the two retreat paths must be safe (every checked b >
//!   `safety_min` at every step under its own prediction, the terminal closing-speed margin
//!   included), else the plan is not admissible (ranked by the retreat's violation, and the
//!   fallbacks may steer back). Retreat candidates of the fallbacks are not subject to it
//!   (they are the retreat).
//!
//! Measured on validation it costs success (see `crate::Planner`, "Safety geometry and
//! contingency", and `docs/results/nudge_safety.md`); it is off by default.
//!
//! The idea (why a retreat rather than a wider constraint): replanning every 0.3 s, the ego commits only
//! to the first step of each plan; a plan whose retreat is safe leaves the next call a way back
//! when the traffic does not do what the prediction said, so the constraint on the plan itself
//! may be tight (the box geometry, `SafetyGeometry::Boxes`) without betting the ego on the
//! prediction.

use crate::model::{Bicycle, State};
use crate::qp::{RateBox, repair_box_rate};
use crate::settings::PlannerSettings;

use super::linearised::{LinearisedProblem, half_extent_at};
use super::repair::steer_towards;

/// Smallest lateral distance (m) between the call's goal and the own lane's centre for which
/// the rule applies (a lane is ≥ 2.5 m wide; below this the goal is the own lane).
pub(crate) const MIN_LANE_OFFSET: f64 = 1.0;

/// The contingency rule of one call, in the call's frame.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Contingency {
    /// The line between the own lane and the goal's lane (m).
    line: f64,
    /// +1 when the goal lies at larger y than the own lane, −1 otherwise.
    side: f64,
    /// The own lane's centre (m).
    own: f64,
    /// The retreats' accelerations (m/s²), in the order tried.
    accels: Vec<f64>,
    /// Predicted steps the retreat is checked for at least.
    steps: usize,
    /// Heading cap of the retreat's steering (rad): the heading bound of a plan aiming at the
    /// own lane.
    max_heading: f64,
}

impl Contingency {
    /// The rule of the call `lp` under `s`; `None` when it is off, the problem has no retreat
    /// lane, or the goal lies within [`MIN_LANE_OFFSET`] of it.
    pub(crate) fn new(s: &PlannerSettings, lp: &LinearisedProblem) -> Option<Self> {
        if !s.contingency {
            return None;
        }
        let retreat = lp.retreat.as_ref()?;
        let offset = lp.reference[1] - retreat.y;
        if offset.abs() < MIN_LANE_OFFSET {
            return None;
        }
        Some(Self {
            line: retreat.y + 0.5 * offset,
            side: offset.signum(),
            own: retreat.y,
            accels: if s.contingency_accel == 0.0 {
                vec![0.0]
            } else {
                vec![s.contingency_accel, 0.0]
            },
            steps: s.contingency_steps,
            max_heading: retreat
                .upper
                .iter()
                .map(|u| u[2])
                .fold(f64::INFINITY, f64::min),
        })
    }

    /// How far (m) the box of an ego of `size` = (length, width) at state `z` reaches across
    /// the line (> 0: across).
    pub(crate) fn reach(&self, size: [f64; 2], z: &State) -> f64 {
        self.side * (z[1] - self.line) + half_extent_at(size, z[2])
    }

    /// The first plan step k (1-based: state z_k of `rollout`) whose box is across the line.
    pub(crate) fn first_across(&self, size: [f64; 2], rollout: &[State]) -> Option<usize> {
        rollout
            .iter()
            .position(|z| self.reach(size, z) > 0.0)
            .map(|k| k + 1)
    }

    /// The branch state j (0: the measured state, else z_j) for a first crossing at step
    /// `k`: min(k, T − steps).
    pub(crate) fn branch(&self, k: usize, horizon: usize) -> usize {
        k.min(horizon.saturating_sub(self.steps))
    }

    /// The accelerations (m/s²) of the retreats, in the order tried: `contingency_accel`,
    /// then 0 (holding the speed) when that differs.
    pub(crate) fn accels(&self) -> &[f64] {
        &self.accels
    }

    /// The retreat path of the plan (`delta`, `accel` `[T]` and their roll-out `rollout`
    /// z_1..z_T) branching at state `j` at acceleration `a_retreat` (m/s²): z_1..z_j, then
    /// T − j states of the retreat from z_j (z_0 the call's start).
    pub(crate) fn path(
        &self,
        model: &Bicycle,
        lp: &LinearisedProblem,
        plan: (&[f64], &[f64], &[State]),
        j: usize,
        a_retreat: f64,
    ) -> Vec<State> {
        let (delta, accel, rollout) = plan;
        let t = lp.horizon;
        let (from, prev_delta, prev_accel) = if j == 0 {
            (lp.start, lp.delta_box.prev, lp.accel_box.prev)
        } else {
            (rollout[j - 1], delta[j - 1], accel[j - 1])
        };
        let (d, a) = self.manoeuvre(model, lp, &from, [prev_delta, prev_accel], t - j, a_retreat);
        let mut path = rollout[..j].to_vec();
        let mut tail = vec![State::zeros(); t - j];
        model.rollout(&from, &d, &a, &mut tail);
        path.extend(tail);
        path
    }

    /// The retreat's inputs (steering, acceleration) `[n]` from state `from` whose previous
    /// inputs were `prev` = (δ, a): the constant `a_retreat` (m/s²) within the acceleration
    /// box and jerk bound, steering towards the own lane's centre within the steering box and
    /// rate bound.
    pub(crate) fn manoeuvre(
        &self,
        model: &Bicycle,
        lp: &LinearisedProblem,
        from: &State,
        prev: [f64; 2],
        n: usize,
        a_retreat: f64,
    ) -> (Vec<f64>, Vec<f64>) {
        let accel_box = RateBox {
            prev: prev[1].clamp(lp.accel_box.lo, lp.accel_box.hi),
            ..lp.accel_box
        };
        let delta_box = RateBox {
            prev: prev[0].clamp(lp.delta_box.lo, lp.delta_box.hi),
            ..lp.delta_box
        };
        let mut a = vec![a_retreat; n];
        repair_box_rate(&mut a, accel_box);
        let d = steer_towards(model, from, &a, self.own, self.max_heading, delta_box);
        (d, a)
    }
}
