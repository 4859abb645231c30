//! The follower-gap rule (`PlannerSettings::follower_ttc`): a plan must not move the ego
//! sideways into the path of a vehicle behind it on the goal's side unless that vehicle keeps
//! a safe gap behind the ego *without reacting*.
//!
//! The safety constraint checks each vehicle where the predictor expects it, and the
//! predictors (learned from traffic in which drivers make room) expect a target-lane follower
//! to yield to an ego that cuts in. Recorded traffic never yields: on validation scenes in the
//! log-replay world the planner's at-fault collisions came from an ego entering the target
//! lane level with, or just ahead of, a follower that was as fast or faster (a bumper gap of
//! 1–2 m at 22 m/s), then stuck across the line while the follower drove into its side.
//!
//! * **Followers**: the checked vehicles whose last observed centre is behind the ego's
//!   (along the road) and lies on the goal's side of the ego (across the road), when the goal
//!   is at least [`MIN_GOAL_OFFSET`] away, except a vehicle whose box overlaps the ego's by
//!   more than half the ego's width across the road (it is in the ego's own lane). Each drives
//!   on along the road at its last observed speed (from its last two observed positions) and
//!   keeps its lateral position: the follower does not react (its observed lateral velocity
//!   is too noisy to extrapolate: a follower drifting inside its lane looks like one leaving
//!   it).
//! * **In its path**: at step k the ego is in a follower's path when the lateral clearance
//!   between their boxes (centre distance across the road less half the two widths, headings
//!   ignored) is below `follower_clearance`.
//! * **Its gap**: the bumper gap (centre distance along the road less half the two lengths)
//!   must be at least `follower_min_gap` + (v_f − v_ego)₊·`follower_ttc`, v_f the follower's
//!   speed along the road and v_ego the ego's planned speed at that step: a follower no
//!   faster than the ego only needs the minimum gap (it falls back), a faster one must be at
//!   least `follower_ttc` from reaching the ego at their current speeds.
//! * **The verdict**: a step with the ego in a follower's path and the gap short of that
//!   counts min(`follower_clearance`, c₀) − c_k (m) when positive, c₀ the clearance at the
//!   ego's measured state and c_k the planned one: the plan may hold or widen the lateral
//!   clearance it starts with (an ego already across the line may stay or go back), never
//!   narrow it. A plan with any such step is not admissible; among inadmissible plans the sum
//!   ranks like a bound excess (the least-violating fallback prefers leaving the follower's
//!   path).
//!
//! 0 disables the rule.

use nudge_predictor::T_OBS;

use crate::model::State;
use crate::settings::PlannerSettings;

use super::problem::PlanningProblem;

/// Smallest lateral distance (m) between the ego and the call's goal for which the rule
/// applies: closer, the goal is the ego's own lane and no side is entered.
pub(crate) const MIN_GOAL_OFFSET: f64 = 0.5;

/// One follower, in the call's frame (origin at the ego's measured position).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Follower {
    /// Last observed centre (m).
    at: [f64; 2],
    /// Speed along the road from its last two observed positions (m/s).
    speed: f64,
    /// (length, width) (m).
    size: [f64; 2],
    /// Lateral clearance between the boxes at the ego's measured state (m).
    start_clearance: f64,
}

/// The follower-gap rule of one call.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct FollowerGap {
    followers: Vec<Follower>,
    ego_size: [f64; 2],
    /// Time to collision a faster follower must keep (s).
    ttc: f64,
    /// Bumper gap every follower must keep (m).
    min_gap: f64,
    /// Lateral clearance below which the ego is in a follower's path (m).
    clearance: f64,
    /// Step length (s).
    dt: f64,
}

/// Lateral clearance (m) between two boxes of widths `w_a`, `w_b` whose centres are `dy` apart
/// across the road (negative when they overlap across the road).
fn lateral_clearance(dy: f64, w_a: f64, w_b: f64) -> f64 {
    dy.abs() - 0.5 * (w_a + w_b)
}

impl FollowerGap {
    /// The rule of `problem` under `settings`: `None` when it is off (`follower_ttc` = 0), the
    /// goal is within [`MIN_GOAL_OFFSET`] of the ego, or no checked vehicle (within
    /// `check_range`) is a follower on the goal's side.
    pub(crate) fn new(problem: &PlanningProblem<'_>, s: &PlannerSettings) -> Option<Self> {
        if s.follower_ttc <= 0.0 {
            return None;
        }
        let ego = [problem.ego.x, problem.ego.y];
        let side = problem.y_target - ego[1];
        if side.abs() < MIN_GOAL_OFFSET {
            return None;
        }
        let ego_size = problem.sizes[0];
        let h = problem.history;
        let followers: Vec<Follower> = (1..h.n_agents())
            .filter_map(|i| {
                let p = h.at(i, T_OBS - 1);
                let q = h.at(i, T_OBS - 2);
                let at = [p[0] - ego[0], p[1] - ego[1]];
                let near = at[0].hypot(at[1]) <= s.check_range;
                let start_clearance = lateral_clearance(at[1], ego_size[1], problem.sizes[i][1]);
                // A vehicle overlapping the ego by more than half its width across the road
                // is in the ego's own lane: the gap to it is not this rule's business.
                let beside = start_clearance > -0.5 * ego_size[1];
                (near && beside && at[0] < 0.0 && at[1] * side > 0.0).then(|| Follower {
                    at,
                    speed: (p[0] - q[0]) / s.dt,
                    size: problem.sizes[i],
                    start_clearance,
                })
            })
            .collect();
        (!followers.is_empty()).then_some(Self {
            followers,
            ego_size,
            ttc: s.follower_ttc,
            min_gap: s.follower_min_gap,
            clearance: s.follower_clearance,
            dt: s.dt,
        })
    }

    /// The bumper gap (m) a follower at speed `v_f` must keep behind an ego at speed `v_ego`
    /// (m/s).
    fn needed(&self, v_f: f64, v_ego: f64) -> f64 {
        self.min_gap + (v_f - v_ego).max(0.0) * self.ttc
    }

    /// The rule's violation of the roll-out `z` (`[T]` states z_1..z_T, call frame): Σ over
    /// followers and steps with the ego in the follower's path and the gap short of
    /// [`Self::needed`] of min(`clearance`, c₀) − c_k when positive (m); 0 when admissible.
    pub(crate) fn violation(&self, z: &[State]) -> f64 {
        let mut total = 0.0;
        for f in &self.followers {
            let allowed = self.clearance.min(f.start_clearance);
            for (k, zk) in z.iter().enumerate() {
                let fx = f.at[0] + f.speed * self.dt * (k + 1) as f64;
                let fy = f.at[1];
                if fx >= zk[0] {
                    continue;
                }
                let c = lateral_clearance(zk[1] - fy, self.ego_size[1], f.size[1]);
                if c >= allowed {
                    continue;
                }
                let bumper = zk[0] - fx - 0.5 * (self.ego_size[0] + f.size[0]);
                if bumper < self.needed(f.speed, zk[3]) {
                    total += allowed - c;
                }
            }
        }
        total
    }
}
