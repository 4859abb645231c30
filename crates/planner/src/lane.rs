//! The lane-change decision above the MPC: which lateral goal the planner aims at each step,
//! and when a lane change that finds no admissible plan is given up.
//!
//! The planner itself ([`crate::Planner`]) plans towards one lateral goal per call. A lane
//! change across a blocked target lane would otherwise idle across the lane line, straddling
//! two live lanes; and giving up late, after the ego has slowed down and half entered the
//! target lane, puts it back into its own lane's traffic at low speed. The rule:
//!
//! * **abort** after `abort_after` consecutive planning steps without an admissible plan
//!   (status `Fallback`, `Unsafe` or `SolverFailed`) while the ego's centre is still on its own
//!   side of the line between the two lanes: aim at the own lane's centre for `abort_hold`
//!   steps, then try again;
//! * **abort a stalled change** (with a positive `stall_progress`): a step whose ego centre
//!   moved less than `stall_progress` towards the target lane since the previous step, while
//!   its box straddles the line and its centre is still on its own side, counts towards the
//!   abort like a step without an admissible plan. A planner that finds admissible plans which
//!   edge over the line and stop there (in front of a closed gap) would otherwise idle across
//!   it for good;
//! * **abort at once from a straddling start** (with a positive `start_abort_after`,
//!   [`LaneChange::with_start_abort`]): an ego whose box starts across a line of its own lane
//!   (it spans the line, its centre still in its own lane) counts, until its first admissible
//!   plan, towards an abort after `start_abort_after` steps without an admissible plan
//!   instead of `abort_after`: with 1, the first step without an admissible plan turns the
//!   goal to the own lane's centre, so the planner (not only its fallbacks) plans the way
//!   back at once. One such abort per run; after it, or after the first admissible plan, or
//!   once the box is inside its own lane, `abort_after` applies;
//! * **commit** once the centre has crossed that line: from then on the change is finished,
//!   never aborted (going back would cross the line a second time);
//! * **retreat when stuck**: the own lane stays on offer to the planner's fallbacks
//!   ([`LaneChange::retreat`]) before the crossing, and after it only while the ego is stuck
//!   across the line (`abort_after` consecutive steps without an admissible plan, not yet
//!   wholly inside the target lane). The goal stays the target lane; the fallbacks pick
//!   going back only when it violates the predicted safety least;
//! * **seek a gap** (with a positive `gap_speed`, [`LaneChange::with_gap_seeking`]): while the
//!   goal is the target lane and the ego is not yet wholly inside it, a target-lane vehicle
//!   alongside the ego (bumper gap along the road below `gap_window`) blocks the change. The
//!   reference speed of the next planning step then leaves it: `gap_speed` faster than that
//!   vehicle when, at their current speeds, the ego will be ahead of it after the planning
//!   horizon, else `gap_speed` slower, but never more than `gap_speed` below the run's own
//!   reference ([`LaneChange::v_ref`]). Without it the planner keeps
//!   the ego's starting speed as its reference and can ride beside a target-lane vehicle of
//!   about its speed until the step budget runs out, half across the line. On validation
//!   (student planner, teacher world, 300 scenes × 3 seeds) it moved success 86.0 → 87.3 %
//!   (18 runs lost, 30 gained); dropping back without the `gap_speed` floor below the base
//!   (86.7 %) braked the ego behind slowing vehicles, and passing only (86.1 %) gained nothing.
//!   It is off by default (`SimConfig::gap_speed` 0): with it the teacher planner lost 17 of
//!   300 log-replay runs (89.0 → 83.3 %, 0 gained; 3 not-at-fault collisions), replayed
//!   drivers never opening the gap it speeds up or drops back for.
//! * **keep up with the flow after a crawl** (with a positive `crawl_fraction`,
//!   [`LaneChange::with_crawl_reference`]): the reference speed is the ego's starting speed,
//!   and an ego that starts queued at 1–3 m/s keeps planning that crawl after the traffic
//!   ahead has cleared. The first step at which the starting speed is below `crawl_fraction`
//!   × the goal lane's flow (the median speed of its vehicles within [`FLOW_RANGE_M`], or the
//!   last one seen once they are out of range) makes the ego crawling, and from then on its
//!   reference is at least that flow ([`LaneChange::v_ref`]). Egos that start at an ordinary
//!   speed keep their own reference. At 0.5 (the default) no validation run changes (the
//!   validation split has no crawling start); on 100 of the train split's 581 crawling
//!   starts × 3 seeds it raised the student planner's success in the teacher world from 29.0
//!   to 57.0 % and cut the runs with planned slow steps from 99 to 21
//!   (`docs/results/crawl_reference.md`).
//!
//! The closed-loop simulator applies it in every closed loop; a user embedding the planner
//! calls [`LaneChange::goal`] before and [`LaneChange::after_plan`] after each planning step.

use crate::admm::StepStatus;

/// Other vehicles within this distance along the road (m, centre to centre) make a lane's
/// flow ([`LaneChange::flow`]): also the range of the surrounding traffic of the closed-loop
/// metrics.
pub const FLOW_RANGE_M: f64 = 50.0;

/// The median (mean of the two middle values for an even count); `None` when empty.
#[must_use]
pub fn median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// The state of one lane change. Lateral positions are road-frame y (m, positive left).
#[derive(Debug, Clone, PartialEq)]
pub struct LaneChange {
    y_target: f64,
    y_own: f64,
    /// The line between the two lanes: the midpoint of their centres (m).
    y_line: f64,
    /// |y − y_target| below which the ego is wholly inside the target lane (m).
    inside: f64,
    abort_after: usize,
    abort_hold: usize,
    /// Half the ego's width (m): its box straddles the line while |y − y_line| < this.
    half_width: f64,
    /// Least progress per step towards the target (m) of a change that is not stalled; 0: off.
    stall_progress: f64,
    /// The ego's centre at the previous planning step (m).
    last_y: Option<f64>,
    /// Consecutive steps without an admissible plan, or stalled, before the crossing.
    unsafe_steps: usize,
    /// Consecutive steps without an admissible plan after the crossing, not yet inside.
    stuck_steps: usize,
    hold: usize,
    aborts: usize,
    /// Speed offset (m/s) from a blocking target-lane vehicle's speed; 0: gap seeking off.
    gap_speed: f64,
    /// Bumper gap along the road (m) below which a target-lane vehicle blocks.
    gap_window: f64,
    /// The ego's length (m).
    ego_length: f64,
    /// A base reference speed below this fraction of the goal lane's flow makes the ego
    /// crawling ([`LaneChange::with_crawl_reference`]); 0: off.
    crawl_fraction: f64,
    /// The ego has crawled: its reference speed keeps up with the goal lane's flow.
    crawling: bool,
    /// The last flow (m/s) seen in the target lane and in the own lane
    /// ([`LaneChange::flow`]).
    seen_flow: [Option<f64>; 2],
    /// Steps without an admissible plan before an abort while the start's straddle lasts
    /// ([`LaneChange::with_start_abort`]); 0: off.
    start_abort_after: usize,
    /// The ego started straddling a line of its own lane and has had no admissible plan,
    /// no start abort, and not yet been wholly inside its own lane since.
    straddling_start: bool,
}

/// Another vehicle as the gap seeking of [`LaneChange::v_ref`] sees it: its centre (road frame,
/// m), its speed along the road (m/s) and its length (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Neighbour {
    /// Centre along the road (m).
    pub x: f64,
    /// Centre across the road (m, positive left).
    pub y: f64,
    /// Speed along the road (m/s).
    pub v: f64,
    /// Length (m).
    pub length: f64,
}

impl LaneChange {
    /// A lane change from the lane centred at `y_own` to the one centred at `y_target` (m) of
    /// an ego `ego_width` wide (m); `settle_y` (m) is the smallest distance from the target
    /// centre counted as inside; aborts after `abort_after` steps without an admissible plan
    /// (0: never), holding the own lane for `abort_hold` steps.
    #[must_use]
    pub fn new(
        y_own: f64,
        y_target: f64,
        ego_width: f64,
        settle_y: f64,
        abort_after: usize,
        abort_hold: usize,
    ) -> Self {
        Self {
            y_target,
            y_own,
            y_line: 0.5 * (y_own + y_target),
            inside: (0.5 * (y_target - y_own).abs() - 0.5 * ego_width).max(settle_y),
            abort_after,
            abort_hold,
            half_width: 0.5 * ego_width,
            stall_progress: 0.0,
            last_y: None,
            unsafe_steps: 0,
            stuck_steps: 0,
            hold: 0,
            aborts: 0,
            gap_speed: 0.0,
            gap_window: 0.0,
            ego_length: 0.0,
            crawl_fraction: 0.0,
            crawling: false,
            seen_flow: [None, None],
            start_abort_after: 0,
            straddling_start: false,
        }
    }

    /// Turns on the abort from a straddling start for an ego whose centre starts at `y0`
    /// (m): when its box spans a line of its own lane (|y0 − y_own| above half the lane
    /// spacing less half the ego's width), steps without an admissible plan count towards an
    /// abort after `start_abort_after` of them (0: off) until the first admissible plan, the
    /// first such abort, or the box wholly inside its own lane.
    #[must_use]
    pub fn with_start_abort(mut self, start_abort_after: usize, y0: f64) -> Self {
        self.start_abort_after = start_abort_after;
        self.straddling_start = start_abort_after > 0 && self.straddles_own_lane(y0);
        self
    }

    /// Whether an ego centred at `y` (m) has its box across a line of its own lane (the lane
    /// spacing taken from the own and target centres).
    fn straddles_own_lane(&self, y: f64) -> bool {
        (y - self.y_own).abs() > (self.y_line - self.y_own).abs() - self.half_width
    }

    /// Turns on gap seeking ([`LaneChange::v_ref`]) for an ego `ego_length` long (m): a
    /// target-lane vehicle whose bumper gap to the ego along the road is below `gap_window`
    /// (m) blocks the change, and the reference speed moves `gap_speed` (m/s) past its speed
    /// (0: off).
    #[must_use]
    pub fn with_gap_seeking(mut self, gap_speed: f64, gap_window: f64, ego_length: f64) -> Self {
        self.gap_speed = gap_speed;
        self.gap_window = gap_window;
        self.ego_length = ego_length;
        self
    }

    /// Turns on the crawl reference ([`LaneChange::v_ref`]): an ego whose base reference speed
    /// falls below `crawl_fraction` (0: off) × the goal lane's flow ([`LaneChange::flow`])
    /// keeps up with that flow from then on.
    #[must_use]
    pub fn with_crawl_reference(mut self, crawl_fraction: f64) -> Self {
        self.crawl_fraction = crawl_fraction;
        self
    }

    /// The flow of the goal lane ([`LaneChange::goal`]) around an ego at x = `ego_x` (m): the
    /// median speed along the road (m/s) of the `others` whose centres lie within half the
    /// lane spacing of the goal lane's centre and within [`FLOW_RANGE_M`] of `ego_x` along the
    /// road; `None` when there are none.
    #[must_use]
    pub fn flow(&self, ego_x: f64, others: &[Neighbour]) -> Option<f64> {
        let half_spacing = (self.y_target - self.y_line).abs();
        let goal = self.goal();
        let speeds: Vec<f64> = others
            .iter()
            .filter(|o| (o.y - goal).abs() < half_spacing && (o.x - ego_x).abs() <= FLOW_RANGE_M)
            .map(|o| o.v)
            .collect();
        median(&speeds)
    }

    /// The reference speed of the next planning step (m/s) for an ego at `ego` = (x, y, ψ, v)
    /// (road frame, m, rad, m/s) among `others`, `base` being the run's own reference speed and
    /// `horizon_s` the planning horizon (s). Called once per planning step, before the plan.
    ///
    /// With the crawl reference on ([`LaneChange::with_crawl_reference`]) the goal lane's
    /// flow is [`LaneChange::flow`] now, or when no vehicle of that lane is within range, the
    /// last flow this lane change saw in that lane (the traffic that left the ego behind drove
    /// at that speed). The first step at which `base` is below `crawl_fraction` × that flow
    /// makes the ego *crawling* for the rest of the lane change, and a crawling ego's `base`
    /// is raised to the flow (unchanged while none has been seen in the goal lane). An ego
    /// that starts at a crawl, queued behind a slow vehicle, otherwise keeps that crawl as its
    /// reference after its path has cleared; one that starts at an ordinary speed below the
    /// flow keeps its own (raising every reference to the flow changed the validation runs
    /// of ordinary egos and cost success, `docs/results/crawl_reference.md`).
    ///
    /// With gap seeking on, while the goal is the target lane and the ego is not yet wholly
    /// inside it, the blocking vehicle is the target-lane vehicle (centre within half the lane
    /// spacing of the target lane's centre) nearest along the road among those whose bumper
    /// gap to the ego is below `gap_window`. When, at their current speeds, the ego would be
    /// ahead of it after `horizon_s`, the reference is `max(base, v + gap_speed)` (pass it),
    /// else `min(base, v − gap_speed)` but no lower than `base − gap_speed` nor 0 (let it pass
    /// without braking towards a standstill behind a slowing vehicle); `base` otherwise. The
    /// caller bounds the result by the planner's `v_max`.
    #[must_use]
    pub fn v_ref(&mut self, base: f64, ego: [f64; 4], others: &[Neighbour], horizon_s: f64) -> f64 {
        let base = self.crawl_reference(base, ego[0], others);

        if self.gap_speed <= 0.0 || self.hold > 0 || (ego[1] - self.y_target).abs() <= self.inside {
            return base;
        }
        let half_spacing = (self.y_target - self.y_line).abs();
        let blocking = others
            .iter()
            .filter(|o| (o.y - self.y_target).abs() < half_spacing)
            .filter(|o| (o.x - ego[0]).abs() - 0.5 * (self.ego_length + o.length) < self.gap_window)
            .min_by(|a, b| (a.x - ego[0]).abs().total_cmp(&(b.x - ego[0]).abs()));
        let Some(o) = blocking else {
            return base;
        };
        // The ego ahead of it after the horizon at the current speeds: pass it, else drop back.
        if ego[0] - o.x + (ego[3] - o.v) * horizon_s > 0.0 {
            base.max(o.v + self.gap_speed)
        } else {
            base.min(o.v - self.gap_speed)
                .max(base - self.gap_speed)
                .max(0.0)
        }
    }

    /// The crawl reference of [`LaneChange::v_ref`]: `base` (m/s), or at least the goal lane's
    /// flow once the ego is crawling; the flow (of the vehicles `others` around `ego_x`, m) is
    /// looked up only with the crawl reference on.
    fn crawl_reference(&mut self, base: f64, ego_x: f64, others: &[Neighbour]) -> f64 {
        if self.crawl_fraction <= 0.0 {
            return base;
        }
        let slot = usize::from(self.hold > 0);
        if let Some(flow) = self.flow(ego_x, others) {
            self.seen_flow[slot] = Some(flow);
        }
        let Some(flow) = self.seen_flow[slot] else {
            return base;
        };
        self.crawling |= base < self.crawl_fraction * flow;
        if self.crawling { base.max(flow) } else { base }
    }

    /// Turns on the stalled-change abort: a step with less than `stall_progress` (m) of
    /// progress towards the target lane, the ego straddling the line before crossing it,
    /// counts towards `abort_after` like a step without an admissible plan (0: off).
    #[must_use]
    pub fn with_stall_abort(mut self, stall_progress: f64) -> Self {
        self.stall_progress = stall_progress;
        self
    }

    /// The lateral goal of the next planning step (m): the target lane's centre, or the own
    /// lane's centre while an abort holds.
    #[must_use]
    pub fn goal(&self) -> f64 {
        if self.hold > 0 {
            self.y_own
        } else {
            self.y_target
        }
    }

    /// The lane centre the planner may fall back to this step with the ego's centre at `y`
    /// (m, [`crate::PlanningProblem::y_retreat`]): the own lane's while the goal is the target
    /// lane and the centre has not crossed the line; once committed only while the ego is
    /// **stuck** across the line: not yet wholly inside the target lane after `abort_after`
    /// consecutive steps without an admissible plan (an ego straddling the line in front of a
    /// target-lane follower must be able to leave the straddle either way). None while an
    /// abort holds (the goal is the own lane then).
    #[must_use]
    pub fn retreat(&self, y: f64) -> Option<f64> {
        let stuck = self.abort_after > 0
            && self.stuck_steps >= self.abort_after
            && (y - self.y_target).abs() > self.inside;
        (self.hold == 0 && (!self.committed(y) || stuck)).then_some(self.y_own)
    }

    /// Whether the ego's centre at `y` (m) has crossed the line between the two lanes.
    #[must_use]
    pub fn committed(&self, y: f64) -> bool {
        (y - self.y_line) * (self.y_target - self.y_line) > 0.0
    }

    /// Aborts so far.
    #[must_use]
    pub fn aborts(&self) -> usize {
        self.aborts
    }

    /// Counts a planning step that ended in `status` with the ego's centre at `y` (m) when it
    /// was planned.
    pub fn after_plan(&mut self, status: StepStatus, y: f64) {
        let stalled = self.stalled(y);
        self.last_y = Some(y);
        let straddling = (y - self.y_target).abs() > self.inside && self.committed(y);
        if straddling && status.is_unsafe_plan() {
            self.stuck_steps += 1;
        } else {
            self.stuck_steps = 0;
        }
        if self.straddling_start && (!status.is_unsafe_plan() || !self.straddles_own_lane(y)) {
            self.straddling_start = false;
        }
        let abort_after = if self.straddling_start {
            self.start_abort_after
        } else {
            self.abort_after
        };
        if self.hold > 0 {
            self.hold -= 1;
        } else if abort_after > 0
            && (status.is_unsafe_plan() || stalled)
            && (y - self.y_target).abs() > self.inside
            && !self.committed(y)
        {
            self.unsafe_steps += 1;
            if self.unsafe_steps >= abort_after {
                self.hold = self.abort_hold;
                self.unsafe_steps = 0;
                self.aborts += 1;
                self.straddling_start = false;
            }
        } else {
            self.unsafe_steps = 0;
        }
    }

    /// Whether the step planned with the ego's centre at `y` (m) shows a stalled change: the
    /// stall abort is on, the ego's box straddles the line with its centre on its own side,
    /// and the centre moved less than `stall_progress` towards the target since the previous
    /// step.
    fn stalled(&self, y: f64) -> bool {
        let towards = (self.y_target - self.y_own).signum();
        self.stall_progress > 0.0
            && !self.committed(y)
            && (y - self.y_line).abs() < self.half_width
            && self
                .last_y
                .is_some_and(|p| (y - p) * towards < self.stall_progress)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Own lane at y = 0, target at 3.7 (line at 1.85), a 1.9 m wide ego, abort after 2 steps
    /// without an admissible plan, hold 3.
    fn change() -> LaneChange {
        LaneChange::new(0.0, 3.7, 1.9, 0.3, 2, 3)
    }

    #[test]
    fn aborts_before_the_line_and_retries_after_the_hold() {
        let mut c = change();
        assert_eq!((c.goal(), c.retreat(1.0)), (3.7, Some(0.0)));
        assert_eq!(
            c.retreat(1.9),
            None,
            "no retreat once the centre crossed the line"
        );
        c.after_plan(StepStatus::Fallback, 1.0);
        assert_eq!((c.goal(), c.aborts()), (3.7, 0));
        c.after_plan(StepStatus::Unsafe, 1.2);
        assert_eq!((c.goal(), c.aborts()), (0.0, 1), "aborted");
        assert_eq!(
            c.retreat(1.2),
            None,
            "no retreat while the goal is the own lane"
        );
        for _ in 0..3 {
            assert_eq!(c.goal(), 0.0);
            c.after_plan(StepStatus::Fallback, 0.5);
        }
        assert_eq!(c.goal(), 3.7, "retries after the hold");
        // An admissible plan resets the count.
        c.after_plan(StepStatus::Fallback, 0.5);
        c.after_plan(StepStatus::Converged, 0.6);
        c.after_plan(StepStatus::Fallback, 0.7);
        assert_eq!((c.goal(), c.aborts()), (3.7, 1));
    }

    #[test]
    fn never_aborts_once_the_centre_crossed_the_line() {
        let mut c = change();
        assert!(!c.committed(1.84) && c.committed(1.86));
        for _ in 0..10 {
            c.after_plan(StepStatus::Fallback, 2.0);
        }
        assert_eq!((c.goal(), c.aborts()), (3.7, 0));
        // A change to the right: the line is crossed going down.
        let mut right = LaneChange::new(3.7, 0.0, 1.9, 0.3, 1, 1);
        assert!(right.committed(1.0) && !right.committed(2.5));
        right.after_plan(StepStatus::Unsafe, 2.5);
        assert_eq!(right.aborts(), 1);
    }

    #[test]
    fn offers_the_retreat_after_the_crossing_only_when_stuck_across_the_line() {
        let mut c = change();
        // Crossed (line at 1.85), not inside (inside: |y − 3.7| ≤ 0.9).
        assert_eq!(c.retreat(2.0), None, "committed and not yet stuck");
        c.after_plan(StepStatus::Unsafe, 2.0);
        assert_eq!(c.retreat(2.0), None, "one step without a plan is not stuck");
        c.after_plan(StepStatus::Fallback, 2.0);
        assert_eq!(
            c.retreat(2.0),
            Some(0.0),
            "stuck after abort_after = 2 steps"
        );
        assert_eq!(
            c.retreat(3.0),
            None,
            "never once wholly inside the target lane"
        );
        assert_eq!(
            (c.goal(), c.aborts()),
            (3.7, 0),
            "still committed: no abort"
        );
        c.after_plan(StepStatus::Converged, 2.1);
        assert_eq!(c.retreat(2.1), None, "an admissible plan ends being stuck");
        // Steps without a plan inside the target lane do not count.
        c.after_plan(StepStatus::Unsafe, 3.5);
        c.after_plan(StepStatus::Unsafe, 3.5);
        assert_eq!(c.retreat(2.1), None);
        // Disabled aborts disable it too.
        let mut off = LaneChange::new(0.0, 3.7, 1.9, 0.3, 0, 3);
        for _ in 0..5 {
            off.after_plan(StepStatus::Unsafe, 2.0);
        }
        assert_eq!(off.retreat(2.0), None);
    }

    /// An ego that edges over the line (its box across it, its centre on its own side) with
    /// admissible plans and stops there aborts after `abort_after` stalled steps; steady
    /// progress, an ego wholly in its own lane, and a zero `stall_progress` never abort.
    #[test]
    fn aborts_a_change_stalled_across_the_line() {
        // Line at 1.85, half width 0.95: the box straddles for 0.9 < y < 2.8.
        let stalled = || change().with_stall_abort(0.05);
        let mut c = stalled();
        for y in [0.2, 0.6, 1.0, 1.02] {
            c.after_plan(StepStatus::Converged, y);
        }
        assert_eq!((c.goal(), c.aborts()), (3.7, 0), "one stalled step");
        c.after_plan(StepStatus::Converged, 1.03);
        assert_eq!(
            (c.goal(), c.aborts()),
            (0.0, 1),
            "two stalled steps straddling"
        );
        // Moving back counts as stalled; a stalled step and an unsafe one add up.
        let mut c = stalled();
        c.after_plan(StepStatus::Converged, 1.2);
        c.after_plan(StepStatus::Converged, 1.1);
        assert_eq!(c.aborts(), 0);
        c.after_plan(StepStatus::Unsafe, 1.5);
        assert_eq!(c.aborts(), 1);
        // Steady progress of 0.1 m per step across the straddle: no abort.
        let mut c = stalled();
        for k in 0..10 {
            c.after_plan(StepStatus::Converged, 0.9 + 0.1 * f64::from(k));
        }
        assert_eq!(c.aborts(), 0);
        // Waiting in the own lane (box not across the line) is not stalling.
        let mut c = stalled();
        for _ in 0..6 {
            c.after_plan(StepStatus::Converged, 0.5);
        }
        assert_eq!(c.aborts(), 0);
        // After the crossing, and with the rule off, no stalled-change abort.
        let mut c = stalled();
        for _ in 0..6 {
            c.after_plan(StepStatus::Converged, 2.0);
        }
        let mut off = change();
        for _ in 0..6 {
            off.after_plan(StepStatus::Converged, 1.2);
        }
        assert_eq!((c.aborts(), off.aborts()), (0, 0));
        // A change to the right stalls the same way (line at 1.85 going down).
        let mut right = LaneChange::new(3.7, 0.0, 1.9, 0.3, 2, 3).with_stall_abort(0.05);
        for y in [2.6, 2.6, 2.62] {
            right.after_plan(StepStatus::Converged, y);
        }
        assert_eq!(right.aborts(), 1);
    }

    /// A target-lane vehicle alongside moves the reference speed past it: faster when the ego
    /// will be ahead of it after the horizon, slower (by at most `gap_speed` below the base)
    /// when it will be ahead of the ego; nothing changes without a blocking vehicle, once the
    /// ego is inside the target lane, during an abort's hold, or with the rule off.
    #[test]
    fn gap_seeking_moves_the_reference_speed_past_a_blocking_vehicle() {
        // Own lane y = 0, target 3.7 (half spacing 1.85); a 4.5 m ego at x = 0, v = 20.
        let seeking = || change().with_gap_seeking(2.0, 6.0, 4.5);
        let ego = [0.0, 0.5, 0.0, 20.0];
        let car = |x: f64, y: f64, v: f64| Neighbour {
            x,
            y,
            v,
            length: 4.5,
        };
        let mut c = seeking();
        // Level, 2 m behind and slower: the ego will be ahead, so it passes at 19 + 2.
        assert_eq!(c.v_ref(20.0, ego, &[car(-2.0, 3.7, 19.0)], 1.8), 21.0);
        // 3 m ahead at the same speed: the ego drops back to 20 − 2.
        assert_eq!(c.v_ref(20.0, ego, &[car(3.0, 3.8, 20.0)], 1.8), 18.0);
        // 8 m ahead at 19 (bumper gap 3.5 m): 19 − 2 = 17, but never below base − gap_speed.
        assert_eq!(c.v_ref(20.0, ego, &[car(8.0, 3.8, 19.0)], 1.8), 18.0);
        // 3 m ahead at 12: the ego will be ahead of it after 1.8 s, so the base stays.
        assert_eq!(c.v_ref(20.0, ego, &[car(3.0, 3.8, 12.0)], 1.8), 20.0);
        // Ahead but fast enough to clear: the base stays.
        assert_eq!(c.v_ref(20.0, ego, &[car(3.0, 3.8, 25.0)], 1.8), 20.0);
        // The nearest blocking vehicle decides (the one 1 m behind, not the one 9 m ahead).
        let two = [car(9.0, 3.7, 20.0), car(-1.0, 3.7, 19.5)];
        assert_eq!(c.v_ref(20.0, ego, &two, 1.8), 21.5);
        // Not blocking: bumper gap 12 − 4.5 = 7.5 m ≥ 6 m; in the own lane; in a far lane.
        for o in [
            car(12.0, 3.7, 20.0),
            car(1.0, 0.2, 20.0),
            car(1.0, 7.4, 20.0),
        ] {
            assert_eq!(c.v_ref(20.0, ego, &[o], 1.8), 20.0, "{o:?}");
        }
        // Inside the target lane (|y − 3.7| ≤ 0.9): the base.
        let inside = [0.0, 3.0, 0.0, 20.0];
        assert_eq!(c.v_ref(20.0, inside, &[car(3.0, 3.8, 20.0)], 1.8), 20.0);
        // The rule off: the base.
        assert_eq!(change().v_ref(20.0, ego, &[car(3.0, 3.8, 20.0)], 1.8), 20.0);
        // While an abort holds the own lane: the base.
        let mut held = seeking();
        held.after_plan(StepStatus::Unsafe, 0.5);
        held.after_plan(StepStatus::Unsafe, 0.5);
        assert_eq!(held.goal(), 0.0);
        assert_eq!(held.v_ref(20.0, ego, &[car(3.0, 3.8, 20.0)], 1.8), 20.0);
        // A change to the right sees the target lane below.
        let mut right = LaneChange::new(3.7, 0.0, 1.9, 0.3, 2, 3).with_gap_seeking(2.0, 6.0, 4.5);
        let ego_r = [0.0, 3.2, 0.0, 20.0];
        assert_eq!(right.v_ref(20.0, ego_r, &[car(-2.0, 0.1, 19.0)], 1.8), 21.0);
    }

    /// The crawl reference: the goal lane's flow is the median speed of its vehicles within
    /// 50 m along the road (centres within half a lane spacing of the goal's centre), or the
    /// last one seen; a base below `crawl_fraction` × that flow makes the ego crawling, which
    /// raises its reference to the flow for the rest of the lane change; a base at or above
    /// the fraction never moves; an abort's hold uses the own lane's flow; off, the base.
    #[test]
    fn a_crawling_ego_keeps_up_with_the_goal_lanes_flow() {
        let car = |x: f64, y: f64, v: f64| Neighbour {
            x,
            y,
            v,
            length: 4.5,
        };
        let ego = [0.0, 0.2, 0.0, 1.5];
        // Target lane (3.7): 8, 10, 12 m/s within range (median 10), one at 30 m/s 60 m away
        // and one in the own lane at 2 m/s, neither of which counts.
        let traffic = [
            car(-30.0, 3.6, 8.0),
            car(20.0, 3.9, 12.0),
            car(45.0, 3.0, 10.0),
            car(60.0, 3.7, 30.0),
            car(9.0, 0.1, 2.0),
        ];
        let far = &traffic[3..];
        let crawl = || change().with_crawl_reference(0.5);
        // Nothing seen in the target lane yet: the base.
        let mut c = crawl();
        assert_eq!(c.flow(0.0, far), None);
        assert_eq!(c.v_ref(1.5, ego, far, 1.8), 1.5);
        // 1.5 < 0.5 × 10: crawling, the reference is the flow.
        assert_eq!(c.flow(0.0, &traffic), Some(10.0));
        assert_eq!(c.v_ref(1.5, ego, &traffic, 1.8), 10.0);
        // The lane's vehicles gone out of range: the last flow seen.
        assert_eq!(c.v_ref(1.5, ego, far, 1.8), 10.0);
        // Crawling stays once begun: a slower flow later (2.5 m/s, no longer twice the base)
        // is still kept up with, and never lowers the base.
        let slower = [car(5.0, 3.7, 2.5)];
        assert_eq!(c.v_ref(1.5, ego, &slower, 1.8), 2.5);
        assert_eq!(c.v_ref(3.0, ego, &slower, 1.8), 3.0);
        // A base at half the flow or more is an ordinary speed: never moved.
        let mut ordinary = crawl();
        assert_eq!(ordinary.v_ref(5.0, ego, &traffic, 1.8), 5.0);
        assert_eq!(ordinary.v_ref(6.0, ego, &traffic, 1.8), 6.0);
        // Off: the base.
        assert_eq!(change().v_ref(1.5, ego, &traffic, 1.8), 1.5);
        // While an abort holds the own lane, its flow counts (the 2 m/s car), not the target
        // lane's remembered one.
        let mut held = crawl();
        assert_eq!(held.v_ref(0.5, ego, &traffic, 1.8), 10.0);
        held.after_plan(StepStatus::Unsafe, 0.2);
        held.after_plan(StepStatus::Unsafe, 0.2);
        assert_eq!(held.goal(), 0.0);
        assert_eq!(held.flow(0.0, &traffic), Some(2.0));
        assert_eq!(held.v_ref(0.5, ego, &traffic, 1.8), 2.0);
        assert_eq!(held.v_ref(0.5, ego, far, 1.8), 2.0);
        // With gap seeking too, the crawl reference is the base the gap seeking starts from:
        // the car level with the ego at 10 m/s in the target lane blocks and the ego, ahead
        // of it after the horizon, passes at 10 + 2.
        let mut both = crawl().with_gap_seeking(2.0, 6.0, 4.5);
        let ego_fast = [0.0, 0.5, 0.0, 11.0];
        let beside = [car(-1.0, 3.7, 10.0), car(20.0, 3.7, 10.0)];
        assert_eq!(both.v_ref(1.5, ego_fast, &beside, 1.8), 12.0);
    }

    /// An ego whose box starts across the line (centre 1.2 m from its own lane's centre,
    /// half width 0.95, line at 1.85) aborts on its first step without an admissible plan
    /// with `start_abort_after` = 1; without it only after `abort_after` = 2; one start abort
    /// per run, and none for an ego that starts inside its lane or once a plan was admissible.
    #[test]
    fn aborts_at_once_from_a_straddling_start() {
        let mut c = change().with_start_abort(1, 1.2);
        c.after_plan(StepStatus::Unsafe, 1.2);
        assert_eq!((c.goal(), c.aborts()), (0.0, 1), "aborted at once");
        let mut plain = change();
        plain.after_plan(StepStatus::Unsafe, 1.2);
        assert_eq!(
            (plain.goal(), plain.aborts()),
            (3.7, 0),
            "abort_after = 2 steps"
        );
        // After the hold, the plain abort_after applies again.
        for _ in 0..3 {
            c.after_plan(StepStatus::Unsafe, 1.0);
        }
        assert_eq!(c.goal(), 3.7);
        c.after_plan(StepStatus::Unsafe, 1.0);
        assert_eq!((c.goal(), c.aborts()), (3.7, 1), "one start abort per run");
        // Starting inside the own lane (|0.5| ≤ 1.85 − 0.95): no start abort.
        let mut inside = change().with_start_abort(1, 0.5);
        inside.after_plan(StepStatus::Unsafe, 0.5);
        assert_eq!(inside.aborts(), 0);
        // An admissible plan first ends the straddling start.
        let mut ok = change().with_start_abort(1, 1.2);
        ok.after_plan(StepStatus::Converged, 1.2);
        ok.after_plan(StepStatus::Unsafe, 1.2);
        assert_eq!(ok.aborts(), 0);
        // Across the other line of the own lane (y = −1.2): it straddles too.
        let mut other = change().with_start_abort(1, -1.2);
        other.after_plan(StepStatus::Fallback, -1.2);
        assert_eq!(other.aborts(), 1);
    }

    #[test]
    fn no_aborts_inside_the_target_lane_or_when_disabled() {
        let mut c = change();
        for _ in 0..5 {
            c.after_plan(StepStatus::Fallback, 3.5);
        }
        assert_eq!(c.aborts(), 0);
        let mut off = LaneChange::new(0.0, 3.7, 1.9, 0.3, 0, 3);
        for _ in 0..5 {
            off.after_plan(StepStatus::Fallback, 0.5);
        }
        assert_eq!(off.aborts(), 0);
    }
}
