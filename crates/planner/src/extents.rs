//! Lanes that begin and end along the road ("nudge.scenario/2" lane extents) as the planner and
//! the simulator use them.
//!
//! A planning problem may carry the lane layout ([`crate::PlanningProblem::lanes`], [`Lanes`]):
//! the lane boundaries across the road and where each lane begins and ends along it. Only
//! *real* begins and ends count ([`LaneExtent::begins`], [`LaneExtent::ends`]: an on-ramp
//! joining, an acceleration or exit lane ending); where only the lane map starts or stops the
//! lane is taken to run on. The rules:
//!
//! * **Admissibility** (a hard constraint on the roll-out): a planned state whose centre lies in
//!   a lane that has not begun yet, or has ended, at its x is inadmissible, like a state off the
//!   road. The execution check ranks such a roll-out by its *lane excess*
//!   ([`Lanes::excess`]: the smaller of how far the centre is past the end, or before the
//!   begin, and how far it is from leaving the lane sideways, m) and repairs it; a plan that
//!   still has one is [`crate::PlanStatus::Unsafe`] and names the first such state
//!   ([`crate::Plan::lane_violation`]).
//! * **A lane not yet begun is never entered for less elsewhere**: when no candidate is
//!   admissible, one that puts a centre in a lane before it begins ranks below every one that
//!   does not, whatever their violations (the ranking of the execution check's repairs). By
//!   the lane excess alone a centre 3.6 mm across the line of a closed on-ramp (excess
//!   0.0036 m) outranked the shifted previous plan, whose only fault was its last state
//!   0.024 m outside the lateral corridor (the corridor moves with the start, so a plan that
//!   turned back from the line left it when shifted), and the ego entered the ramp 2.3 m
//!   before it began (found by the property test at v = 21.415 m/s).
//! * **A lane not yet begun as the goal**: while the lateral target lies in a lane that
//!   really begins beyond the horizon's reach (x_0 + v_0 · T · dt), the call aims at the
//!   centre of the ego's own lane instead (without it the ego pressed against the line of the
//!   closed lane and, with no admissible plan left, crossed it: found by the property test).
//! * **Urgency** (a cost): while the ego's centre is in a lane that really ends ahead and the
//!   lateral target lies outside that lane (a merge), the weight of the lateral tracking error
//!   grows as the remaining distance d to the end (m, from the ego's centre) shrinks:
//!   w_y + `w_deadline` · φ(d), φ(d) = clamp(1 − d / `deadline_distance`, 0, 1)²
//!   ([`deadline_factor`]). The deadline term w_deadline · φ(d) · Σ_k (y_k − y_target)² is a
//!   quadratic in the planned y with a weight fixed for the call, so every phase of the ADMM
//!   (and the joint reference QP) sees it as a larger w_y. Beyond `deadline_distance` from the
//!   end the weight is w_y itself, bit for bit.
//!
//! * **Stopping rule** (a terminal constraint): a plan whose last state's centre is in a lane
//!   that really ends (before the end) must end able to stop before the end, braking at
//!   `stop_decel`: x_T + v_T² / (2 · `stop_decel`) ≤ end − m ([`Lanes::stop_excess`], counted
//!   like the lane excess, so a plan that breaks it is inadmissible). The margin m is
//!   `stop_margin`, except that **sideways progress is credited**: a last state heading out of
//!   the lane (|ψ_T| at least half `heading_max`) needs only m = min(`stop_margin`, the
//!   distance it takes to leave the lane, [`Lanes::leave_distance`]: steering out at the
//!   bounds into an adjacent lane open there). A plan that leaves the lane within the horizon
//!   (its last state in the target lane) is not held by the rule, only by safety; one that
//!   stays must keep the ego able to stop. The rule binds while the ego's start could still
//!   comply braking at −`a_min` (the planner's hardest braking); past that point the ego is
//!   committed (`stop_rule` of the planner's set-up). While the ego's lane ends ahead within
//!   the rule's reach the fallbacks also offer **stopping sequences** (among the repairs of
//!   [`crate::Planner`]): braking at v² / (2 · (line − x)) towards the line
//!   `end − stop_margin` (within the jerk bound), steered along the road, to the own lane's
//!   centre, or to the goal. So a merging ego that finds no admissible plan into the target
//!   lane slows down and waits before the end instead of forcing its way in or driving past
//!   the end, and merges when a gap appears, from a standstill too (the closed loop ends
//!   the simulator's `RunOutcome::Waiting` when the step limit comes first).
//!
//! * **The target the simulator draws** (the simulator's `target_lane`): an adjacent lane that is open
//!   at the ego's x and does not really end within the run's reach (`target_reach`:
//!   `max_steps` · `dt` · v_0 + `deadline_distance` ahead), so a run never asks the ego to
//!   change into a lane that ends before it could finish the change and travel on (on US-101
//!   the auxiliary lane was drawn for egos beside it 44 m before its end: 30 of 1778 test and
//!   545 of 7071 train scenarios draw differently now; scenes without real ends draw as before).
//!
//! Why these. The admissibility rule is what makes a lane's end binding: without it nothing
//! stops a plan from driving on past the end. The deadline term is the urgency; the stopping
//! rule makes the end binding early enough to brake for it (the horizon, 1.8 s, is shorter
//! than the braking from 20 m/s). Measured (the simulator crate's
//! `merge_deadline` example): an ego at 20 m/s in an acceleration lane ending at x = 120 m beside a
//! 25 m/s platoon with one 30 m gap (its front 20, 60 or 100 m behind the ego), 40 closed-loop
//! steps, constant-velocity planning predictor. Without the stopping rule, in the `idm` world
//! (the platoon reacts) the default `w_deadline` = 60 merged in 3 of 3 runs (crossing at x =
//! 111 m) and `w_deadline` = 0 in none (3 `Collision`s); in the `log_replay` world (the
//! platoon never yields) the runs ended `LaneEnded` with the weight off and `Collision` with
//! it on (the ego forced its way in at x = 116–118 m). With the stopping rule (defaults
//! `stop_decel` = 3 m/s², `stop_margin` = 12 m): `idm` 3 of 3 `Success` with the default
//! weight (the ego slows down beside the platoon, a yielding follower opens a gap, the centre
//! crosses at x = 113 m; with the weight off the ego waits, 3 `Waiting`); `log_replay` 3 of 3
//! `Waiting` (stopped or crawling, at most 0.2 m/s, at x = 107–108 m after 40 steps; no
//! collision, never past the end) with the weight on or off. `stop_decel` 4 or 5 m/s² left the
//! `idm` runs waiting too (the ego reaches the end faster and slower traffic has no time to
//! yield). The sideways credit and the 12 m margin let a stopped ego merge: from a standstill
//! at a lane's centre the bicycle at the steering and heading bounds needs about 10 m of road
//! to get its centre across the line of a 3.7 m lane, so at the former 8 m, or with the full
//! margin required of every state in the lane, an ego that had stopped never merged (the test
//! `an_ego_stopped_before_the_end_merges_once_the_main_lane_empties`: `Waiting` to the step
//! limit, then `Success`). Credit is given only to a state heading out at half `heading_max`
//! or more: crediting every state by its distance to the line let a blocked ego creep along
//! the line up to where it could just still leave, and stay there. On the 105 merge
//! scenarios of the train split (2 seeds, constant velocity and student, `teacher`, `idm`,
//! `log_replay` worlds; `docs/results/merge_closed_loop.md`) the credit, the 12 m margin and
//! the gate at −`a_min` (instead of `stop_decel`, which let an ego that slipped past the
//! comfortable stopping point drive on to `LaneEnded`) turned 8 failed runs of the rule
//! before into successes and 4 successes into failures (1,186 → 1,190 of 1,260), and 4 runs
//! with a collision into none (2 `Success`, 2 `LaneEnded`). A hard lateral bound tied to the
//! end (y outside the ending lane from the step whose nominal x passes it) was not chosen: it
//! depends on the nominal x, not the candidate's, so a plan that brakes before the end would
//! be judged against the wrong steps.
//!
//! The other vehicles are not subject to these rules: in the `idm` world every other vehicle
//! keeps its lane and lateral position, except that one whose lane really ends changes into
//! the adjacent lane when a gap is acceptable by the world's safety criterion and otherwise
//! stops before the end (the simulator's `LaneEndMerge`, its `idm` world); in the
//! `log_replay` world vehicles follow the log, and in the `teacher` world the teacher's
//! prediction.

use serde::{Deserialize, Serialize};

/// Where one lane lies along the road (schema "nudge.scenario/2"), road-frame x (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneExtent {
    /// x where the lane begins (m); `begin < end`.
    pub begin: f64,
    /// x where the lane ends (m).
    pub end: f64,
    /// The lane really begins at `begin` (an on-ramp joining); `false`: the lane map starts there.
    pub begins: bool,
    /// The lane really ends at `end` (an acceleration or exit lane: a vehicle staying on the road
    /// must leave it before); `false`: the lane map stops there.
    pub ends: bool,
}

use crate::error::PlannerError;

/// The lane layout of a planning problem: boundaries across the road and each lane's extent
/// along it (road frame, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lanes<'a> {
    /// Lane-boundary y, strictly ascending `[L + 1]` (m); lane j lies between `bounds[j]` and
    /// `bounds[j + 1]`.
    pub bounds: &'a [f64],
    /// Extent of each lane along x `[L]` (m), in `bounds` order.
    pub extents: &'a [LaneExtent],
}

/// How a position lies outside its lane's extent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum LaneViolationKind {
    /// The lane has really ended before this x.
    Ended,
    /// The lane really begins after this x.
    NotBegun,
}

/// A planned state whose centre lies in a lane outside its extent.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LaneViolation {
    /// Plan step (1-based: state z_step of the plan).
    pub step: usize,
    /// Index of the lane (in [`Lanes::bounds`] order).
    pub lane: usize,
    /// Ended or not begun.
    pub kind: LaneViolationKind,
    /// x of the state's centre (m).
    pub x: f64,
}

/// Largest |coordinate| accepted in a lane layout (m), as for positions.
const MAX_ABS: f64 = nudge_predictor::limits::MAX_ABS_POSITION;

/// The deadline factor φ(d) = clamp(1 − d / `distance`, 0, 1)² of a remaining distance `d`
/// (m) to the end of the ego's lane, with `distance` > 0 (m) where the deadline starts to
/// count: 0 at and beyond `distance`, 1 at and past the end.
#[must_use]
pub fn deadline_factor(d: f64, distance: f64) -> f64 {
    let u = (1.0 - d / distance).clamp(0.0, 1.0);
    u * u
}

/// The stopping rule of a lane that really ends ([`Lanes::stop_excess`]): how hard the ego
/// may brake for it and how far before the end it must be able to stop, and the steering
/// bounds that say how soon it can leave the lane sideways ([`Lanes::leave_distance`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StopRule {
    /// Deceleration of the stopping point (m/s², > 0): `stop_decel`.
    pub decel: f64,
    /// How far before the end the ego must be able to stop (m) while it is farther than
    /// that from leaving the lane: `stop_margin`.
    pub margin: f64,
    /// Largest heading relative to the road (rad): `heading_max`.
    pub heading_max: f64,
    /// Largest slip angle β = atan(l_r / (l_f + l_r) · tan δ_max) (rad).
    pub beta_max: f64,
    /// Largest change of heading per metre travelled, sin β_max / l_r (rad/m).
    pub turn_rate: f64,
}

impl StopRule {
    /// The rule of `s`: `stop_decel`, `stop_margin`, `heading_max`, and the slip angle and
    /// turn rate of the bicycle (`l_f`, `l_r`) at full steering `delta_max`.
    #[must_use]
    pub fn new(s: &crate::PlannerSettings) -> Self {
        let beta_max =
            (s.model.l_r / (s.model.l_f + s.model.l_r) * s.bounds.delta_max.tan()).atan();
        Self {
            decel: s.lane_ends.stop_decel,
            margin: s.lane_ends.stop_margin,
            heading_max: s.bounds.heading_max,
            beta_max,
            turn_rate: beta_max.sin() / s.model.l_r,
        }
    }

    /// The distance along the road (m) a centre `gap` (m, > 0) from a line, heading `psi`
    /// (rad, positive towards the line), needs to reach it steering towards it at the bound:
    /// the direction of travel ψ + β_max turns at `turn_rate` per metre until the heading
    /// reaches `heading_max` (the lateral gain over s metres is (ψ + β_max) s + turn_rate s²/2),
    /// then runs straight at `heading_max`. 0 for a centre on or past the line.
    #[must_use]
    pub fn distance_to_cross(&self, gap: f64, psi: f64) -> f64 {
        if gap <= 0.0 {
            return 0.0;
        }
        let (k, top) = (self.turn_rate, self.heading_max);
        if psi >= top {
            return gap / psi.tan();
        }
        let d0 = psi + self.beta_max;
        let s1 = (top - psi) / k;
        let gained = d0 * s1 + 0.5 * k * s1 * s1;
        if gained >= gap {
            (-d0 + (d0 * d0 + 2.0 * k * gap).sqrt()) / k
        } else {
            s1 + (gap - gained) / top.tan()
        }
    }
}

impl Lanes<'_> {
    /// Number of lanes L.
    #[must_use]
    pub fn len(&self) -> usize {
        self.extents.len()
    }

    /// Whether there are no lanes (never, once [`Lanes::check`] passed).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.extents.is_empty()
    }

    /// Checks the layout: at least one lane, L + 1 finite, strictly ascending boundaries within
    /// ±1e6 m; every extent finite, within ±1e6 m, begin < end.
    ///
    /// # Errors
    /// [`PlannerError::BadLane`] naming the lane and the field (`bounds`, `begin`, `end`).
    pub fn check(&self) -> Result<(), PlannerError> {
        let bad = |lane: usize, field: &'static str, reason: String| {
            Err(PlannerError::BadLane {
                lane,
                field,
                reason,
            })
        };
        let nl = self.extents.len();
        if nl == 0 || self.bounds.len() != nl + 1 {
            return bad(
                0,
                "bounds",
                format!(
                    "{} boundaries for {nl} lane extents; L + 1 boundaries for L >= 1 lanes",
                    self.bounds.len()
                ),
            );
        }
        for (j, &y) in self.bounds.iter().enumerate() {
            // Boundary j > 0 is the left boundary of lane j − 1; boundary 0 the right one of lane 0.
            let lane = j.saturating_sub(1);
            if !y.is_finite() || y.abs() > MAX_ABS {
                return bad(
                    lane,
                    "bounds",
                    format!("boundary {j} y = {y} m is not finite within ±{MAX_ABS} m"),
                );
            }
            if j > 0 && self.bounds[j - 1] >= y {
                return bad(
                    j - 1,
                    "bounds",
                    format!(
                        "boundaries {} m and {y} m are not strictly ascending",
                        self.bounds[j - 1]
                    ),
                );
            }
        }
        for (lane, e) in self.extents.iter().enumerate() {
            for (field, v) in [("begin", e.begin), ("end", e.end)] {
                if !v.is_finite() || v.abs() > MAX_ABS {
                    return bad(
                        lane,
                        field,
                        format!("x = {v} m is not finite within ±{MAX_ABS} m"),
                    );
                }
            }
            if e.begin >= e.end {
                return bad(
                    lane,
                    "end",
                    format!(
                        "the lane ends at {} m, not after its begin {} m",
                        e.end, e.begin
                    ),
                );
            }
        }
        Ok(())
    }

    /// The lane whose band holds lateral position `y` (m): lane j when
    /// `bounds[j] <= y < bounds[j + 1]` (the left edge counts to the last lane); `None` off
    /// the road (and for a layout without L + 1 boundaries).
    #[must_use]
    pub fn lane_at(&self, y: f64) -> Option<usize> {
        let nl = self.extents.len();
        // A layout that fails [`Lanes::check`] (the wrong number of boundaries) holds no lane.
        if nl == 0
            || self.bounds.len() != nl + 1
            || !(self.bounds[0]..=self.bounds[nl]).contains(&y)
        {
            return None;
        }
        Some(self.bounds[1..nl].partition_point(|&b| b <= y))
    }

    /// Whether the band from `lo` to `hi` across the road (m, `lo` ≤ `hi`) spans a lane line:
    /// an interior boundary lies strictly inside it. The road's outer edges are not lane
    /// lines.
    #[must_use]
    pub fn spans_line(&self, lo: f64, hi: f64) -> bool {
        let n = self.bounds.len();
        n > 2 && self.bounds[1..n - 1].iter().any(|&b| lo < b && b < hi)
    }

    /// The lane and how a centre at (`x`, `y`) (m) lies outside its lane's extent, counting
    /// only real begins and ends; `None` when it is inside (or off the road).
    #[must_use]
    pub fn outside(&self, x: f64, y: f64) -> Option<(usize, LaneViolationKind)> {
        let lane = self.lane_at(y)?;
        let e = self.extents[lane];
        if e.ends && x > e.end {
            Some((lane, LaneViolationKind::Ended))
        } else if e.begins && x < e.begin {
            Some((lane, LaneViolationKind::NotBegun))
        } else {
            None
        }
    }

    /// How far a centre at (`x`, `y`) (m) is from admissible (m): 0 inside its lane's extent,
    /// else the smaller of the distance along x back into the extent and the distance across
    /// to the nearer boundary of the lane.
    #[must_use]
    pub fn excess(&self, x: f64, y: f64) -> f64 {
        match self.outside(x, y) {
            None => 0.0,
            Some((lane, kind)) => {
                let e = self.extents[lane];
                let along = match kind {
                    LaneViolationKind::Ended => x - e.end,
                    LaneViolationKind::NotBegun => e.begin - x,
                };
                let across = (y - self.bounds[lane]).min(self.bounds[lane + 1] - y);
                along.min(across)
            }
        }
    }

    /// The first state of `states` (road-frame (x, y, ...), plan steps 1..) outside its lane's
    /// extent.
    #[must_use]
    pub fn first_violation(&self, states: &[[f64; 4]]) -> Option<LaneViolation> {
        states.iter().enumerate().find_map(|(k, z)| {
            self.outside(z[0], z[1]).map(|(lane, kind)| LaneViolation {
                step: k + 1,
                lane,
                kind,
                x: z[0],
            })
        })
    }

    /// How far a centre at (`x`, `y`) heading `psi` (rad, relative to the road) and moving at
    /// `v` (m/s) along the road breaks the stopping rule `rule` (m): in a lane that really
    /// ends, before its end, the stopping point braking at `rule.decel` must lie at least the
    /// margin m before the end, x + v² / (2 · decel) ≤ end − m. The margin is `rule.margin`;
    /// for a centre heading out of the lane (|ψ| ≥ `rule.heading_max` / 2) sideways progress is
    /// credited: m = min(`rule.margin`, [`Lanes::leave_distance`]), so an ego steering out may
    /// creep on as close to the end as it can still leave the lane before it. The excess of
    /// the left side over the right; 0 when it holds, elsewhere, or past the end (where
    /// [`Lanes::excess`] counts).
    #[must_use]
    pub fn stop_excess(&self, x: f64, y: f64, psi: f64, v: f64, rule: &StopRule) -> f64 {
        let Some(lane) = self.lane_at(y) else {
            return 0.0;
        };
        let e = self.extents[lane];
        if !e.ends || x > e.end {
            return 0.0;
        }
        let v = v.max(0.0);
        let committed = psi.abs() >= 0.5 * rule.heading_max;
        let margin = if committed {
            self.leave_distance(x, y, psi, rule)
                .map_or(rule.margin, |d| d.min(rule.margin))
        } else {
            rule.margin
        };
        (x + v * v / (2.0 * rule.decel) - (e.end - margin)).max(0.0)
    }

    /// The distance along the road (m) a centre at (`x`, `y`) heading `psi` (rad) needs to
    /// leave its lane, which really ends, into an adjacent lane open where it crosses:
    /// steering out at the bound of `rule` towards the side it heads to (left for ψ > 0, right
    /// for ψ < 0, the nearer of the two for ψ = 0; small-angle kinematics: the
    /// direction of travel turns at `rule.turn_rate` per metre from ψ + `rule.beta_max` until
    /// the heading reaches `rule.heading_max`, then runs straight at that heading). `None` in
    /// a lane that does not really end, or without an adjacent lane open at the crossing.
    #[must_use]
    pub fn leave_distance(&self, x: f64, y: f64, psi: f64, rule: &StopRule) -> Option<f64> {
        let lane = self.lane_at(y)?;
        if !self.extents[lane].ends {
            return None;
        }
        let side = |sign: f64, next: Option<usize>| -> Option<f64> {
            let next = next.filter(|&j| j < self.extents.len())?;
            let boundary = if sign > 0.0 {
                self.bounds[lane + 1]
            } else {
                self.bounds[lane]
            };
            let d = rule.distance_to_cross(sign * (boundary - y), sign * psi);
            let n = self.extents[next];
            let x_cross = x + d;
            let closed = (n.ends && x_cross > n.end) || (n.begins && x_cross < n.begin);
            (!closed).then_some(d)
        };
        let left = (psi >= 0.0).then(|| side(1.0, Some(lane + 1))).flatten();
        let right = (psi <= 0.0)
            .then(|| side(-1.0, lane.checked_sub(1)))
            .flatten();
        match (left, right) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The stopping line of a centre at (`x`, `y`) (m): `end − margin` (m) of its lane when
    /// that lane really ends and `x` is not past the end; `None` otherwise.
    #[must_use]
    pub fn stop_line(&self, x: f64, y: f64, margin: f64) -> Option<f64> {
        let lane = self.lane_at(y)?;
        let e = self.extents[lane];
        (e.ends && x <= e.end).then_some(e.end - margin)
    }

    /// The remaining distance (m) from a centre at (`x`, `y`) to the real end of its lane,
    /// when that lane really ends and `y_target` (m) lies outside it (a merge is due); may be
    /// negative past the end. `None` otherwise.
    #[must_use]
    pub fn merge_deadline(&self, x: f64, y: f64, y_target: f64) -> Option<f64> {
        let lane = self.lane_at(y)?;
        let e = self.extents[lane];
        let target_inside = (self.bounds[lane]..self.bounds[lane + 1]).contains(&y_target);
        (e.ends && !target_inside).then_some(e.end - x)
    }
}

/// An owned copy of a [`Lanes`] for one planning call.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LaneTable {
    bounds: Vec<f64>,
    extents: Vec<LaneExtent>,
}

impl LaneTable {
    /// A copy of `lanes`.
    pub(crate) fn new(lanes: &Lanes<'_>) -> Self {
        Self {
            bounds: lanes.bounds.to_vec(),
            extents: lanes.extents.to_vec(),
        }
    }

    /// The borrowed view.
    pub(crate) fn view(&self) -> Lanes<'_> {
        Lanes {
            bounds: &self.bounds,
            extents: &self.extents,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Acceleration lane 0 (y in [-1.85, 1.85]) ends for real at x = 120; main lane 1 runs
    /// through; lane 2 (an on-ramp on the left, for the test) begins for real at x = 50.
    fn layout() -> (Vec<f64>, Vec<LaneExtent>) {
        let e = |begin, end, begins, ends| LaneExtent {
            begin,
            end,
            begins,
            ends,
        };
        (
            vec![-1.85, 1.85, 5.55, 9.25],
            vec![
                e(-500.0, 120.0, false, true),
                e(-500.0, 500.0, false, false),
                e(50.0, 500.0, true, false),
            ],
        )
    }

    #[test]
    fn lanes_and_violations() {
        let (b, x) = layout();
        let l = Lanes {
            bounds: &b,
            extents: &x,
        };
        assert!(l.check().is_ok());
        assert_eq!(l.lane_at(-1.85), Some(0));
        assert_eq!(l.lane_at(1.85), Some(1));
        assert_eq!(l.lane_at(9.25), Some(2));
        assert_eq!(l.lane_at(9.26), None);
        assert_eq!(l.outside(119.9, 0.0), None);
        assert_eq!(l.outside(120.5, 0.0), Some((0, LaneViolationKind::Ended)));
        assert_eq!(l.outside(49.0, 7.0), Some((2, LaneViolationKind::NotBegun)));
        assert_eq!(l.outside(1e5, 3.7), None, "lane 1 runs on");
        // Past the end by 0.5 m, 1.35 m from the lane line: the smaller counts.
        assert!((l.excess(120.5, 0.5) - 0.5).abs() < 1e-12);
        assert!((l.excess(130.0, 1.5) - 0.35).abs() < 1e-12);
        assert_eq!(l.excess(100.0, 0.0), 0.0);
        let v = l.first_violation(&[[110.0, 0.0, 0.0, 0.0], [121.0, 0.0, 0.0, 0.0]]);
        assert_eq!(
            v,
            Some(LaneViolation {
                step: 2,
                lane: 0,
                kind: LaneViolationKind::Ended,
                x: 121.0
            })
        );
        assert_eq!(l.merge_deadline(100.0, 0.0, 3.7), Some(20.0));
        assert_eq!(l.merge_deadline(100.0, 0.0, 0.0), None, "no merge");
        assert_eq!(l.merge_deadline(100.0, 3.7, 7.4), None, "lane 1 runs on");
    }

    #[test]
    fn stopping_rule_before_the_end_of_an_ending_lane() {
        let (b, x) = layout();
        let l = Lanes {
            bounds: &b,
            extents: &x,
        };
        // Lane 0 ends at 120: stop line 120 − 8 = 112; at 20 m/s braking at 4 m/s² takes 50 m.
        // (Lane 0's way out, lane 1, is 1.85 m from its centre: more than 8 m of road away.)
        let rule48 = StopRule {
            decel: 4.0,
            margin: 8.0,
            ..StopRule::new(&crate::PlannerSettings::default())
        };
        assert_eq!(l.stop_line(100.0, 0.0, 8.0), Some(112.0));
        assert_eq!(l.stop_line(121.0, 0.0, 8.0), None, "past the end");
        assert_eq!(l.stop_line(100.0, 3.7, 8.0), None, "lane 1 runs on");
        assert_eq!(
            l.stop_excess(62.0, 0.0, 0.0, 20.0, &rule48),
            0.0,
            "stops at 112 exactly"
        );
        assert!((l.stop_excess(70.0, 0.0, 0.0, 20.0, &rule48) - 8.0).abs() < 1e-12);
        assert!((l.stop_excess(115.0, 0.0, 0.0, 0.0, &rule48) - 3.0).abs() < 1e-12);
        assert_eq!(
            l.stop_excess(70.0, 3.7, 0.0, 20.0, &rule48),
            0.0,
            "not an ending lane"
        );
        assert_eq!(
            l.stop_excess(121.0, 0.0, 0.0, 0.0, &rule48),
            0.0,
            "past the end"
        );
        assert_eq!(
            l.stop_excess(40.0, 7.0, 0.0, 30.0, &rule48),
            0.0,
            "lane 2 never ends"
        );
    }

    /// The distance a bicycle (the planner's model, stepped 1 mm at a time at 1 m/s) drives
    /// along x before its centre gains `gap` sideways, steering at `delta_max` until its
    /// heading reaches `heading_max`, then straight on at that heading.
    fn crossing_by_the_bicycle(gap: f64, psi: f64, s: &crate::PlannerSettings) -> f64 {
        let bike = crate::model::Bicycle {
            l_f: s.model.l_f,
            l_r: s.model.l_r,
            dt: 1e-3,
        };
        let mut z = crate::model::State::new(0.0, 0.0, psi, 1.0);
        while z[1] < gap {
            let delta = if z[2] < s.bounds.heading_max {
                s.bounds.delta_max
            } else {
                0.0
            };
            z = bike.advance(&z, delta, 0.0);
            assert!(z[0] < 1e3, "never crosses");
        }
        z[0]
    }

    #[test]
    fn the_distance_to_leave_a_lane_is_the_bicycles_at_the_steering_bounds() {
        let s = crate::PlannerSettings::default();
        let rule = StopRule::new(&s);
        // Within a few centimetres (the bicycle's steering snaps off at the heading bound;
        // small angles) over lateral gaps of a lane and headings from away to beyond the bound.
        for (gap, psi) in [
            (1.85, 0.0),
            (1.0, 0.1),
            (0.3, 0.0),
            (1.85, -0.05),
            (1.2, 0.2),
            (0.9, 0.25),
        ] {
            let want = crossing_by_the_bicycle(gap, psi, &s);
            let got = rule.distance_to_cross(gap, psi);
            assert!(
                (got - want).abs() <= 0.03 * want + 0.05,
                "gap {gap} psi {psi}: {got} vs the bicycle's {want}"
            );
        }
        assert_eq!(rule.distance_to_cross(0.0, 0.0), 0.0);
        // From a lane's centre about 10 m (the reason `stop_margin` is 12 m).
        let from_centre = rule.distance_to_cross(1.85, 0.0);
        assert!((9.0..10.5).contains(&from_centre), "{from_centre}");
    }

    #[test]
    fn the_stopping_rule_credits_a_way_out_of_the_lane() {
        let (b, x) = layout();
        let l = Lanes {
            bounds: &b,
            extents: &x,
        };
        let rule = StopRule::new(&crate::PlannerSettings::default());
        let margin = rule.margin;
        // Standing 1 m past the stopping line in lane 0 (ends at 120), 0.5 m from its left
        // line: heading straight on it breaks the rule by 1 m; heading out at 0.15 rad it
        // needs only the distance to leave, and the credit holds while that fits before the end.
        let x0 = 120.0 - margin + 1.0;
        assert!((l.stop_excess(x0, 1.35, 0.0, 0.0, &rule) - 1.0).abs() < 1e-12);
        let out = l
            .leave_distance(x0, 1.35, 0.15, &rule)
            .expect("a way out to the left");
        assert!((out - rule.distance_to_cross(0.5, 0.15)).abs() < 1e-12);
        assert!(out < margin - 1.0);
        assert_eq!(l.stop_excess(x0, 1.35, 0.15, 0.0, &rule), 0.0);
        // Heading out too little (below half the heading bound) earns no credit.
        assert!((l.stop_excess(x0, 1.35, 0.09, 0.0, &rule) - 1.0).abs() < 1e-12);
        // Towards the road's edge there is no way out (the lane on the other side does not
        // count while the ego heads away from it): the full margin.
        assert_eq!(l.leave_distance(x0, -1.35, -0.15, &rule), None);
        assert!((l.stop_excess(x0, -1.35, -0.15, 0.0, &rule) - 1.0).abs() < 1e-12);
        // Moving, the stopping distance counts as before: 10 m/s adds 100 / 6 m at 3 m/s².
        let want = x0 - 5.0 + 100.0 / (2.0 * rule.decel) - (120.0 - out);
        assert!(want > 0.0);
        let moving = l.stop_excess(x0 - 5.0, 1.35, 0.15, 10.0, &rule);
        assert!((moving - want).abs() < 1e-9, "{moving} vs {want}");
        // A lane that does not really end has no distance to leave.
        assert_eq!(l.leave_distance(50.0, 3.7, 0.15, &rule), None);
        // Lane 1 runs on; lane 2 (begins at 50) is no way out before it begins.
        let (b3, mut x3) = layout();
        x3[1].ends = true;
        x3[1].end = 300.0;
        let l3 = Lanes {
            bounds: &b3,
            extents: &x3,
        };
        assert_eq!(
            l3.leave_distance(20.0, 5.0, 0.2, &rule),
            None,
            "lane 2 not begun"
        );
        assert!(l3.leave_distance(60.0, 5.0, 0.2, &rule).is_some());
    }

    #[test]
    fn deadline_factor_grows_towards_the_end() {
        assert_eq!(deadline_factor(100.0, 100.0), 0.0);
        assert_eq!(deadline_factor(250.0, 100.0), 0.0);
        assert_eq!(deadline_factor(0.0, 100.0), 1.0);
        assert_eq!(deadline_factor(-5.0, 100.0), 1.0);
        assert!((deadline_factor(50.0, 100.0) - 0.25).abs() < 1e-15);
        let mut last = 0.0;
        for d in (0..=100).rev() {
            let f = deadline_factor(f64::from(d), 100.0);
            assert!(f >= last);
            last = f;
        }
    }

    #[test]
    fn bad_layouts_name_lane_and_field() {
        let (b, x) = layout();
        let check = |b: &[f64], x: &[LaneExtent]| match (Lanes {
            bounds: b,
            extents: x,
        })
        .check()
        {
            Err(PlannerError::BadLane { lane, field, .. }) => Some((lane, field)),
            Ok(()) => None,
            Err(e) => panic!("{e}"),
        };
        assert_eq!(check(&b[..3], &x), Some((0, "bounds")));
        let short = Lanes {
            bounds: &b[..3],
            extents: &x,
        };
        assert_eq!(short.lane_at(0.0), None, "a malformed layout holds no lane");
        assert_eq!(short.outside(1e4, 0.0), None);
        let mut b2 = b.clone();
        b2[2] = 1.0;
        assert_eq!(check(&b2, &x), Some((1, "bounds")));
        b2[2] = f64::NAN;
        assert_eq!(check(&b2, &x), Some((1, "bounds")));
        let mut x2 = x.clone();
        x2[2].begin = f64::INFINITY;
        assert_eq!(check(&b, &x2), Some((2, "begin")));
        let mut x3 = x.clone();
        x3[1].end = -600.0;
        assert_eq!(check(&b, &x3), Some((1, "end")));
        x3[1].end = 2e6;
        assert_eq!(check(&b, &x3), Some((1, "end")));
    }
}
