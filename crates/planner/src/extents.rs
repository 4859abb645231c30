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
//!   that really ends (before the end) must end able to stop `stop_margin` before the end,
//!   braking at `stop_decel`: x_T + v_T² / (2 · `stop_decel`) ≤ end − `stop_margin`
//!   ([`Lanes::stop_excess`], counted like the lane excess, so a plan that breaks it is
//!   inadmissible). A plan that leaves the lane within the horizon (its last state in the
//!   target lane) is not held by it, only by safety; one that stays must keep the ego able
//!   to stop. While the ego's lane ends ahead within the rule's reach the fallbacks also
//!   offer **stopping sequences** (among the repairs of [`crate::Planner`]): braking at
//!   v² / (2 · (line − x)) towards the line `end − stop_margin` (within the jerk bound),
//!   steered along the road, to the own lane's centre, or to the goal. So a merging ego that finds no admissible plan
//!   into the target lane slows down and waits before the end instead of forcing its way in
//!   or driving past the end, and merges when a gap appears (the closed loop ends
//!   [`crate::sim::RunOutcome::Waiting`] when the step limit comes first).
//!
//! Why these. The admissibility rule is what makes a lane's end binding: without it nothing
//! stops a plan from driving on past the end. The deadline term is the urgency; the stopping
//! rule makes the end binding early enough to brake for it (the horizon, 1.8 s, is shorter
//! than the braking from 20 m/s). Measured (`cargo run --release -p nudge-planner --example
//! merge_deadline`): an ego at 20 m/s in an acceleration lane ending at x = 120 m beside a
//! 25 m/s platoon with one 30 m gap (its front 20, 60 or 100 m behind the ego), 40 closed-loop
//! steps, constant-velocity planning predictor. Without the stopping rule, in the `idm` world
//! (the platoon reacts) the default `w_deadline` = 60 merged in 3 of 3 runs (crossing at x =
//! 111 m) and `w_deadline` = 0 in none (3 `Collision`s); in the `log_replay` world (the
//! platoon never yields) the runs ended `LaneEnded` with the weight off and `Collision` with
//! it on (the ego forced its way in at x = 116–118 m). With the stopping rule (defaults
//! `stop_decel` = 3 m/s², `stop_margin` = 8 m): `idm` 3 of 3 `Success` with the weight on or
//! off (the ego slows down beside the platoon, a yielding follower opens a gap, the centre
//! crosses at x = 114 m); `log_replay` 3 of 3 `Waiting` (stopped or crawling, at most
//! 0.9 m/s, at x = 111–112 m after 40 steps; no collision, never past the end) with the
//! weight on or off. `stop_decel` 4 or 5 m/s² left the `idm` runs waiting too (the ego reaches the end faster and slower traffic has no time
//! to yield). Limitation: from a standstill at the line the ego cannot merge within the
//! `stop_margin` left (a plan that starts the merge ends still in the lane, closer to the
//! end than the rule allows); a gap that arrives while it is still rolling is taken (the
//! closed-loop tests of `crates/planner/tests/lane_extents.rs`). A hard lateral
//! bound tied to the end (y outside the ending lane from the step whose nominal x passes it)
//! was not chosen: it depends on the nominal x, not the candidate's, so a plan that brakes
//! before the end would be judged against the wrong steps.
//!
//! * **The target the simulator draws** ([`crate::target_lane`]): an adjacent lane that is open
//!   at the ego's x and does not really end within the run's reach ([`crate::target_reach`]:
//!   `max_steps` · `dt` · v_0 + `deadline_distance` ahead), so a run never asks the ego to
//!   change into a lane that ends before it could finish the change and travel on (on US-101
//!   the auxiliary lane was drawn for egos beside it 44 m before its end: 30 of 1778 test and
//!   545 of 7071 train scenarios draw differently now; scenes without real ends draw as before).
//!
//! The other vehicles are not subject to these rules: in the `idm` world every other vehicle
//! keeps its lane and lateral position, except that one whose lane really ends changes into
//! the adjacent lane when a gap is acceptable by the world's safety criterion and otherwise
//! stops before the end ([`crate::sim::LaneEndMerge`], [`crate::sim::idm`]); in the
//! `log_replay` world vehicles follow the log, and in the `teacher` world the teacher's
//! prediction.

use serde::{Deserialize, Serialize};

use crate::error::PlannerError;
use crate::scenario::LaneExtent;

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

    /// How far a centre at (`x`, `y`) moving at `v` (m/s) along the road breaks the stopping
    /// rule (m): in a lane that really ends, before its end, the stopping point braking at
    /// `decel` (m/s², > 0) must lie at least `margin` (m) before the end,
    /// x + v² / (2 · `decel`) ≤ end − `margin`; the excess of the left side over the right,
    /// 0 when it holds, elsewhere, or past the end (where [`Lanes::excess`] counts).
    #[must_use]
    pub fn stop_excess(&self, x: f64, y: f64, v: f64, decel: f64, margin: f64) -> f64 {
        let Some(lane) = self.lane_at(y) else {
            return 0.0;
        };
        let e = self.extents[lane];
        if !e.ends || x > e.end {
            return 0.0;
        }
        let v = v.max(0.0);
        (x + v * v / (2.0 * decel) - (e.end - margin)).max(0.0)
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
        assert_eq!(l.stop_line(100.0, 0.0, 8.0), Some(112.0));
        assert_eq!(l.stop_line(121.0, 0.0, 8.0), None, "past the end");
        assert_eq!(l.stop_line(100.0, 3.7, 8.0), None, "lane 1 runs on");
        assert_eq!(
            l.stop_excess(62.0, 0.0, 20.0, 4.0, 8.0),
            0.0,
            "stops at 112 exactly"
        );
        assert!((l.stop_excess(70.0, 0.0, 20.0, 4.0, 8.0) - 8.0).abs() < 1e-12);
        assert!((l.stop_excess(115.0, 0.0, 0.0, 4.0, 8.0) - 3.0).abs() < 1e-12);
        assert_eq!(
            l.stop_excess(70.0, 3.7, 20.0, 4.0, 8.0),
            0.0,
            "not an ending lane"
        );
        assert_eq!(
            l.stop_excess(121.0, 0.0, 0.0, 4.0, 8.0),
            0.0,
            "past the end"
        );
        assert_eq!(
            l.stop_excess(40.0, 7.0, 30.0, 4.0, 8.0),
            0.0,
            "lane 2 never ends"
        );
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
