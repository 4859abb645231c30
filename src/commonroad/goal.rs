//! A planning problem's goal region: what the file says ([`GoalState`]: position shapes or
//! lanelets, a time-step interval, velocity and orientation intervals), the test CommonRoad's
//! checker applies to a solution state ([`GoalState::reached_by`], as
//! `commonroad.planning.goal.GoalRegion.is_reached`), the goal in nudge's road frame
//! ([`RoadGoal`]: the target lane the goal covers, its x range and the time window), and the
//! policy that drives nudge's planner towards it ([`GoalPolicy`]).
//!
//! nudge plans lane changes: the goal's lane becomes the run's target (instead of the lane the
//! simulator draws from the seed) and the reference speed is scheduled so that the ego
//! arrives at the goal's x in the middle of its time window, within its velocity interval.

use nudge_planner::{Plan, Planner, PlannerError, PlannerSettings, PlanningProblem};
use nudge_predictor::{DT, Predictor};
use nudge_sim::Policy;

use super::error::CommonRoadError;
use super::scene::CommonRoadScene;
use super::xml::RawLanelet;

/// A closed interval `[lo, hi]` of a goal (m/s, rad or time steps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// Lower end.
    pub lo: f64,
    /// Upper end (≥ `lo`).
    pub hi: f64,
}

impl Interval {
    /// Whether `v` lies in `[lo, hi]`.
    #[must_use]
    pub fn contains(self, v: f64) -> bool {
        self.lo <= v && v <= self.hi
    }

    /// Whether the angle `a` (rad) lies in the interval modulo 2π.
    #[must_use]
    pub fn contains_angle(self, a: f64) -> bool {
        use std::f64::consts::TAU;
        if self.hi - self.lo >= TAU {
            return true;
        }
        let shifted = self.lo + (a - self.lo).rem_euclid(TAU);
        shifted <= self.hi
    }

    /// The middle of the interval.
    #[must_use]
    pub fn mid(self) -> f64 {
        0.5 * (self.lo + self.hi)
    }
}

/// One shape of a goal's position (file frame, m, rad).
#[derive(Debug, Clone, PartialEq)]
pub enum GoalShape {
    /// A rectangle: length along `orientation`, width across it, centred at `center`.
    Rectangle {
        /// Length (m).
        length: f64,
        /// Width (m).
        width: f64,
        /// Orientation of the length axis (rad).
        orientation: f64,
        /// Centre (m).
        center: [f64; 2],
    },
    /// A circle of `radius` (m) around `center` (m).
    Circle {
        /// Radius (m).
        radius: f64,
        /// Centre (m).
        center: [f64; 2],
    },
    /// A polygon (vertices `[P, 2]`, m, P ≥ 3).
    Polygon(Vec<[f64; 2]>),
    /// The polygon of a lanelet of the file (left bound then the right bound reversed, m).
    Lanelet {
        /// The lanelet's id.
        id: String,
        /// Its outline (m).
        outline: Vec<[f64; 2]>,
    },
}

impl GoalShape {
    /// The lanelet `id` of `lanelets` as a goal shape.
    pub(crate) fn lanelet(id: &str, lanelets: &[RawLanelet]) -> Option<Self> {
        let ll = lanelets.iter().find(|l| l.id == id)?;
        let mut outline = ll.left.clone();
        outline.extend(ll.right.iter().rev());
        Some(Self::Lanelet {
            id: id.to_string(),
            outline,
        })
    }

    /// Whether the shape contains point `p` (m; boundary included).
    #[must_use]
    pub fn contains(&self, p: [f64; 2]) -> bool {
        match self {
            Self::Rectangle {
                length,
                width,
                orientation,
                center,
            } => {
                let (s, c) = orientation.sin_cos();
                let d = [p[0] - center[0], p[1] - center[1]];
                let u = c * d[0] + s * d[1];
                let v = -s * d[0] + c * d[1];
                u.abs() <= 0.5 * length && v.abs() <= 0.5 * width
            }
            Self::Circle { radius, center } => {
                (p[0] - center[0]).hypot(p[1] - center[1]) <= *radius
            }
            Self::Polygon(v) | Self::Lanelet { outline: v, .. } => point_in_polygon(p, v),
        }
    }

    /// Points that outline the shape (m): a rectangle's corners and centre, a circle's centre
    /// and four extreme points, a polygon's vertices.
    #[must_use]
    pub fn outline(&self) -> Vec<[f64; 2]> {
        match self {
            Self::Rectangle {
                length,
                width,
                orientation,
                center,
            } => {
                let (s, c) = orientation.sin_cos();
                let mut pts = vec![*center];
                for (a, b) in [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0)] {
                    let (u, v) = (a * 0.5 * length, b * 0.5 * width);
                    pts.push([center[0] + c * u - s * v, center[1] + s * u + c * v]);
                }
                pts
            }
            Self::Circle { radius, center } => {
                let r = *radius;
                vec![
                    *center,
                    [center[0] + r, center[1]],
                    [center[0] - r, center[1]],
                    [center[0], center[1] + r],
                    [center[0], center[1] - r],
                ]
            }
            Self::Polygon(v) | Self::Lanelet { outline: v, .. } => v.clone(),
        }
    }
}

/// Even-odd ray casting; points on an edge count as inside.
fn point_in_polygon(p: [f64; 2], v: &[[f64; 2]]) -> bool {
    let n = v.len();
    let mut inside = false;
    for i in 0..n {
        let (a, b) = (v[i], v[(i + 1) % n]);
        let cross = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
        let within = p[0] >= a[0].min(b[0]) - 1e-12
            && p[0] <= a[0].max(b[0]) + 1e-12
            && p[1] >= a[1].min(b[1]) - 1e-12
            && p[1] <= a[1].max(b[1]) + 1e-12;
        if cross.abs() < 1e-12 && within {
            return true;
        }
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) * (b[0] - a[0]) / (b[1] - a[1]);
            if p[0] < x {
                inside = !inside;
            }
        }
    }
    inside
}

/// One goal state of a planning problem (file frame). A state reaches it when its time step
/// lies in `time`, its position in any of `shapes` (none: anywhere), its velocity in
/// `velocity` and its orientation in `orientation` (when given).
#[derive(Debug, Clone, PartialEq)]
pub struct GoalState {
    /// 1-based line of `<goalState>`.
    pub line: usize,
    /// Time steps (file steps, inclusive).
    pub time: Interval,
    /// Position shapes (their union); empty: any position.
    pub shapes: Vec<GoalShape>,
    /// Velocity interval (m/s).
    pub velocity: Option<Interval>,
    /// Orientation interval (rad, modulo 2π).
    pub orientation: Option<Interval>,
}

impl GoalState {
    /// Whether a state at time step `step`, centre `pos` (m), `velocity` (m/s) and
    /// `orientation` (rad) reaches this goal, as CommonRoad's checker decides.
    #[must_use]
    pub fn reached_by(&self, step: i64, pos: [f64; 2], velocity: f64, orientation: f64) -> bool {
        #[allow(clippy::cast_precision_loss)]
        let t = step as f64;
        self.time.contains(t)
            && (self.shapes.is_empty() || self.shapes.iter().any(|s| s.contains(pos)))
            && self.velocity.is_none_or(|v| v.contains(velocity))
            && self
                .orientation
                .is_none_or(|o| o.contains_angle(orientation))
    }
}

/// A goal in nudge's road frame: the lane to reach, where and when.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoadGoal {
    /// The planning problem's id.
    pub problem: i64,
    /// Index (into the goal's [`GoalState`]s) of the goal planned for.
    pub state: usize,
    /// Road x range (m) the goal's position covers.
    pub x: [f64; 2],
    /// Road y (m) the ego aims at: the centre of the goal's position, inside `lane`.
    pub y: f64,
    /// The lane (index into the lane boundaries at the goal's x, from the right) the goal
    /// covers.
    pub lane: usize,
    /// The time window (s of the file's clock).
    pub time_s: [f64; 2],
    /// The velocity interval (m/s), if the goal has one.
    pub velocity: Option<Interval>,
}

/// The last seconds before the middle of a goal's time window over which [`GoalPolicy`]
/// keeps its reference speed inside the goal's velocity interval (s).
pub const ARRIVAL_S: f64 = 2.0;

/// Most distance (m/s) inside the ends of a goal's velocity interval that [`GoalPolicy`]'s
/// reference speed keeps (the planner tracks its reference with a lag).
pub const VELOCITY_MARGIN: f64 = 1.0;

/// Most distance (m) inside the ends of a goal's x range that [`GoalPolicy`] aims at.
pub const GOAL_MARGIN: f64 = 5.0;

impl CommonRoadScene {
    fn goal_err(&self, problem: i64, reason: String) -> CommonRoadError {
        CommonRoadError::Goal {
            path: self.raw.path.clone(),
            problem,
            reason,
        }
    }

    /// The goal of planning problem `problem` in the road frame, for an ego whose last
    /// observed time is `t0_s` (s) at road point `ego` (m): the first of its goal states that
    /// nudge can plan to. A goal without a position keeps the ego's lane.
    ///
    /// # Errors
    /// [`CommonRoadError::Goal`] naming the problem and why none of its goal states can be
    /// planned to: no goal state, a time window that ends before t0, a position outside the
    /// road frame's range (beyond the map), beyond the lane map, behind the ego, or outside
    /// the lanes.
    pub fn road_goal(
        &self,
        problem: i64,
        t0_s: f64,
        ego: [f64; 2],
    ) -> Result<RoadGoal, CommonRoadError> {
        let pp = self
            .raw
            .planning_problems
            .iter()
            .find(|p| p.id == problem)
            .ok_or_else(|| self.goal_err(problem, "no planning problem with this id".into()))?;
        if pp.goals.is_empty() {
            return Err(self.goal_err(problem, "no <goalState>".into()));
        }
        let mut why = Vec::new();
        for (k, g) in pp.goals.iter().enumerate() {
            match self.goal_in_road(problem, k, g, t0_s, ego) {
                Ok(r) => return Ok(r),
                Err(w) => why.push(format!("goal state {} (line {}): {w}", k + 1, g.line)),
            }
        }
        Err(self.goal_err(problem, why.join("; ")))
    }

    fn goal_in_road(
        &self,
        problem: i64,
        state: usize,
        g: &GoalState,
        t0_s: f64,
        ego: [f64; 2],
    ) -> Result<RoadGoal, String> {
        let x0 = ego[0];
        let dt = self.raw.dt;
        let time_s = [g.time.lo * dt, g.time.hi * dt];
        if time_s[1] <= t0_s {
            return Err(format!(
                "its time window {:.1}..{:.1} s ends before t0 {t0_s:.1} s",
                time_s[0], time_s[1]
            ));
        }
        if g.shapes.is_empty() {
            // Any position: the ego keeps its lane and meets the time, velocity and
            // orientation conditions.
            let bounds = self.lanes.bounds_at(ego[0]);
            let lane = bounds
                .windows(2)
                .position(|w| w[0] <= ego[1] && ego[1] <= w[1])
                .ok_or_else(|| {
                    format!(
                        "no goal position, and the ego (road y {:.2} m) is not inside a lane",
                        ego[1]
                    )
                })?;
            return Ok(RoadGoal {
                problem,
                state,
                x: [f64::NEG_INFINITY, f64::INFINITY],
                y: 0.5 * (bounds[lane] + bounds[lane + 1]),
                lane,
                time_s,
                velocity: g.velocity,
            });
        }
        let (lo, hi) = self.frame.road_range();
        let mut pts = Vec::new();
        for p in g.shapes.iter().flat_map(GoalShape::outline) {
            let r = self.frame.to_road(p);
            if !(r[0].is_finite() && r[1].is_finite() && r[0] > lo && r[0] < hi) {
                return Err(format!(
                    "its position ({:.1}, {:.1}) m lies beyond the map (outside the road frame's \
                     x range {lo:.1}..{hi:.1} m)",
                    p[0], p[1]
                ));
            }
            pts.push(r);
        }
        let x = pts.iter().fold([f64::INFINITY, f64::NEG_INFINITY], |a, r| {
            [a[0].min(r[0]), a[1].max(r[0])]
        });
        let (map_lo, map_hi) = (
            self.lanes.pieces[0].0,
            self.lanes.pieces[self.lanes.pieces.len() - 1].1,
        );
        if x[1] < map_lo || x[0] > map_hi {
            return Err(format!(
                "its position (road x {:.1}..{:.1} m) lies beyond the lane map (x {map_lo:.1}..{map_hi:.1} m)",
                x[0], x[1]
            ));
        }
        if x[1] <= x0 {
            return Err(format!(
                "its position (road x {:.1}..{:.1} m) lies behind the ego (x {x0:.1} m)",
                x[0], x[1]
            ));
        }
        #[allow(clippy::cast_precision_loss)]
        let centre = {
            let s = pts
                .iter()
                .fold([0.0, 0.0], |a, r| [a[0] + r[0], a[1] + r[1]]);
            [s[0] / pts.len() as f64, s[1] / pts.len() as f64]
        };
        let bounds = self.lanes.bounds_at(centre[0]);
        let lane = bounds
            .windows(2)
            .position(|w| w[0] <= centre[1] && centre[1] <= w[1]);
        let Some(lane) = lane else {
            return Err(format!(
                "its position (road y {:.2} m) lies outside the lanes at its x ({:.2}..{:.2} m)",
                centre[1],
                bounds[0],
                bounds[bounds.len() - 1]
            ));
        };
        Ok(RoadGoal {
            problem,
            state,
            x,
            y: centre[1],
            lane,
            time_s,
            velocity: g.velocity,
        })
    }
}

/// nudge's planner driven towards a [`RoadGoal`]: each step's problem gets the goal's y as
/// its target and a reference speed that brings the ego to the middle of the goal's x range
/// at the middle of its time window (within the goal's velocity interval when it has one,
/// and within [0, `v_max`]).
#[derive(Debug)]
pub struct GoalPolicy {
    settings: PlannerSettings,
    /// Built from `settings` at the first step (its error is that step's).
    planner: Option<Planner>,
    goal: RoadGoal,
    /// The last observed time (s, file clock) of the run's start.
    t0_s: f64,
    /// Closed-loop steps planned so far.
    steps: usize,
    v_max: f64,
}

impl GoalPolicy {
    /// The policy for `goal`, planning with nudge's planner under `settings` from the run's
    /// last observed time `t0_s` (s); reference speeds at most the settings' `v_max` (m/s).
    #[must_use]
    pub fn new(settings: PlannerSettings, goal: RoadGoal, t0_s: f64) -> Self {
        Self {
            v_max: settings.bounds.v_max,
            settings,
            planner: None,
            goal,
            t0_s,
            steps: 0,
        }
    }

    /// The reference speed (m/s) at time `t_s` (s) for an ego at road x `x` (m) moving at
    /// `v` (m/s): the speed that brings it at the middle of the goal's time window to where
    /// its present speed would, moved inside the goal's x range (at most [`GOAL_MARGIN`] or a
    /// quarter of the range inside its ends); its present speed once the middle is less than
    /// one step away or the ego is past that point; within [0, `v_max`], and within the goal's
    /// velocity interval (at most [`VELOCITY_MARGIN`] or a quarter of it inside its ends) over
    /// the last [`ARRIVAL_S`] (throughout for a goal without a position).
    #[must_use]
    pub fn v_ref(&self, t_s: f64, x: f64, v: f64) -> f64 {
        let g = &self.goal;
        let t_mid = 0.5 * (g.time_s[0] + g.time_s[1]);
        let left = t_mid - t_s;
        // Where the ego would be at the window's middle at its speed, moved into the goal's
        // x range (a margin inside its ends).
        let margin = (0.25 * (g.x[1] - g.x[0])).min(GOAL_MARGIN);
        let aim = (x + v * left.max(0.0)).clamp(g.x[0] + margin, g.x[1] - margin);
        let want = if left > DT && x < aim {
            (aim - x) / left
        } else {
            v
        };
        // The velocity interval binds over the last ARRIVAL_S before the window's middle (or
        // throughout for a goal anywhere): before, the ego may have to go slower or faster
        // than it allows to arrive in time.
        let binds = left <= ARRIVAL_S || !g.x[0].is_finite() || !g.x[1].is_finite();
        let (lo, hi) = g
            .velocity
            .filter(|_| binds)
            .map_or((0.0, self.v_max), |iv| {
                let m = (0.25 * (iv.hi - iv.lo)).min(VELOCITY_MARGIN);
                ((iv.lo + m).max(0.0), (iv.hi - m).min(self.v_max))
            });
        if lo <= hi {
            want.clamp(lo, hi)
        } else {
            want.clamp(0.0, self.v_max)
        }
    }
}

impl Policy for GoalPolicy {
    fn reset(&mut self) {
        if let Some(p) = &mut self.planner {
            p.reset();
        }
        self.steps = 0;
    }

    fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        #[allow(clippy::cast_precision_loss)]
        let t = self.t0_s + self.steps as f64 * DT;
        self.steps += 1;
        let e = problem.ego;
        let aimed = PlanningProblem {
            y_target: self.goal.y,
            v_ref: self.v_ref(t, e.x, e.v),
            ..*problem
        };
        let planner = match &mut self.planner {
            Some(p) => p,
            None => self.planner.insert(Planner::new(self.settings.clone())?),
        };
        planner.plan(&aimed, predictor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rectangle_contains_its_rotated_corners_only() {
        let r = GoalShape::Rectangle {
            length: 4.0,
            width: 2.0,
            orientation: std::f64::consts::FRAC_PI_2,
            center: [10.0, 5.0],
        };
        assert!(r.contains([10.0, 5.0]));
        assert!(r.contains([10.9, 6.9]));
        assert!(!r.contains([11.1, 5.0]));
        assert!(!r.contains([10.0, 7.1]));
        // Corners pulled 1 mm towards the centre are inside, pushed 1 mm out are not.
        for p in &r.outline()[1..] {
            let d = [p[0] - 10.0, p[1] - 5.0];
            let n = d[0].hypot(d[1]);
            let at = |k: f64| [10.0 + d[0] * (1.0 + k / n), 5.0 + d[1] * (1.0 + k / n)];
            assert!(r.contains(at(-1e-3)) && !r.contains(at(1e-3)), "{p:?}");
        }
    }

    #[test]
    fn polygon_and_angle_intervals() {
        let sq = GoalShape::Polygon(vec![[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]);
        assert!(sq.contains([1.0, 1.0]) && sq.contains([2.0, 1.0]));
        assert!(!sq.contains([2.1, 1.0]) && !sq.contains([-0.1, 1.0]));
        let iv = Interval { lo: 3.0, hi: 3.3 };
        assert!(iv.contains_angle(3.1) && iv.contains_angle(3.1 - std::f64::consts::TAU));
        assert!(!iv.contains_angle(0.0));
        let c = GoalShape::Circle {
            radius: 1.0,
            center: [0.0, 0.0],
        };
        assert!(c.contains([0.6, 0.6]) && !c.contains([0.8, 0.8]));
    }
}
