//! The safety constraint b_i of one MPC call: which vehicles are checked, and b for the ego
//! at a position and heading against one of them at its (predicted or observed) position.
//! The planner evaluates it on every trial point ([`SafetyEval`]); the closed-loop simulator
//! evaluates the very same function on the executed step
//! ([`SafetyConstraint::executed_min_b`]).

use std::time::{Duration, Instant};

use nudge_predictor::{Predictor, T_OBS};

use crate::cancel::Cancel;
use crate::error::PlannerError;
use crate::model::State;
use crate::safety::{Ellipse, OrientedBox, box_separation, motion_axis, motion_direction};
use crate::settings::PlannerSettings;

use super::problem::{BudgetLimit, PlanningProblem};

/// One vehicle the safety constraint checks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckedVehicle {
    /// Agent index (≥ 1).
    pub index: usize,
    /// (length, width) (m).
    pub size: [f64; 2],
    /// Last observed position (m, road frame).
    pub last: [f64; 2],
    /// (|cos ψ|, |sin ψ|) of its last observed motion ([`motion_direction`], heading 0 when it
    /// barely moved): its heading wherever a later motion is too short to read one from.
    pub direction: [f64; 2],
    /// (cos ψ, sin ψ) of its last observed motion ([`motion_axis`], heading 0 when it barely
    /// moved): the signed direction the box geometry needs.
    pub axis: [f64; 2],
}

/// The geometry of the ego at one step against one checked vehicle at that step
/// ([`SafetyConstraint::pair`]): computed once, read by b, its gradient, the beside test and
/// the box overlap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairGeometry {
    /// The ego (x, y, ψ, v) (m, m, rad, m/s).
    pub ego: [f64; 4],
    /// (sin ψ, cos ψ) of the ego.
    pub sin_cos: [f64; 2],
    /// The other vehicle's position one step earlier (m).
    pub previous: [f64; 2],
    /// The other vehicle's position (m).
    pub other: [f64; 2],
    /// (|cos|, |sin|) of the other vehicle's motion from `previous` ([`motion_direction`]).
    pub other_direction: [f64; 2],
    /// The closing-speed margin (m) at the horizon's last step, else 0.
    pub closing: f64,
}

impl PairGeometry {
    /// (|cos ψ|, |sin ψ|) of the ego.
    #[must_use]
    pub fn ego_direction(&self) -> [f64; 2] {
        [self.sin_cos[1].abs(), self.sin_cos[0].abs()]
    }
}

/// The safety constraint of one MPC call: the vehicles within `check_range` of the ego's
/// measured position, and the ellipse b_i of [`Ellipse::oriented`] sized by both vehicles'
/// bounding boxes at their headings (the ego's from its heading ψ, the other's from the
/// direction of its motion since the previous step).
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyConstraint {
    vehicles: Vec<CheckedVehicle>,
    ego_size: [f64; 2],
    /// The ellipse's scales (along, across the road; [`crate::axis_scales`]).
    scale: f64,
    margins: [f64; 2],
    /// Slices the ego is cut into along its heading for the ellipse geometry
    /// (`safety.ego_segment_length`; 1: one ellipse for the whole ego).
    segments: usize,
    /// Step length (s), for the other vehicles' speeds from their predicted positions.
    dt: f64,
    /// Deceleration (m/s²) the closing-speed margin grants the rear vehicle; 0 disables it.
    brake_decel: f64,
}

impl SafetyConstraint {
    /// The constraint of `problem` (checked with [`PlanningProblem::check`]) under `settings`.
    #[must_use]
    pub fn new(problem: &PlanningProblem<'_>, settings: &PlannerSettings) -> Self {
        let origin = [problem.ego.x, problem.ego.y];
        let mut vehicles = Vec::new();
        for i in 1..problem.history.n_agents() {
            let p = problem.history.at(i, T_OBS - 1);
            let d = ((p[0] - origin[0]).powi(2) + (p[1] - origin[1]).powi(2)).sqrt();
            if d <= settings.safety.check_range {
                let q = problem.history.at(i, T_OBS - 2);
                vehicles.push(CheckedVehicle {
                    index: i,
                    size: problem.sizes[i],
                    last: [p[0], p[1]],
                    direction: motion_direction([q[0], q[1]], [p[0], p[1]], [1.0, 0.0]),
                    axis: motion_axis([q[0], q[1]], [p[0], p[1]], [1.0, 0.0]),
                });
            }
        }
        Self {
            vehicles,
            ego_size: problem.sizes[0],
            scale: settings.safety.ellipse_scale,
            margins: [settings.safety.margin_x, settings.safety.margin_y],
            segments: ego_segments(problem.sizes[0][0], settings.safety.ego_segment_length),
            dt: settings.model.dt,
            brake_decel: settings.safety.brake_decel,
        }
    }

    /// The checked vehicles, in agent order.
    #[must_use]
    pub fn vehicles(&self) -> &[CheckedVehicle] {
        &self.vehicles
    }

    /// The geometry of the ego at `ego` = (x, y, ψ, v) (m, m, rad, m/s) against `vehicle` at
    /// `other` (m), which was at `previous` one step earlier, at the `terminal` step of the
    /// horizon or not: evaluated once per (vehicle, step) and shared by b, its gradient, the
    /// beside test and the box overlap.
    #[must_use]
    pub fn pair(
        &self,
        vehicle: &CheckedVehicle,
        ego: [f64; 4],
        previous: [f64; 2],
        other: [f64; 2],
        terminal: bool,
    ) -> PairGeometry {
        let (sin, cos) = ego[2].sin_cos();
        PairGeometry {
            ego,
            sin_cos: [sin, cos],
            previous,
            other,
            other_direction: motion_direction(previous, other, vehicle.direction),
            closing: if terminal {
                self.closing_margin([ego[0], ego[1]], ego[3], previous, other)
            } else {
                0.0
            },
        }
    }

    /// The ellipse around `vehicle` at `other` (m), which was at `previous` one step earlier,
    /// for an ego whose heading has direction `ego_direction` = (|cos ψ|, |sin ψ|).
    #[must_use]
    pub fn ellipse(
        &self,
        vehicle: &CheckedVehicle,
        ego_direction: [f64; 2],
        previous: [f64; 2],
        other: [f64; 2],
    ) -> Ellipse {
        self.ellipse_of(
            vehicle,
            ego_direction,
            motion_direction(previous, other, vehicle.direction),
        )
    }

    /// [`Self::ellipse`] for the other vehicle's motion direction `other_direction`.
    fn ellipse_of(
        &self,
        vehicle: &CheckedVehicle,
        ego_direction: [f64; 2],
        other_direction: [f64; 2],
    ) -> Ellipse {
        Ellipse::oriented(
            self.ego_size,
            ego_direction,
            vehicle.size,
            other_direction,
            self.scale,
            self.margins[0],
            self.margins[1],
        )
    }

    /// Whether `vehicle` at `other` (having moved from `previous`, m) is **beside** the ego at
    /// `ego` = (x, y, ψ, v): the lateral distance of their centres is at least the sum of the
    /// half widths of their road-aligned bounding boxes (at their headings) plus `margin_y`,
    /// so their boxes cannot touch at any offset along the road.
    #[must_use]
    pub fn beside(
        &self,
        vehicle: &CheckedVehicle,
        ego: [f64; 4],
        previous: [f64; 2],
        other: [f64; 2],
    ) -> bool {
        self.beside_of(vehicle, &self.pair(vehicle, ego, previous, other, false))
    }

    /// [`Self::beside`] of a [`PairGeometry`].
    #[must_use]
    pub fn beside_of(&self, vehicle: &CheckedVehicle, pair: &PairGeometry) -> bool {
        let reach = Ellipse::oriented(
            self.ego_size,
            pair.ego_direction(),
            vehicle.size,
            pair.other_direction,
            1.0,
            0.0,
            self.margins[1],
        )
        .a_y;
        (pair.other[1] - pair.ego[1]).abs() >= reach
    }

    /// The closing-speed margin (m) added to the ellipse's longitudinal semi-axis: the extra
    /// distance the rear one of the ego (at `ego`, m, speed `ego_speed`, m/s) and the other
    /// vehicle (at `other`, having moved from `previous` in one step) needs to brake to the
    /// front one's speed at `brake_decel`, (v_rear² − v_front²) / (2·brake_decel) when the rear
    /// one is faster, else 0 (speeds along the road). The ellipse alone only keeps the boxes
    /// apart over the horizon; this keeps a gap from which the rear vehicle can still match
    /// the front one's speed after it.
    #[must_use]
    pub fn closing_margin(
        &self,
        ego: [f64; 2],
        ego_speed: f64,
        previous: [f64; 2],
        other: [f64; 2],
    ) -> f64 {
        if self.brake_decel <= 0.0 {
            return 0.0;
        }
        let other_speed = (other[0] - previous[0]) / self.dt;
        let (rear, front) = if ego[0] <= other[0] {
            (ego_speed, other_speed)
        } else {
            (other_speed, ego_speed)
        };
        let front = front.max(0.0);
        if rear > front {
            (rear * rear - front * front) / (2.0 * self.brake_decel)
        } else {
            0.0
        }
    }

    /// b of the ego at `ego` = (x, y, ψ, v) (m, m, rad, m/s) against `vehicle` at `other`
    /// (m), which was at `previous` one step earlier: the [`SafetyConstraint::ellipse`] (of
    /// each slice of a long ego, `safety.ego_segment_length`), with the
    /// [`SafetyConstraint::closing_margin`] added to its longitudinal semi-axis at the
    /// `terminal` step of the horizon (a terminal condition: the plan must end where the rear
    /// vehicle can still match the front one's speed; within the horizon the predictions
    /// themselves show the gap closing, and a margin there would forbid the very braking that
    /// recovers from a short gap). The ellipse of the whole ego (the drawn safety region) is
    /// returned with it.
    #[must_use]
    pub fn b(
        &self,
        vehicle: &CheckedVehicle,
        ego: [f64; 4],
        previous: [f64; 2],
        other: [f64; 2],
        terminal: bool,
    ) -> (f64, Ellipse) {
        let pair = self.pair(vehicle, ego, previous, other, terminal);
        let mut ellipse = self.ellipse_of(vehicle, pair.ego_direction(), pair.other_direction);
        ellipse.a_x += pair.closing;
        let b = if self.segments > 1 {
            self.sliced(vehicle, &pair).0
        } else {
            ellipse.value([ego[0], ego[1]], other)
        };
        (b, ellipse)
    }

    /// b as [`SafetyConstraint::b`] and its gradient ∂b/∂(x, y) of the ego's position (the
    /// prediction, the headings and the sizes of the ellipses held fixed).
    #[must_use]
    pub fn b_and_gradient(
        &self,
        vehicle: &CheckedVehicle,
        ego: [f64; 4],
        previous: [f64; 2],
        other: [f64; 2],
        terminal: bool,
    ) -> (f64, [f64; 2]) {
        self.b_and_gradient_of(vehicle, &self.pair(vehicle, ego, previous, other, terminal))
    }

    /// [`Self::b_and_gradient`] of a [`PairGeometry`].
    #[must_use]
    pub fn b_and_gradient_of(
        &self,
        vehicle: &CheckedVehicle,
        pair: &PairGeometry,
    ) -> (f64, [f64; 2]) {
        if self.segments > 1 {
            self.sliced(vehicle, pair)
        } else {
            let mut e = self.ellipse_of(vehicle, pair.ego_direction(), pair.other_direction);
            e.a_x += pair.closing;
            let p = [pair.ego[0], pair.ego[1]];
            (e.value(p, pair.other), e.gradient(p, pair.other))
        }
    }

    /// b of the sliced ego (`safety.ego_segment_length`) and its gradient
    /// ∂b/∂(x, y) of the ego's centre: the ego is cut along its heading into `segments`
    /// slices of length L/k, and b is the smallest over the slices of the
    /// [`Ellipse::oriented`] of one slice (size (L/k, W) at the ego's heading) and the
    /// vehicle, the pair's closing margin added to the longitudinal semi-axis, evaluated at
    /// the slice's centre ([`Ellipse::sliced`]).
    fn sliced(&self, vehicle: &CheckedVehicle, pair: &PairGeometry) -> (f64, [f64; 2]) {
        let k = self.segments;
        let mut e = Ellipse::oriented(
            [self.ego_size[0] / k as f64, self.ego_size[1]],
            pair.ego_direction(),
            vehicle.size,
            pair.other_direction,
            self.scale,
            self.margins[0],
            self.margins[1],
        );
        e.a_x += pair.closing;
        let [sn, cs] = pair.sin_cos;
        e.sliced(
            [pair.ego[0], pair.ego[1]],
            [cs, sn],
            self.ego_size[0],
            k,
            pair.other,
        )
    }

    /// How deep the ego's box at `ego` = (x, y, ψ, v) overlaps the vehicle's box at `other`
    /// (heading of its motion from `previous`) (m): −[`box_separation`] without clearance
    /// when the boxes overlap, else 0; ∞ when it is NaN (never counted as clear).
    #[must_use]
    pub fn overlap(
        &self,
        vehicle: &CheckedVehicle,
        ego: [f64; 4],
        previous: [f64; 2],
        other: [f64; 2],
    ) -> f64 {
        self.overlap_of(vehicle, &self.pair(vehicle, ego, previous, other, false))
    }

    /// [`Self::overlap`] of a [`PairGeometry`].
    #[must_use]
    pub fn overlap_of(&self, vehicle: &CheckedVehicle, pair: &PairGeometry) -> f64 {
        let [sn, cs] = pair.sin_cos;
        let a = OrientedBox::along([pair.ego[0], pair.ego[1]], [cs, sn], self.ego_size);
        let axis = motion_axis(pair.previous, pair.other, vehicle.axis);
        let b = OrientedBox::along(pair.other, axis, vehicle.size);
        let sep = box_separation(&a, &b, [0.0, 0.0]).0;
        if sep.is_nan() {
            f64::INFINITY
        } else {
            (-sep).max(0.0)
        }
    }

    /// The minimum b_i over the checked vehicles at the step the vehicles actually drove: the
    /// ego at `ego` = (x, y, ψ, v) (m, m, rad, m/s) and every agent at `positions[agent]` (m,
    /// agent 0 unused), each having moved from its last observed position. This is the value
    /// the constraint gives step 1 of a candidate equal to that motion. `None` when no vehicle
    /// is checked; −∞ when b is NaN.
    #[must_use]
    pub fn executed_min_b(&self, ego: [f64; 4], positions: &[[f64; 2]]) -> Option<f64> {
        if self.vehicles.is_empty() {
            return None;
        }
        let min_b = self
            .vehicles
            .iter()
            .map(|v| self.b(v, ego, v.last, positions[v.index], false).0)
            .fold(f64::INFINITY, min_or_nan);
        Some(never_nan(min_b))
    }
}

/// The vehicle a plan's safety binds on: the checked vehicle with the smallest b over the
/// plan's steps under one prediction ([`SafetyConstraint::binding`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BindingVehicle {
    /// Agent index (≥ 1).
    pub agent: usize,
    /// Plan step k of the smallest b (0-based: state z_{k+1}).
    pub step: usize,
    /// The smallest b over the plan (−∞ when b is NaN).
    pub b: f64,
    /// Semi-axes (a_x, a_y) (m) of the vehicle's safety ellipse at every plan step, `[T]`,
    /// the closing-speed margin included at the last step: the ellipse of step k is centred
    /// on the vehicle's predicted position at step k, axis-aligned with the road.
    pub semi_axes: Vec<[f64; 2]>,
}

impl SafetyConstraint {
    /// The binding vehicle of the planned states `states` = z_1..z_T (x, y, ψ, v) (m, m, rad,
    /// m/s, `[T]`) under `prediction` (m, `[n − 1, T, 2]` flat, agents 1..n at steps 1..T, the
    /// planning predictor's output for that plan): b of every checked vehicle at every step,
    /// exactly as the planner evaluates a candidate, and the vehicle and step of the smallest
    /// (the first in agent-then-step order on ties). `None` when no vehicle is checked.
    #[must_use]
    pub fn binding(&self, states: &[[f64; 4]], prediction: &[f64]) -> Option<BindingVehicle> {
        let t = states.len();
        let mut best: Option<BindingVehicle> = None;
        for v in &self.vehicles {
            let base = (v.index - 1) * t * 2;
            let mut previous = v.last;
            let mut semi_axes = Vec::with_capacity(t);
            let mut own = (f64::INFINITY, 0);
            for (k, z) in states.iter().enumerate() {
                let other = [prediction[base + 2 * k], prediction[base + 2 * k + 1]];
                let (b, ellipse) = self.b(v, *z, previous, other, k + 1 == t);
                previous = other;
                semi_axes.push([ellipse.a_x, ellipse.a_y]);
                let b = never_nan(b);
                if b < own.0 {
                    own = (b, k);
                }
            }
            if best.as_ref().is_none_or(|w| own.0 < w.b) {
                best = Some(BindingVehicle {
                    agent: v.index,
                    step: own.1,
                    b: own.0,
                    semi_axes,
                });
            }
        }
        best
    }
}

/// The slices k = ⌈`length` / `segment`⌉ (≥ 1) an ego `length` long (m) is cut into for the
/// ellipse geometry, as a float so that an absurd count can be compared with
/// [`crate::PlannerSettings::MAX_EGO_SEGMENTS`] before any cast (`Planner::check`); 1 when
/// `segment` is 0 (off) or at least the length.
#[must_use]
pub(crate) fn ego_slice_count(length: f64, segment: f64) -> f64 {
    if segment > 0.0 && length > segment {
        (length / segment).ceil()
    } else {
        1.0
    }
}

/// [`ego_slice_count`] as a count, for a problem `Planner::check` has accepted (at most
/// [`crate::PlannerSettings::MAX_EGO_SEGMENTS`]).
#[must_use]
pub(crate) fn ego_segments(length: f64, segment: f64) -> usize {
    ego_slice_count(length, segment) as usize
}

/// The minimum of `a` and `b`, NaN when either is (`f64::min` would drop a NaN `b`).
fn min_or_nan(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.min(b)
    }
}

/// A NaN minimum is never safe: −∞.
fn never_nan(min_b: f64) -> f64 {
    if min_b.is_nan() {
        f64::NEG_INFINITY
    } else {
        min_b
    }
}

/// b over a candidate: min b_i and the total violation Σ max(0, threshold − b).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Evaluation {
    /// Minimum b over checked vehicles and steps (`None` when none is checked).
    pub min_b: Option<f64>,
    /// Σ (threshold − b) over the pairs with b ≤ threshold.
    pub violation: f64,
    /// Minimum b over the pairs whose vehicle is not beside the ego
    /// ([`SafetyConstraint::beside`]; `None` when there is none).
    pub path_min_b: Option<f64>,
    /// `violation` over the pairs whose vehicle is not beside the ego.
    pub path_violation: f64,
    /// `violation` over the pairs whose vehicle is not beside the ego and whose centre is
    /// ahead of the ego's along the road at that step: the vehicles the ego drives into
    /// ([`crate::RankKey::Ahead`]).
    pub ahead_violation: f64,
    /// Σ over the pairs of how deep the boxes overlap (m, [`SafetyConstraint::overlap`]); 0
    /// unless the evaluator counts it ([`SafetyEval::count_overlap`]).
    pub overlap: f64,
}

impl Evaluation {
    /// A candidate that got no prediction (the budget is spent, or the predictors would
    /// refuse it): unsafe at every threshold, and worse than any evaluated candidate.
    pub(crate) fn not_evaluated() -> Self {
        Self {
            min_b: Some(f64::NEG_INFINITY),
            violation: f64::INFINITY,
            path_min_b: Some(f64::NEG_INFINITY),
            path_violation: f64::INFINITY,
            ahead_violation: f64::INFINITY,
            overlap: f64::INFINITY,
        }
    }

    /// Safe at `threshold`: nothing checked, or min b > threshold.
    pub(crate) fn is_safe(&self, threshold: f64) -> bool {
        self.min_b.is_none_or(|b| b > threshold)
    }
}

/// Runs the predictor on candidate states and evaluates the constraint at every checked
/// vehicle and step, counting predictor calls. Buffers are allocated once per call.
pub(crate) struct SafetyEval<'c> {
    constraint: &'c SafetyConstraint,
    origin: [f64; 2],
    horizon: usize,
    /// The Z-update's threshold b_min (`safety.safety_min`) for the violation.
    threshold: f64,
    /// Ego candidate `[T, 2]` in the road frame (m).
    candidate: Vec<f64>,
    /// Prediction `[n − 1, T, 2]` (m).
    prediction: Vec<f64>,
    /// Heading ψ_k (rad) of the candidate, per step.
    ego_heading: Vec<f64>,
    /// Speed v_k (m/s) of the candidate, per step.
    ego_speed: Vec<f64>,
    /// ∂(total violation)/∂(x_k, y_k) at the last evaluated point, prediction and ellipse
    /// sizes frozen.
    pub violation_gradient: Vec<[f64; 2]>,
    /// Predictor calls so far.
    pub calls: usize,
    /// The (vehicle, step) pairs of the last evaluation with b below [`ROW_B`], linearised
    /// in the ego's position (prediction and ellipse frozen), for the refinement.
    pub rows: Vec<SafetyRow>,
    /// The call's work budget.
    pub budget: Budget,
    /// With `PlannerSettings::ablate_reaction`: the path the predictor sees instead of every
    /// candidate.
    keep_lane: Option<KeepLane>,
    /// Count [`Evaluation::overlap`] ([`crate::RankKey::Contact`]).
    pub count_overlap: bool,
    /// The ego's last observed position (road frame, m), the origin of the predictors'
    /// candidate range: when set, a candidate they would refuse (non-finite, or beyond
    /// `nudge_predictor::limits::check_candidates`) is never passed to the predictor and is
    /// not safe ([`SafetyEval::eval`]).
    pub ego_last: Option<[f64; 2]>,
    /// Candidates judged not safe because the predictors would refuse them.
    pub refused: usize,
}

/// The keep-lane path `[T, 2]` (road frame, m) the predictor sees when the reaction is
/// ablated, and whether `SafetyEval::prediction` already holds its prediction.
struct KeepLane {
    path: Vec<f64>,
    predicted: bool,
}

/// The work budget of one MPC call: a wall-clock deadline (`budget.seconds`, never more
/// than `PlannerSettings::MAX_SECONDS`), a number of predictor calls (`budget.calls`, never
/// more than `PlannerSettings::MAX_CALLS`) and an optional cancellation flag
/// ([`crate::Cancel`]). While it lasts every evaluation calls the predictor; once it is spent
/// an evaluation returns "not evaluated" — unsafe, never safe — without calling it, so trial
/// points are rejected and the ADMM loop, the refinement and the lattice search stop.
/// `reserve` predictor calls (and their estimated time) are kept back during the ADMM loop
/// for the execution check.
#[derive(Debug, Clone)]
pub(crate) struct Budget {
    deadline: Option<Instant>,
    max_calls: Option<usize>,
    /// Calls held back for the execution check (0 once it runs).
    pub reserve: usize,
    /// Time spent in the predictor so far.
    predictor_time: Duration,
    /// An evaluation was refused for lack of budget.
    pub exhausted: bool,
    /// The first limit that was reached, if any.
    pub reached: Option<BudgetLimit>,
    /// Set from another thread to end the call ([`crate::PlannerError::Cancelled`]).
    cancel: Option<Cancel>,
}

/// Calls the execution check is guaranteed under a budget: the roll-out of the ADMM inputs
/// and the shifted previous plan.
pub(crate) const RESERVED_CALLS: usize = 2;

impl Budget {
    /// The budget of `settings` for a call that started at `start`: `budget.seconds` and
    /// `budget.calls`, each capped (0 meaning the cap) by `PlannerSettings::MAX_SECONDS` and
    /// `PlannerSettings::MAX_CALLS`; `cancel` ends the call once set.
    pub(crate) fn new(settings: &PlannerSettings, start: Instant, cancel: Option<Cancel>) -> Self {
        let seconds = if settings.budget.seconds > 0.0 {
            settings.budget.seconds.min(PlannerSettings::MAX_SECONDS)
        } else {
            PlannerSettings::MAX_SECONDS
        };
        Self {
            deadline: Some(start + Duration::from_secs_f64(seconds)),
            max_calls: Some(if settings.budget.calls > 0 {
                settings.budget.calls
            } else {
                PlannerSettings::MAX_CALLS
            }),
            reserve: RESERVED_CALLS,
            predictor_time: Duration::ZERO,
            exhausted: false,
            reached: None,
            cancel,
        }
    }

    /// No budget at all.
    pub(crate) fn unlimited() -> Self {
        Self {
            deadline: None,
            max_calls: None,
            reserve: 0,
            predictor_time: Duration::ZERO,
            exhausted: false,
            reached: None,
            cancel: None,
        }
    }

    /// Whether the cancellation flag is set.
    pub(crate) fn cancelled(&self) -> bool {
        self.cancel.as_ref().is_some_and(Cancel::is_cancelled)
    }

    /// Whether one more predictor call (after `calls`) would eat into the reserve: the call
    /// is cancelled, or the call count, or now plus the time of the call and of the reserve at
    /// the mean call time so far (plus 0.5 ms for the QPs and bookkeeping between calls) past
    /// the deadline. Records the first limit reached ([`Self::reached`]).
    pub(crate) fn spent(&mut self, calls: usize) -> bool {
        if self.cancelled() {
            return true;
        }
        let limit = if self.max_calls.is_some_and(|m| calls + 1 + self.reserve > m) {
            BudgetLimit::Calls
        } else if self.deadline.is_some_and(|d| {
            let mean = if calls == 0 {
                Duration::ZERO
            } else {
                self.predictor_time / u32::try_from(calls).unwrap_or(u32::MAX)
            };
            let reserve = u32::try_from(self.reserve + 1).unwrap_or(u32::MAX);
            Instant::now() + mean * reserve + Duration::from_micros(500) > d
        }) {
            BudgetLimit::Seconds
        } else {
            return false;
        };
        self.reached.get_or_insert(limit);
        true
    }
}

/// Pairs with b below this value are kept as [`SafetyRow`]s (far pairs cannot become active
/// within one refinement step).
pub(crate) const ROW_B: f64 = 1.5;

/// One (vehicle, step) pair of a safety evaluation, linearised in the ego's position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SafetyRow {
    /// Step k (0-based: state z_{k+1}).
    pub step: usize,
    /// b at the evaluated point.
    pub b: f64,
    /// ∂b/∂(x_k, y_k) (1/m).
    pub gradient: [f64; 2],
}

impl<'c> SafetyEval<'c> {
    /// An evaluator of `constraint` for candidates in the frame centred at `origin`.
    pub(crate) fn new(
        constraint: &'c SafetyConstraint,
        origin: [f64; 2],
        horizon: usize,
        n_agents: usize,
        threshold: f64,
    ) -> Self {
        Self {
            constraint,
            origin,
            horizon,
            threshold,
            candidate: vec![0.0; horizon * 2],
            prediction: vec![0.0; n_agents.saturating_sub(1) * horizon * 2],
            ego_heading: vec![0.0; horizon],
            ego_speed: vec![0.0; horizon],
            violation_gradient: vec![[0.0; 2]; horizon],
            calls: 0,
            rows: Vec::new(),
            budget: Budget::unlimited(),
            keep_lane: None,
            count_overlap: false,
            ego_last: None,
            refused: 0,
        }
    }

    /// Ablates the reaction: from now on the predictor sees `path` (`[T, 2]`, road frame, m;
    /// [`crate::keep_lane_path`]) instead of each candidate, predicted once and reused, so
    /// every evaluation checks its candidate against the same prediction.
    pub(crate) fn ablate_reaction(&mut self, path: Vec<f64>) {
        debug_assert_eq!(path.len(), self.horizon * 2);
        self.keep_lane = Some(KeepLane {
            path,
            predicted: false,
        });
    }

    /// The prediction `[n − 1, T, 2]` (m) of the last evaluation.
    #[cfg(test)]
    pub(crate) fn prediction(&self) -> &[f64] {
        &self.prediction
    }

    /// The current candidate is one the predictors accept (finite, and within
    /// `nudge_predictor::limits::check_candidates` from [`SafetyEval::ego_last`]); always
    /// true without `ego_last`. An optimiser's trial point can overshoot by kilometres when
    /// ADMM's duals grow over a call whose dynamics cannot be met; it gets no prediction.
    fn representable(&self) -> bool {
        self.ego_last.is_none_or(|last| {
            self.candidate.iter().all(|c| c.is_finite())
                && nudge_predictor::limits::check_candidates(&self.candidate, self.horizon, last)
                    .is_ok()
        })
    }

    /// Fills `prediction` for the current candidate: the predictor on the candidate, or with
    /// the reaction ablated on the keep-lane path (only at the first evaluation).
    fn predict(&mut self, predictor: &mut dyn Predictor) -> Result<(), PlannerError> {
        let seen = match &self.keep_lane {
            Some(k) if k.predicted => return Ok(()),
            Some(k) => &k.path,
            None => &self.candidate,
        };
        let t0 = Instant::now();
        predictor.predict(seen, &mut self.prediction)?;
        self.budget.predictor_time += t0.elapsed();
        self.calls += 1;
        if let Some(k) = &mut self.keep_lane {
            k.predicted = true;
        }
        Ok(())
    }

    /// The threshold of the violation (b_min).
    pub(crate) fn threshold(&self) -> f64 {
        self.threshold
    }

    /// [`SafetyEval::eval`] of `z` against a second, non-reactive `predictor` (constant
    /// velocity, `PlannerSettings::fallback_nonreactive`): every candidate is predicted
    /// (the ablation's keep-lane path is bypassed), and neither the predictor-call count
    /// nor the refused count changes. Leaves `rows`, the gradient and the prediction to this
    /// evaluation, so callers take the planning predictor's rows first.
    pub(crate) fn eval_nonreactive(
        &mut self,
        predictor: &mut dyn Predictor,
        z: &[State],
    ) -> Result<Evaluation, PlannerError> {
        let keep_lane = self.keep_lane.take();
        let (calls, refused) = (self.calls, self.refused);
        let e = self.eval(predictor, z);
        self.keep_lane = keep_lane;
        (self.calls, self.refused) = (calls, refused);
        e
    }

    /// Evaluates the candidate states `z` (`[T]`, this call's frame); no predictor call when
    /// nothing is checked.
    pub(crate) fn eval(
        &mut self,
        predictor: &mut dyn Predictor,
        z: &[State],
    ) -> Result<Evaluation, PlannerError> {
        let checked = self.constraint.vehicles();
        if checked.is_empty() {
            return Ok(Evaluation {
                min_b: None,
                violation: 0.0,
                path_min_b: None,
                path_violation: 0.0,
                ahead_violation: 0.0,
                overlap: 0.0,
            });
        }
        let t = self.horizon;
        for (k, zk) in z.iter().enumerate().take(t) {
            self.candidate[2 * k] = zk[0] + self.origin[0];
            self.candidate[2 * k + 1] = zk[1] + self.origin[1];
            self.violation_gradient[k] = [0.0; 2];
            self.ego_heading[k] = zk[2];
            self.ego_speed[k] = zk[3];
        }
        if self.budget.spent(self.calls) {
            self.budget.exhausted = true;
            self.rows.clear();
            return Ok(Evaluation::not_evaluated());
        }
        if self.keep_lane.is_none() && !self.representable() {
            self.refused += 1;
            self.rows.clear();
            return Ok(Evaluation::not_evaluated());
        }
        self.predict(predictor)?;
        let mut min_b = f64::INFINITY;
        let mut violation = 0.0;
        let mut path_min_b: Option<f64> = None;
        let mut path_violation = 0.0;
        let mut ahead_violation = 0.0;
        let mut overlap = 0.0;
        self.rows.clear();
        for v in checked {
            let base = (v.index - 1) * t * 2;
            let mut previous = v.last;
            for k in 0..t {
                let ego = [self.candidate[2 * k], self.candidate[2 * k + 1]];
                let other = [
                    self.prediction[base + 2 * k],
                    self.prediction[base + 2 * k + 1],
                ];
                let ego_state = [ego[0], ego[1], self.ego_heading[k], self.ego_speed[k]];
                let pair = self
                    .constraint
                    .pair(v, ego_state, previous, other, k + 1 == t);
                let (b, g) = self.constraint.b_and_gradient_of(v, &pair);
                let in_path = !self.constraint.beside_of(v, &pair);
                if self.count_overlap {
                    overlap += self.constraint.overlap_of(v, &pair);
                }
                previous = other;
                if in_path {
                    path_min_b = Some(path_min_b.map_or(b, |m| min_or_nan(m, b)));
                    if b <= self.threshold {
                        path_violation += self.threshold - b;
                        if other[0] > ego[0] {
                            ahead_violation += self.threshold - b;
                        }
                    }
                }
                min_b = min_or_nan(min_b, b);
                if b < ROW_B {
                    self.rows.push(SafetyRow {
                        step: k,
                        b,
                        gradient: g,
                    });
                }
                if b <= self.threshold {
                    violation += self.threshold - b;
                    self.violation_gradient[k][0] -= g[0];
                    self.violation_gradient[k][1] -= g[1];
                }
            }
        }
        if min_b.is_nan() {
            return Ok(Evaluation {
                min_b: Some(f64::NEG_INFINITY),
                violation: f64::INFINITY,
                path_min_b: Some(f64::NEG_INFINITY),
                path_violation: f64::INFINITY,
                ahead_violation: f64::INFINITY,
                overlap: f64::INFINITY,
            });
        }
        Ok(Evaluation {
            min_b: Some(min_b),
            violation,
            path_min_b: path_min_b.map(|b| if b.is_nan() { f64::NEG_INFINITY } else { b }),
            path_violation,
            ahead_violation,
            overlap,
        })
    }
}
