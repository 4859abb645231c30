//! The per-call set-up shared by [`crate::Planner::plan`] and
//! [`crate::Planner::reference_qp`]: the ego-centred frame, the nominal trajectory (the
//! shifted previous plan, or constant velocity on a cold start), the linearised dynamics
//! around it, the input and state bounds, and the cost J = Φ1 + Φ2 + Φ3.

use crate::extents::{LaneTable, StopRule, deadline_factor};
use crate::model::{Bicycle, Linearisation, State};
use crate::qp::{RateBox, repair_box_rate};
use crate::settings::PlannerSettings;

use super::problem::PlanningProblem;

/// What one call leaves for the next: its inputs, shifted by one step when used (the duals
/// start from 0 in every call).
#[derive(Debug, Clone)]
pub(crate) struct WarmStart {
    /// Steering `[T]` (rad).
    pub delta: Vec<f64>,
    /// Acceleration `[T]` (m/s²).
    pub accel: Vec<f64>,
}

/// `v` shifted by one step, its last entry repeated.
fn shifted<T: Copy>(v: &[T], empty: T) -> Vec<T> {
    let mut s: Vec<T> = v.iter().skip(1).copied().collect();
    s.push(*v.last().unwrap_or(&empty));
    s
}

/// The lane centre a lane change may fall back to ([`PlanningProblem::y_retreat`]) and the
/// state bounds of a plan aiming at it: those of the call with the corridor running from the
/// start to this centre instead of the target.
pub(crate) struct Retreat {
    /// Its lateral position in the call's frame (m).
    pub y: f64,
    /// Lower state bounds per step `[T]`.
    pub lower: Vec<State>,
    /// Upper state bounds per step `[T]`.
    pub upper: Vec<State>,
}

/// The stopping line of a lane that really ends ahead of the ego's start
/// ([`crate::extents::Lanes::stop_line`]), in the call's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StopLine {
    /// x of the line: the lane's end less `stop_margin` (m).
    pub x: f64,
    /// The centre of the lane the ego starts in (m).
    pub y_own: f64,
}

/// One MPC call's linearised problem, in a frame centred on the ego's position (x and y of
/// every state here are relative to [`LinearisedProblem::origin`]).
pub(crate) struct LinearisedProblem {
    /// Horizon T (steps).
    pub horizon: usize,
    /// The ego's measured position (x, y) in the road frame (m): the frame's origin.
    pub origin: [f64; 2],
    /// The measured state z_0 in this frame (x = y = 0).
    pub start: State,
    /// F(Δ, α, Z) = AΔ + Bα + CZ + D around the nominal trajectory.
    pub linearisation: Linearisation,
    /// Nominal steering `[T]` (rad): the shifted previous plan, within its bounds.
    pub nominal_delta: Vec<f64>,
    /// Nominal acceleration `[T]` (m/s²).
    pub nominal_accel: Vec<f64>,
    /// The roll-out of the nominal inputs, z_1..z_T.
    pub nominal_rollout: Vec<State>,
    /// Duals μ to start from `[T]` (the shifted previous ones, or zeros).
    pub warm_duals: Vec<State>,
    /// Per-step weights (0, w_y, w_ψ, w_v) on (x, y, ψ, v); w_y includes the deadline term
    /// of a merge out of a lane that ends ([`lateral_weight`]).
    pub weights: State,
    /// Reference state (x ignored): (0, y_target, 0, v_ref) in this frame.
    pub reference: State,
    /// The lane centre the ego may fall back to when the problem has one, with the state
    /// bounds of a plan that aims at it.
    pub retreat: Option<Retreat>,
    /// Lower state bounds per step `[T]` (x unbounded; y from the road and the lateral
    /// corridor, ψ from the heading bound, v ≥ 0).
    pub lower: Vec<State>,
    /// Upper state bounds per step `[T]`.
    pub upper: Vec<State>,
    /// The road the ego's box must stay on (every corner): (right, left) edges relative to the
    /// origin (m), each widened by the ego's overhang at the start plus [`START_OVERHANG_SLACK`]
    /// when it starts over that edge (real data puts a few egos up to 0.33 m over it);
    /// unbounded, like the heading, when `heading_max` ≥ π/2 (then only the centre band of
    /// [`state_bounds`] keeps the ego on the road).
    pub edges: [f64; 2],
    /// The ego's (length, width) (m).
    pub ego_size: [f64; 2],
    /// The problem's lane layout ([`PlanningProblem::lanes`]): states in a lane outside its
    /// extent, or breaking the stopping rule of a lane that ends, count as outside the
    /// bounds.
    pub lanes: Option<LaneTable>,
    /// The stopping rule (`stop_decel`, `stop_margin` and the steering bounds that credit
    /// sideways progress), `None` when the rule does not bind this call ([`stop_rule`]).
    pub stop_rule: Option<StopRule>,
    /// Where the ego must stop when its lane really ends ahead of its start: the stopping
    /// line's x and the own lane's centre y, in this frame (m); `None` otherwise.
    pub stop_line: Option<StopLine>,
    /// Box and rate bounds of the steering.
    pub delta_box: RateBox,
    /// Box and rate bounds of the acceleration.
    pub accel_box: RateBox,
}

impl LinearisedProblem {
    /// Sets up one call of `problem` (already checked) from the warm start `warm`.
    pub(crate) fn new(
        s: &PlannerSettings,
        model: &Bicycle,
        warm: Option<&WarmStart>,
        p: &PlanningProblem<'_>,
    ) -> Self {
        let t = s.model.horizon;
        let origin = [p.ego.x, p.ego.y];
        let start = State::new(0.0, 0.0, p.ego.psi, p.ego.v);
        let delta_box = RateBox {
            lo: -s.bounds.delta_max,
            hi: s.bounds.delta_max,
            rate: s.bounds.ddelta_max,
            prev: p.last_delta.clamp(-s.bounds.delta_max, s.bounds.delta_max),
        };
        let accel_box = RateBox {
            lo: s.bounds.a_min,
            hi: s.bounds.a_max,
            rate: s.bounds.da_max,
            prev: p.last_accel.clamp(s.bounds.a_min, s.bounds.a_max),
        };
        let (mut nominal_delta, mut nominal_accel, warm_duals) = match warm {
            Some(w) if w.delta.len() == t => (
                shifted(&w.delta, 0.0),
                shifted(&w.accel, 0.0),
                vec![State::zeros(); t],
            ),
            _ => (vec![0.0; t], vec![0.0; t], vec![State::zeros(); t]),
        };
        repair_box_rate(&mut nominal_delta, delta_box);
        repair_box_rate(&mut nominal_accel, accel_box);
        let mut nominal_rollout = vec![State::zeros(); t];
        model.rollout(&start, &nominal_delta, &nominal_accel, &mut nominal_rollout);
        let mut nominal = Vec::with_capacity(t);
        nominal.push(start);
        nominal.extend_from_slice(&nominal_rollout[..t - 1]);
        let linearisation = Linearisation::new(
            model,
            &start,
            &nominal,
            &nominal_delta,
            &nominal_accel,
            s.admm.v_lin_min,
        );
        let y_goal = held_goal(s, p);
        let (lower, upper) = state_bounds(s, p, origin[1], y_goal);
        Self {
            horizon: t,
            origin,
            start,
            linearisation,
            nominal_delta,
            nominal_accel,
            nominal_rollout,
            warm_duals,
            weights: State::new(0.0, lateral_weight(s, p), s.cost.w_psi, s.cost.w_v),
            reference: State::new(0.0, y_goal - origin[1], 0.0, p.v_ref),
            retreat: p.y_retreat.map(|y| {
                let (lower, upper) = state_bounds(s, p, origin[1], y);
                Retreat {
                    y: y - origin[1],
                    lower,
                    upper,
                }
            }),
            lower,
            upper,
            edges: if s.bounds.heading_max < std::f64::consts::FRAC_PI_2 {
                road_edges(p, origin[1])
            } else {
                [f64::NEG_INFINITY, f64::INFINITY]
            },
            ego_size: p.sizes[0],
            lanes: p.lanes.as_ref().map(LaneTable::new),
            stop_rule: stop_rule(s, p),
            stop_line: stop_line(s, p),
            delta_box,
            accel_box,
        }
    }

    /// Φ3(Z) = Σ_k w_y e_y² + w_ψ e_ψ² + w_v e_v², e = z_k − reference.
    pub(crate) fn tracking_cost(&self, z: &[State]) -> f64 {
        let w = &self.weights;
        z.iter()
            .map(|zk| {
                let e = zk - self.reference;
                w[1] * e[1] * e[1] + w[2] * e[2] * e[2] + w[3] * e[3] * e[3]
            })
            .sum()
    }

    /// J = Φ1(Δ) + Φ2(α) + Φ3(Z).
    pub(crate) fn cost(
        &self,
        s: &PlannerSettings,
        delta: &[f64],
        accel: &[f64],
        z: &[State],
    ) -> f64 {
        input_cost(delta, self.delta_box.prev, s.cost.w_delta, s.cost.w_ddelta)
            + input_cost(accel, self.accel_box.prev, s.cost.w_a, s.cost.w_da)
            + self.tracking_cost(z)
    }

    /// States in this frame → (x, y, ψ, v) in the road frame.
    pub(crate) fn to_world(&self, z: &[State]) -> Vec<[f64; 4]> {
        z.iter()
            .map(|s| [s[0] + self.origin[0], s[1] + self.origin[1], s[2], s[3]])
            .collect()
    }

    /// `z` (the state of step `k`, 0-based) clamped into that step's bounds.
    pub(crate) fn clamp(&self, k: usize, z: &State) -> State {
        z.sup(&self.lower[k]).inf(&self.upper[k])
    }

    /// How far the states `z` (`[T]`) lie outside their bounds: Σ over steps of the excess of
    /// y, ψ and v over their bounds (m, rad, m/s), of the box's corners over the road's
    /// [`LinearisedProblem::edges`] (m) and of the centre outside its lane's extent
    /// ([`crate::Lanes::excess`], m); 0 when every state is within them.
    pub(crate) fn bound_excess(&self, z: &[State]) -> f64 {
        self.bound_excess_within(&self.lower, &self.upper, z)
    }

    /// [`Self::bound_excess`] against the state bounds `lower`, `upper` (`[T]`) instead of
    /// the call's (the road's edges stay the same).
    pub(crate) fn bound_excess_within(&self, lower: &[State], upper: &[State], z: &[State]) -> f64 {
        z.iter()
            .enumerate()
            .map(|(k, zk)| {
                let bounds: f64 = (1..4)
                    .map(|j| (lower[k][j] - zk[j]).max(0.0) + (zk[j] - upper[k][j]).max(0.0))
                    .sum();
                let road = bounds + self.edge_excess_at(zk);
                match &self.lanes {
                    Some(lanes) => {
                        let (x, y) = (zk[0] + self.origin[0], zk[1] + self.origin[1]);
                        road + lanes.view().excess(x, y)
                    }
                    None => road,
                }
            })
            .sum::<f64>()
            + self.stop_excess(z)
    }

    /// How far the corners of the ego's box at `zk` (this frame) lie beyond the road's
    /// [`LinearisedProblem::edges`] (m, the box's lateral half extent at its heading ψ).
    fn edge_excess_at(&self, zk: &State) -> f64 {
        let e = half_extent_at(self.ego_size, zk[2]);
        (self.edges[0] - (zk[1] - e)).max(0.0) + ((zk[1] + e) - self.edges[1]).max(0.0)
    }

    /// The road-edge part of [`Self::bound_excess`]: Σ over the states `z` (`[T]`, this frame)
    /// of how far the box's corners lie beyond the road's edges (m).
    pub(crate) fn edge_excess(&self, z: &[State]) -> f64 {
        z.iter().map(|zk| self.edge_excess_at(zk)).sum()
    }

    /// Whether the ego's box at the measured start spans no lane line: its extent across the
    /// road (½(L·|sin ψ| + W·|cos ψ|) either side of its centre, m) crosses none of the lane
    /// layout's interior boundaries ([`Self::spans_line`] of the start alone). False without
    /// a lane layout (nothing says where the lines are).
    pub(crate) fn starts_in_one_lane(&self) -> bool {
        self.lanes.is_some() && !self.spans_line(std::slice::from_ref(&self.start))
    }

    /// Whether the box of one of the states `z` (`[T]`, this frame) spans a lane line
    /// ([`crate::extents::Lanes::spans_line`] at its extent across the road); false without a
    /// lane layout.
    pub(crate) fn spans_line(&self, z: &[State]) -> bool {
        self.lanes.as_ref().is_some_and(|lanes| {
            let lanes = lanes.view();
            z.iter().any(|zk| {
                let e = half_extent_at(self.ego_size, zk[2]);
                let y = zk[1] + self.origin[1];
                lanes.spans_line(y - e, y + e)
            })
        })
    }

    /// The stopping rule's excess of the plan `z` (`[T]`, this frame) (m): that of its last
    /// state ([`crate::extents::Lanes::stop_excess`]), a terminal constraint: a plan that
    /// ends in a lane that really ends must end able to stop `stop_margin` before the end,
    /// braking at `stop_decel`; 0 without a lane layout.
    pub(crate) fn stop_excess(&self, z: &[State]) -> f64 {
        match (&self.lanes, z.last(), self.stop_rule) {
            (Some(lanes), Some(zt), Some(rule)) => {
                let (x, y) = (zt[0] + self.origin[0], zt[1] + self.origin[1]);
                lanes.view().stop_excess(x, y, zt[2], zt[3], &rule)
            }
            _ => 0.0,
        }
    }

    /// The largest violation of each soft constraint by the states `z` (`[T]`, this frame)
    /// whose minimum b is `min_b` ([`super::problem::Violation`]).
    pub(crate) fn violation(
        &self,
        safety_min: f64,
        z: &[State],
        min_b: Option<f64>,
    ) -> super::problem::Violation {
        let mut v = super::problem::Violation {
            safety: min_b.map_or(0.0, |b| {
                if b.is_finite() {
                    (safety_min - b).max(0.0)
                } else {
                    f64::INFINITY
                }
            }),
            lane: self.stop_excess(z),
            ..Default::default()
        };
        for (k, zk) in z.iter().enumerate() {
            let out = |j: usize| {
                (self.lower[k][j] - zk[j])
                    .max(zk[j] - self.upper[k][j])
                    .max(0.0)
            };
            v.corridor = v.corridor.max(out(1));
            v.heading = v.heading.max(out(2));
            v.road_edge = v.road_edge.max(self.edge_excess_at(zk));
            if let Some(lanes) = &self.lanes {
                let (x, y) = (zk[0] + self.origin[0], zk[1] + self.origin[1]);
                v.lane = v.lane.max(lanes.view().excess(x, y));
            }
        }
        v
    }

    /// The first of the states `z` (`[T]`, this frame) whose centre lies in a lane outside
    /// its extent.
    pub(crate) fn lane_violation(&self, z: &[State]) -> Option<crate::LaneViolation> {
        self.lanes
            .as_ref()
            .and_then(|lanes| lanes.view().first_violation(&self.to_world(z)))
    }

    /// Z⁺ = Π(Z − η·d) into `out`, Π clamping into the state bounds.
    pub(crate) fn project_step(
        &self,
        z: &[State],
        direction: &[State],
        eta: f64,
        out: &mut [State],
    ) {
        for (k, ((o, zk), dk)) in out.iter_mut().zip(z).zip(direction).enumerate() {
            *o = self.clamp(k, &(zk - eta * dk));
        }
    }
}

/// The weight of the lateral tracking error (1/m²): `w_y`, plus the deadline term
/// `w_deadline` · φ(d) while the ego's centre is in a lane that really ends d m ahead (d < 0
/// past it) and the target lies outside that lane ([`crate::extents`]). Exactly `w_y` without
/// a lane layout or farther than `deadline_distance` from the end.
pub(crate) fn lateral_weight(s: &PlannerSettings, p: &PlanningProblem<'_>) -> f64 {
    let factor = p
        .lanes
        .and_then(|lanes| lanes.merge_deadline(p.ego.x, p.ego.y, p.y_target))
        .map_or(0.0, |d| deadline_factor(d, s.lane_ends.deadline_distance));
    if factor > 0.0 {
        s.cost.w_y + s.lane_ends.w_deadline * factor
    } else {
        s.cost.w_y
    }
}

/// The stopping rule of this call ([`StopRule`]: `stop_decel`, `stop_margin`, the credit for
/// heading out of the lane), or `None` when it does not bind: without a lane layout, or when
/// the ego's start could not comply even braking at the planner's hardest deceleration
/// −`a_min` (or `stop_decel` if that is harder; its stopping point at that rate lies beyond its stopping line). Past that point
/// the rule would only make every plan that is still in the ending lane at the horizon
/// inadmissible and hand the step to the fallbacks; the ego is committed to the merge, which
/// the deadline weight drives. Short of it the rule binds, and an ego that has slipped past
/// the comfortable stopping point is brought back by plans (or stopping sequences) that
/// brake harder. Measured on the 105 merge scenarios of the train split: gated at
/// `stop_decel` instead (the ego let go as soon as it could not stop at 3 m/s²), the ego of
/// US-101 scene 7, vehicle 465 (63 m before the end at 17.3 m/s, blocked) slipped past that
/// point after one step at `stop_margin` 12 m and drove on to `LaneEnded` in every arm,
/// where gated at |`a_min`| it slows down and merges.
fn stop_rule(s: &PlannerSettings, p: &PlanningProblem<'_>) -> Option<StopRule> {
    let lanes = p.lanes?;
    let rule = StopRule::new(s);
    let hardest = StopRule {
        decel: (-s.bounds.a_min).max(s.lane_ends.stop_decel),
        ..rule
    };
    let e = &p.ego;
    let excess = lanes.stop_excess(e.x, e.y, e.psi, e.v, &hardest);
    (excess <= 0.0).then_some(rule)
}

/// Where the fallback's stopping sequences stop the ego: `stop_margin` before the end of the
/// lane it starts in, when that lane really ends ahead within reach of the stopping rule (a
/// plan accelerating at `a_max` over the horizon could break it) and the rule binds this call
/// ([`stop_rule`]), in the call's frame.
fn stop_line(s: &PlannerSettings, p: &PlanningProblem<'_>) -> Option<StopLine> {
    // Only while the stopping rule binds: past the point where the ego can still stop, braking
    // towards the line is no longer a way out ([`stop_rule`]).
    stop_rule(s, p)?;
    let lanes = p.lanes?;
    let x = lanes.stop_line(p.ego.x, p.ego.y, s.lane_ends.stop_margin)?;
    // Out of reach: no plan (accelerating at a_max all along) could break the stopping rule.
    let time = s.model.horizon as f64 * s.model.dt;
    let v_far = p.ego.v + s.bounds.a_max.max(0.0) * time;
    let reach =
        p.ego.x + 0.5 * (p.ego.v + v_far) * time + v_far * v_far / (2.0 * s.lane_ends.stop_decel);
    if reach < x {
        return None;
    }
    let own = lanes.lane_at(p.ego.y)?;
    Some(StopLine {
        x: x - p.ego.x,
        y_own: 0.5 * (lanes.bounds[own] + lanes.bounds[own + 1]) - p.ego.y,
    })
}

/// The lateral goal of the call (m): `y_target`, except while `y_target` lies in a lane that
/// really begins beyond the reach of the horizon (x_0 + v_0 · T · dt < begin) and the ego is
/// in another lane: then the centre of the ego's own lane, so that the ego does not press
/// against the line of a lane it may not enter yet.
fn held_goal(s: &PlannerSettings, p: &PlanningProblem<'_>) -> f64 {
    let Some(lanes) = p.lanes else {
        return p.y_target;
    };
    let (Some(target), Some(own)) = (lanes.lane_at(p.y_target), lanes.lane_at(p.ego.y)) else {
        return p.y_target;
    };
    let e = lanes.extents[target];
    let reach = p.ego.x + p.ego.v * s.model.horizon as f64 * s.model.dt;
    if target != own && e.begins && reach < e.begin {
        0.5 * (lanes.bounds[own] + lanes.bounds[own + 1])
    } else {
        p.y_target
    }
}

/// The per-step state bounds `[T]` (y relative to `y0`, m):
///
/// * heading: |ψ_k| ≤ max(`heading_max`, |ψ_0| − (k + 1)·`heading_recovery`), unbounded when
///   `heading_max` ≥ π/2;
/// * lateral: the road less the ego's half extent across the road at that heading bound (its
///   corners stay on the road) and `edge_margin`, intersected with the corridor from the start
///   to the lateral goal `y_goal` (the target, or the retreat lane's centre) widened by
///   `overshoot_max` on both sides; collapsed to its middle
///   when empty, and widened to include the start (data noise can put the ego slightly
///   outside);
/// * speed: 0 ≤ v ≤ max(`v_max`, v_0).
fn state_bounds(
    s: &PlannerSettings,
    p: &PlanningProblem<'_>,
    y0: f64,
    y_goal: f64,
) -> (Vec<State>, Vec<State>) {
    let t = s.model.horizon;
    let [length, width] = p.sizes[0];
    let bounded = s.bounds.heading_max < std::f64::consts::FRAC_PI_2;
    let goal = y_goal - y0;
    let (corridor_low, corridor_high) = (
        goal.min(0.0) - s.bounds.overshoot_max,
        goal.max(0.0) + s.bounds.overshoot_max,
    );
    let mut lower = Vec::with_capacity(t);
    let mut upper = Vec::with_capacity(t);
    for k in 0..t {
        let (heading, half_extent) = if bounded {
            let h = s
                .bounds
                .heading_max
                .max(p.ego.psi.abs() - (k + 1) as f64 * s.bounds.heading_recovery);
            (h, half_extent_across(length, width, h))
        } else {
            (f64::INFINITY, 0.5 * width)
        };
        let half = half_extent + s.bounds.edge_margin;
        let mut low = (p.road[0] + half - y0).max(corridor_low);
        let mut high = (p.road[1] - half - y0).min(corridor_high);
        if low > high {
            let mid = 0.5 * (low + high);
            low = mid;
            high = mid;
        }
        lower.push(State::new(f64::NEG_INFINITY, low.min(0.0), -heading, 0.0));
        upper.push(State::new(
            f64::INFINITY,
            high.max(0.0),
            heading,
            s.bounds.v_max.max(p.ego.v),
        ));
    }
    (lower, upper)
}

/// Extra room (m) beyond its start overhang an ego that starts over a road edge is given.
pub(crate) const START_OVERHANG_SLACK: f64 = 0.05;

/// The road edges relative to `y0` (m), each widened by the ego's overhang at the start
/// (its box at its measured heading) plus [`START_OVERHANG_SLACK`] when it starts over it.
fn road_edges(p: &PlanningProblem<'_>, y0: f64) -> [f64; 2] {
    let e = half_extent_at(p.sizes[0], p.ego.psi);
    let (right, left) = (p.road[0] - y0, p.road[1] - y0);
    let over_right = right - (-e);
    let over_left = e - left;
    [
        if over_right > 0.0 {
            right - over_right - START_OVERHANG_SLACK
        } else {
            right
        },
        if over_left > 0.0 {
            left + over_left + START_OVERHANG_SLACK
        } else {
            left
        },
    ]
}

/// Half extent across the road (m) of a box of `size` = (length, width) (m) at heading `psi`
/// (rad): ½(L·|sin ψ| + W·|cos ψ|).
pub(crate) fn half_extent_at(size: [f64; 2], psi: f64) -> f64 {
    let (s, c) = psi.sin_cos();
    0.5 * (size[0] * s.abs() + size[1] * c.abs())
}

/// Largest half extent across the road (m) of a box of `length` × `width` (m) whose heading
/// is at most `heading` (rad) off the road: ½(L·sin ψ + W·cos ψ), which grows with ψ up to
/// the half diagonal at ψ = atan(L/W).
fn half_extent_across(length: f64, width: f64, heading: f64) -> f64 {
    let h = heading.min(length.atan2(width));
    0.5 * (length * h.sin() + width * h.cos())
}

/// Φ1 or Φ2 of an input sequence: w Σu² + w_d Σ(u_k − u_{k−1})², u_{−1} = `prev`.
pub(crate) fn input_cost(u: &[f64], prev: f64, w: f64, wd: f64) -> f64 {
    let mut p = prev;
    let mut c = 0.0;
    for &x in u {
        c += w * x * x + wd * (x - p) * (x - p);
        p = x;
    }
    c
}

/// Hessian (`[t, t]` row-major) of w Σu² + w_d Σ(u_k − u_{k−1})², plus `extra` on the
/// diagonal.
pub(crate) fn input_hessian(t: usize, w: f64, wd: f64, extra: &[f64]) -> Vec<f64> {
    let mut p = vec![0.0; t * t];
    for k in 0..t {
        let dd = 1.0 + if k + 1 < t { 1.0 } else { 0.0 };
        p[k * t + k] = 2.0 * (w + wd * dd) + extra[k];
        if k + 1 < t {
            p[k * t + k + 1] = -2.0 * wd;
            p[(k + 1) * t + k] = -2.0 * wd;
        }
    }
    p
}
