//! What a closed-loop run is judged by: per step ([`StepMetrics`]) and per run
//! ([`RunMetrics`], [`Collision`]), computed from the run's states alone by the functions of
//! this module (each testable on constructed states), in nuPlan's spirit.
//!
//! Geometry: every vehicle is an oriented box ([`OrientedBox`]; the ego at its state, the
//! others at the heading of their last displacement, as the collision check); the road is the
//! scene's lane bounds `[L + 1]` (y, m), the first and last being the road's edges.
//!
//! * **Collisions, at fault or not** ([`classify_collision`]): a collision is a step at which
//!   the ego's box overlaps another vehicle's (separating-axis test); an event starts at the
//!   first step of a contact with one vehicle and is classified at that step. The ego is NOT
//!   at fault only when (a) the other vehicle is behind it (its centre behind the ego's centre
//!   along the road) and hits its rear (lateral offset of the centres below half the sum of
//!   the widths), (b) the ego is wholly inside one lane (its box spans no lane line and is on
//!   the road, [`wholly_in_one_lane`]), and (c) the ego's applied acceleration at that step is
//!   ≥ −`fault_brake_limit` ([`crate::SimConfig::fault_brake_limit`], 3 m/s²); otherwise it
//!   is at fault. A run with any collision is never a success.
//! * **nuPlan's own classification, beside it** ([`nuplan_collision_type`]): every event is
//!   also typed as nuplan-devkit types it (`no_ego_at_fault_collisions`) and judged by its
//!   rule ([`NuplanCollision::at_fault`]), to compare with numbers reported under nuPlan. It
//!   differs from the rule above in two ways: a vehicle coming from behind (its centre more
//!   than 150° off the ego's heading, seen from the ego's rear axle) is never the ego's fault,
//!   however hard the ego braked; and a side contact with the ego wholly inside one lane is
//!   not the ego's fault. It is stricter in one: hitting a stopped vehicle is always the
//!   ego's fault.
//! * **Off-road** ([`road_excess`]): a step is off-road when a corner of the ego's box lies
//!   beyond the outermost lane bounds by more than the ego's own overhang at the start (real
//!   egos start up to a few decimetres over the edge) plus [`OFF_ROAD_MARGIN_M`].
//! * **Straddling** ([`straddles`]): the ego's box spans a lane line.
//! * **Time to the target lane**: the first step whose ego centre lies inside the target lane
//!   (besides the time to settle of [`crate::RunRecord::steps_to_target`]).
//! * **Slow in a live lane** ([`traffic_speed`]): the ego's speed is below [`SLOW_FRACTION`]
//!   of the median speed of the other vehicles within [`TRAFFIC_RANGE_M`] along the road in
//!   the ego's lane (else in its adjacent lanes) while that median exceeds
//!   [`LIVE_TRAFFIC_MPS`]; executed (the ego's speed after the step) and planned (the speed at
//!   the end of the applied plan).
//! * **Time to collision** ([`min_ttc_ahead`]): over the vehicles ahead whose lateral extent
//!   overlaps the ego's, bumper gap / closing speed along the road (0 when the boxes already
//!   overlap along the road; none when nobody closes in).
//! * **Progress**: the ego's centre x minus its start x (m), and its ratio to the logged
//!   ego's progress at the last step the log covers.
//! * **Heading and overshoot**: the largest |ψ| relative to the road, and how far the ego's
//!   centre went beyond the target lane's centre in the direction of the lane change (m).
//! * **Comfort** ([`kinematics`]): longitudinal jerk from the applied accelerations, yaw rate
//!   and lateral acceleration (v · yaw rate) from the executed states, each per step; per run
//!   the largest magnitude and the RMS, and `comfortable` when every value is within nuPlan's
//!   published comfort limits ([`COMFORT`]).
//! * **Score** ([`score`]): nuPlan-style, multiplicative gates for an at-fault collision and
//!   for leaving the road, times a weighted average of the lane change's success (5), progress
//!   against the log (5), TTC within [`TTC_BOUND_S`] (5), no slow step in a live lane (4) and
//!   comfort (2).
//! * **Density** ([`free_gap`]): the free gap in the target lane around the ego at the start,
//!   bumper to bumper between the nearest target-lane vehicles ahead of and behind the ego's
//!   position (a missing one counts at [`FREE_GAP_RANGE_M`] from the ego); the report cuts it
//!   into terciles (dense / medium / sparse).

use nudge_predictor::{DT, T_OBS};
use serde::{Deserialize, Serialize};

use nudge_planner::scenario::Scenario;
use nudge_planner::{OrientedBox, clip_segment_to_box, motion_heading};

/// Tolerance (m) added to the ego's own overhang at the start before a step counts as
/// off-road.
pub const OFF_ROAD_MARGIN_M: f64 = 0.1;
/// A step is slow when the ego's speed is below this fraction of the surrounding traffic's.
pub const SLOW_FRACTION: f64 = 0.3;
/// Other vehicles within this distance along the road (m, centre to centre) make the ego's
/// surrounding traffic: the planner's lane-flow range ([`nudge_planner::lane::FLOW_RANGE_M`]).
pub const TRAFFIC_RANGE_M: f64 = nudge_planner::lane::FLOW_RANGE_M;
/// The surrounding traffic is live when its median speed exceeds this (m/s).
pub const LIVE_TRAFFIC_MPS: f64 = 3.0;
/// The road ahead of the ego is free when the nearest vehicle in its path ([`lead_gap`]) is
/// at least this time headway (s) ahead at the faster of the ego's speed and the surrounding
/// traffic's: the two-second rule of driver handbooks. A plan that ends slow while a vehicle
/// is closer than that answers a queue, not a free-flowing road ([`road_free`]).
pub const FREE_ROAD_HEADWAY_S: f64 = 2.0;
/// A missing vehicle ahead of or behind the ego in the target lane counts at this distance
/// (m) along the road (the scenes hold the neighbours within 60 m).
pub const FREE_GAP_RANGE_M: f64 = 60.0;
/// A run's TTC is within bound when its minimum exceeds this (s; nuPlan's `least_min_ttc`).
pub const TTC_BOUND_S: f64 = 0.95;
/// A logged ego progress below this (m) makes any progress count as full.
pub const MIN_LOG_PROGRESS_M: f64 = 1.0;

/// Comfort limits: the largest magnitudes a comfortable run stays within.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ComfortLimits {
    /// Longitudinal acceleration range (m/s²).
    pub accel: (f64, f64),
    /// Longitudinal jerk (m/s³).
    pub jerk: f64,
    /// Lateral acceleration (m/s²).
    pub lat_accel: f64,
    /// Yaw rate (rad/s).
    pub yaw_rate: f64,
    /// Yaw acceleration (rad/s²).
    pub yaw_accel: f64,
}

/// nuPlan's comfort limits (nuplan-devkit, metric `ego_is_comfortable`: longitudinal
/// acceleration in [−4.05, 2.40] m/s², |longitudinal jerk| ≤ 4.13 m/s³, |lateral
/// acceleration| ≤ 4.89 m/s², |yaw rate| ≤ 0.95 rad/s, |yaw acceleration| ≤ 1.93 rad/s²).
pub const COMFORT: ComfortLimits = ComfortLimits {
    accel: (-4.05, 2.40),
    jerk: 4.13,
    lat_accel: 4.89,
    yaw_rate: 0.95,
    yaw_accel: 1.93,
};

/// Weights of the score's averaged parts: success, progress, TTC, live-lane speed, comfort.
pub const SCORE_WEIGHTS: [f64; 5] = [5.0, 5.0, 5.0, 4.0, 2.0];

/// A vehicle at one step: its box and its speed along the road (m/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vehicle {
    /// Its box.
    pub bbox: OrientedBox,
    /// Speed along the road (m/s).
    pub vx: f64,
}

/// The ego's box in state (x, y, ψ, v) for a vehicle of `size` = (length, width) (m).
#[must_use]
pub fn ego_box(state: [f64; 4], size: [f64; 2]) -> OrientedBox {
    OrientedBox {
        x: state[0],
        y: state[1],
        heading: state[2],
        length: size[0],
        width: size[1],
    }
}

/// The other vehicles (agents 1..n) after a step, from their observed positions `[n][T_OBS]`
/// (m): each at its last position, with the heading of its last displacement
/// ([`motion_heading`], the scene's heading when it barely moved) and the speed along the
/// road of that displacement.
#[must_use]
pub fn others_from_history(sc: &Scenario, observed: &[Vec<[f64; 2]>]) -> Vec<Vehicle> {
    (1..sc.n_agents)
        .map(|i| {
            let (a, b) = (observed[i][T_OBS - 2], observed[i][T_OBS - 1]);
            Vehicle {
                bbox: OrientedBox {
                    x: b[0],
                    y: b[1],
                    heading: motion_heading(a, b, sc.heading[i]),
                    length: sc.size[i][0],
                    width: sc.size[i][1],
                },
                vx: (b[0] - a[0]) / DT,
            }
        })
        .collect()
}

/// The four corners of a box (m).
#[must_use]
pub fn corners(b: &OrientedBox) -> [[f64; 2]; 4] {
    let (s, c) = b.heading.sin_cos();
    let (hl, hw) = (0.5 * b.length, 0.5 * b.width);
    [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0)]
        .map(|(u, w)| [b.x + u * hl * c - w * hw * s, b.y + u * hl * s + w * hw * c])
}

/// (lowest, highest) y of a box's corners (m).
#[must_use]
pub fn lateral_extent(b: &OrientedBox) -> (f64, f64) {
    let ys = corners(b).map(|p| p[1]);
    (
        ys.iter().copied().fold(f64::INFINITY, f64::min),
        ys.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    )
}

/// (rear-most, front-most) x of a box's corners (m).
#[must_use]
pub fn longitudinal_extent(b: &OrientedBox) -> (f64, f64) {
    let xs = corners(b).map(|p| p[0]);
    (
        xs.iter().copied().fold(f64::INFINITY, f64::min),
        xs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    )
}

/// How far the box's farthest corner lies beyond the road's edges `bounds[0]`,
/// `bounds[L]` (m): positive when a corner is off the road, negative (the smallest margin)
/// when the box is on it.
#[must_use]
pub fn road_excess(b: &OrientedBox, bounds: &[f64]) -> f64 {
    let (lo, hi) = lateral_extent(b);
    (bounds[0] - lo).max(hi - bounds[bounds.len() - 1])
}

/// Whether the box spans a lane line (an interior bound strictly inside its lateral extent).
#[must_use]
pub fn straddles(b: &OrientedBox, bounds: &[f64]) -> bool {
    let (lo, hi) = lateral_extent(b);
    bounds[1..bounds.len() - 1]
        .iter()
        .any(|&line| lo < line && line < hi)
}

/// Whether the box is wholly inside one lane: it spans no lane line and lies on the road,
/// the road's edges widened by `edge_tolerance` (m; the ego's off-road tolerance).
#[must_use]
pub fn wholly_in_one_lane(b: &OrientedBox, bounds: &[f64], edge_tolerance: f64) -> bool {
    !straddles(b, bounds) && road_excess(b, bounds) <= edge_tolerance
}

/// The lane holding lateral position `y` (m), `None` off the road.
#[must_use]
pub fn lane_of(y: f64, bounds: &[f64]) -> Option<usize> {
    (0..bounds.len() - 1).find(|&k| bounds[k] <= y && y < bounds[k + 1])
}

/// A collision event: the first step of the ego's contact with one other vehicle, and the
/// geometry that classified it ([`classify_collision`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Collision {
    /// Closed-loop step (0-based) of the first contact.
    pub step: usize,
    /// The other vehicle's agent index (1..n).
    pub other: usize,
    /// The ego is at fault.
    pub at_fault: bool,
    /// (a) the other's centre is behind the ego's along the road ...
    pub other_behind: bool,
    /// ... and it hits the ego's rear (|Δy| of the centres < half the sum of the widths).
    pub rear_hit: bool,
    /// (b) the ego is wholly inside one lane.
    pub ego_in_lane: bool,
    /// (c) the ego's applied acceleration at that step (m/s²).
    pub ego_accel: f64,
    /// The other's centre minus the ego's, along the road (m).
    pub dx: f64,
    /// The other's centre minus the ego's, across the road (m).
    pub dy: f64,
    /// The ego's heading (rad).
    pub ego_heading: f64,
    /// The other's heading (rad).
    pub other_heading: f64,
    /// The ego's speed (m/s).
    pub ego_v: f64,
    /// The other's speed along the road (m/s).
    pub other_v: f64,
    /// The event's type under nuPlan's classification ([`nuplan_collision_type`]).
    pub nuplan_type: NuplanCollision,
    /// The ego is at fault under nuPlan's rule ([`NuplanCollision::at_fault`]).
    pub nuplan_at_fault: bool,
}

/// A collision's type as nuplan-devkit classifies it (`no_ego_at_fault_collisions`), checked
/// in this order ([`nuplan_collision_type`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum NuplanCollision {
    /// The ego's speed is at most [`NUPLAN_STOPPED_MPS`].
    StoppedEgo,
    /// The other's speed is at most [`NUPLAN_STOPPED_MPS`].
    StoppedTrack,
    /// The other's centre is more than [`NUPLAN_BEHIND_DEG`] off the ego's heading, seen from
    /// the ego's rear axle.
    ActiveRear,
    /// The ego's front edge (its bumper, corner to corner) touches the other's box.
    ActiveFront,
    /// Any other contact.
    ActiveLateral,
}

impl NuplanCollision {
    /// The type's name as nuPlan spells it (`"STOPPED_EGO_COLLISION"`, ...).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::StoppedEgo => "STOPPED_EGO_COLLISION",
            Self::StoppedTrack => "STOPPED_TRACK_COLLISION",
            Self::ActiveRear => "ACTIVE_REAR_COLLISION",
            Self::ActiveFront => "ACTIVE_FRONT_COLLISION",
            Self::ActiveLateral => "ACTIVE_LATERAL_COLLISION",
        }
    }

    /// nuPlan's rule: the ego is at fault for a front collision and for one with a stopped
    /// vehicle, and for a lateral one unless it is wholly inside one lane (`ego_in_lane`;
    /// nuPlan: in multiple lanes or off the drivable area); never for a rear collision nor
    /// while stopped.
    #[must_use]
    pub fn at_fault(self, ego_in_lane: bool) -> bool {
        match self {
            Self::StoppedTrack | Self::ActiveFront => true,
            Self::ActiveLateral => !ego_in_lane,
            Self::StoppedEgo | Self::ActiveRear => false,
        }
    }
}

/// nuPlan's speed (m/s) at or below which a vehicle counts as stopped in a collision.
pub const NUPLAN_STOPPED_MPS: f64 = 0.05;
/// nuPlan's angle (degrees) off the ego's heading beyond which another vehicle is behind it.
pub const NUPLAN_BEHIND_DEG: f64 = 150.0;

/// The type of a contact between the ego (`ego`, speed `ego_v` (m/s), its rear axle
/// `rear_axle` metres behind its box's centre along its heading) and `vehicle` under nuPlan's
/// classification, in nuPlan's order: the ego stopped, the other stopped (its speed along the
/// road), the other behind (the angle between the ego's heading and the direction from the
/// rear axle to the other's centre above [`NUPLAN_BEHIND_DEG`]), the ego's front edge touching
/// the other's box, else lateral.
#[must_use]
pub fn nuplan_collision_type(
    ego: &OrientedBox,
    ego_v: f64,
    rear_axle: f64,
    vehicle: &Vehicle,
) -> NuplanCollision {
    let (s, c) = ego.heading.sin_cos();
    let axle = [ego.x - rear_axle * c, ego.y - rear_axle * s];
    let to_other = [vehicle.bbox.x - axle[0], vehicle.bbox.y - axle[1]];
    let cos_angle = (to_other[0] * c + to_other[1] * s) / to_other[0].hypot(to_other[1]);
    let behind = cos_angle < NUPLAN_BEHIND_DEG.to_radians().cos();
    let [front_left, front_right, _, _] = corners(ego);
    if ego_v.abs() <= NUPLAN_STOPPED_MPS {
        NuplanCollision::StoppedEgo
    } else if vehicle.vx.abs() <= NUPLAN_STOPPED_MPS {
        NuplanCollision::StoppedTrack
    } else if behind {
        NuplanCollision::ActiveRear
    } else if segment_touches_box(front_left, front_right, &vehicle.bbox) {
        NuplanCollision::ActiveFront
    } else {
        NuplanCollision::ActiveLateral
    }
}

/// Whether the segment from `a` to `b` (m) touches box `bx` (closed): the segment clipped to
/// the box in the box's frame ([`clip_segment_to_box`]) is not empty.
#[must_use]
pub fn segment_touches_box(a: [f64; 2], b: [f64; 2], bx: &OrientedBox) -> bool {
    segment_in_box(a, b, bx).is_some()
}

/// The part of the segment `a` + t·(`b` − `a`) (m), t ∈ [0, 1], inside box `bx` (closed), as
/// its parameter interval (t0, t1): [`clip_segment_to_box`] in the box's frame; `None` when no
/// point of the segment is inside.
fn segment_in_box(a: [f64; 2], b: [f64; 2], bx: &OrientedBox) -> Option<(f64, f64)> {
    let (s, c) = bx.heading.sin_cos();
    let local = |p: [f64; 2]| {
        let (dx, dy) = (p[0] - bx.x, p[1] - bx.y);
        [dx * c + dy * s, -dx * s + dy * c]
    };
    let half = [0.5 * bx.length, 0.5 * bx.width];
    clip_segment_to_box(local(a), local(b), [-half[0], -half[1]], half)
}

/// Classifies the collision starting at `step` between the ego (`ego`, speed `ego_v` (m/s),
/// applied acceleration `ego_accel` (m/s²)) and agent `other` (`vehicle`) on a road of lane
/// `bounds`: not at fault only when (a) the other is behind and hits the ego's rear, (b) the
/// ego is wholly inside one lane (road edges widened by `edge_tolerance`, m) and (c)
/// `ego_accel` ≥ −`brake_limit` (m/s²); at fault otherwise. Also typed and judged by nuPlan's
/// rule ([`nuplan_collision_type`], the ego's rear axle `rear_axle` m behind its centre).
#[allow(clippy::too_many_arguments)]
#[must_use]
pub fn classify_collision(
    step: usize,
    ego: &OrientedBox,
    ego_v: f64,
    ego_accel: f64,
    other: usize,
    vehicle: &Vehicle,
    bounds: &[f64],
    edge_tolerance: f64,
    brake_limit: f64,
    rear_axle: f64,
) -> Collision {
    let o = &vehicle.bbox;
    let (dx, dy) = (o.x - ego.x, o.y - ego.y);
    let other_behind = dx < 0.0;
    let rear_hit = other_behind && dy.abs() < 0.5 * (ego.width + o.width);
    let ego_in_lane = wholly_in_one_lane(ego, bounds, edge_tolerance);
    let not_at_fault = rear_hit && ego_in_lane && ego_accel >= -brake_limit;
    let nuplan_type = nuplan_collision_type(ego, ego_v, rear_axle, vehicle);
    Collision {
        step,
        other,
        at_fault: !not_at_fault,
        other_behind,
        rear_hit,
        ego_in_lane,
        ego_accel,
        dx,
        dy,
        ego_heading: ego.heading,
        other_heading: o.heading,
        ego_v,
        other_v: vehicle.vx,
        nuplan_type,
        nuplan_at_fault: nuplan_type.at_fault(ego_in_lane),
    }
}

/// Agent indices (1..n; `others[k]` is agent k + 1) whose boxes overlap the ego's.
#[must_use]
pub fn contacts(ego: &OrientedBox, others: &[Vehicle]) -> Vec<usize> {
    others
        .iter()
        .enumerate()
        .filter(|(_, o)| ego.overlaps(&o.bbox))
        .map(|(k, _)| k + 1)
        .collect()
}

/// The nearest other vehicle: (agent index, x − x_ego, y − y_ego) (m), by centre distance.
#[must_use]
pub fn nearest(ego: &OrientedBox, others: &[Vehicle]) -> Option<(usize, f64, f64)> {
    let mut best: Option<(usize, f64, f64)> = None;
    for (k, o) in others.iter().enumerate() {
        let (dx, dy) = (o.bbox.x - ego.x, o.bbox.y - ego.y);
        if best.is_none_or(|(_, bx, by)| dx.hypot(dy) < bx.hypot(by)) {
            best = Some((k + 1, dx, dy));
        }
    }
    best
}

/// The smallest time to collision (s) with a vehicle ahead (centre ahead of the ego's) whose
/// lateral extent overlaps the ego's: bumper gap (rear-most x of its box minus the front-most
/// x of the ego's) over the closing speed (the ego's speed along the road `ego_vx` minus its
/// own, m/s); 0 when the gap is ≤ 0; `None` when no such vehicle closes in.
#[must_use]
pub fn min_ttc_ahead(ego: &OrientedBox, ego_vx: f64, others: &[Vehicle]) -> Option<f64> {
    let (e_lo, e_hi) = lateral_extent(ego);
    let front = longitudinal_extent(ego).1;
    let mut best: Option<f64> = None;
    for o in others {
        if o.bbox.x <= ego.x {
            continue;
        }
        let (o_lo, o_hi) = lateral_extent(&o.bbox);
        if o_hi <= e_lo || o_lo >= e_hi {
            continue;
        }
        let gap = longitudinal_extent(&o.bbox).0 - front;
        let closing = ego_vx - o.vx;
        let ttc = if gap <= 0.0 {
            Some(0.0)
        } else if closing > 0.0 {
            Some(gap / closing)
        } else {
            None
        };
        if let Some(t) = ttc
            && best.is_none_or(|b| t < b)
        {
            best = Some(t);
        }
    }
    best
}

/// The bumper gap (m) from the ego's box to the nearest vehicle ahead in its path: how far the
/// ego's box can move along the road (+x) before it first touches the other's box, over the
/// vehicles whose centre is ahead of the ego's and that it would touch ([`sweep_gap`]); the
/// other's rear-most x minus the ego's front-most x (≤ 0) for one the ego already overlaps;
/// `None` when no vehicle is ahead in the path.
#[must_use]
pub fn lead_gap(ego: &OrientedBox, others: &[Vehicle]) -> Option<f64> {
    let front = longitudinal_extent(ego).1;
    others
        .iter()
        .filter(|o| o.bbox.x > ego.x)
        .filter_map(|o| {
            if ego.overlaps(&o.bbox) {
                Some((longitudinal_extent(&o.bbox).0 - front).min(0.0))
            } else {
                sweep_gap(ego, &o.bbox)
            }
        })
        .fold(None, |best: Option<f64>, g| {
            Some(best.map_or(g, |b| b.min(g)))
        })
}

/// How far (m) box `a` moves along +x before it first touches box `b` (they do not overlap
/// now); `None` when it never does. First contact of two convex boxes in translation is a
/// corner of one on an edge of the other: the nearest entry of a corner of `a` moving +x into
/// `b`, or of a corner of `b` moving −x into `a`.
#[must_use]
pub fn sweep_gap(a: &OrientedBox, b: &OrientedBox) -> Option<f64> {
    let reach = longitudinal_extent(b).1 - longitudinal_extent(a).0;
    if reach.is_nan() || reach <= 0.0 {
        return None;
    }
    let entry = |p: [f64; 2], dir: f64, bx: &OrientedBox| {
        segment_in_box(p, [p[0] + dir * reach, p[1]], bx).map(|(t0, _)| t0 * reach)
    };
    corners(a)
        .into_iter()
        .filter_map(|p| entry(p, 1.0, b))
        .chain(corners(b).into_iter().filter_map(|q| entry(q, -1.0, a)))
        .fold(None, |best: Option<f64>, g| {
            Some(best.map_or(g, |m| m.min(g)))
        })
}

/// Whether the road ahead of an ego at speed `v` (m/s) is free: no vehicle ahead in its path
/// (`lead_gap` `None`), or one at least [`FREE_ROAD_HEADWAY_S`] × max(`v`, `traffic`) ahead
/// (m; `traffic` the surrounding traffic's speed, m/s, when there is any). Non-finite inputs
/// never make the road free.
#[must_use]
pub fn road_free(lead_gap: Option<f64>, v: f64, traffic: Option<f64>) -> bool {
    let traffic = traffic.unwrap_or(v);
    if !v.is_finite() || !traffic.is_finite() {
        return false;
    }
    lead_gap.is_none_or(|g| g >= FREE_ROAD_HEADWAY_S * v.max(traffic))
}

pub use nudge_planner::lane::median;

/// The speed of the ego's surrounding traffic (m/s): the median speed along the road of the
/// other vehicles within [`TRAFFIC_RANGE_M`] of the ego's x whose centres are in the ego's
/// lane (the lane of its centre, the nearest lane off the road), else of those in the lanes
/// next to it; `None` when there are none.
#[must_use]
pub fn traffic_speed(ego: &OrientedBox, others: &[Vehicle], bounds: &[f64]) -> Option<f64> {
    let lane = super::idm::lane_index(bounds, ego.y);
    let near: Vec<(usize, f64)> = others
        .iter()
        .filter(|o| (o.bbox.x - ego.x).abs() <= TRAFFIC_RANGE_M)
        .filter_map(|o| lane_of(o.bbox.y, bounds).map(|l| (l, o.vx)))
        .collect();
    let speeds = |pick: &dyn Fn(usize) -> bool| -> Vec<f64> {
        near.iter()
            .filter(|(l, _)| pick(*l))
            .map(|(_, v)| *v)
            .collect()
    };
    let own = speeds(&|l| l == lane);
    if own.is_empty() {
        median(&speeds(&|l| l.abs_diff(lane) == 1))
    } else {
        median(&own)
    }
}

/// Whether speed `v` (m/s) is slow in traffic moving at `traffic` (m/s): the traffic is live
/// (> [`LIVE_TRAFFIC_MPS`]) and `v` < [`SLOW_FRACTION`] · `traffic`.
#[must_use]
pub fn is_slow(v: f64, traffic: Option<f64>) -> bool {
    traffic.is_some_and(|t| t > LIVE_TRAFFIC_MPS && v < SLOW_FRACTION * t)
}

/// The free gap (m) in lane `lane` around the ego at the start of scene `sc`: the rear of the
/// nearest vehicle ahead of the ego's x minus the front of the nearest one behind it (centres
/// in the lane, last observed positions); a missing one counts at [`FREE_GAP_RANGE_M`] from
/// the ego's x.
#[must_use]
pub fn free_gap(sc: &Scenario, lane: usize) -> f64 {
    let x0 = sc.position(0, T_OBS - 1)[0];
    let mut ahead = x0 + FREE_GAP_RANGE_M;
    let mut behind = x0 - FREE_GAP_RANGE_M;
    for i in 1..sc.n_agents {
        let p = sc.position(i, T_OBS - 1);
        if lane_of(p[1], &sc.lane_bounds) != Some(lane) {
            continue;
        }
        let half = 0.5 * sc.size[i][0];
        if p[0] >= x0 {
            ahead = ahead.min(p[0] - half);
        } else {
            behind = behind.max(p[0] + half);
        }
    }
    ahead - behind
}

/// The kinematics of one executed step.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Kinematics {
    /// Longitudinal jerk (m/s³): change of the applied acceleration over the step; `None` at
    /// the first step (the acceleration before the run is unknown).
    pub jerk: Option<f64>,
    /// Yaw rate (rad/s): change of heading over the step.
    pub yaw_rate: f64,
    /// Lateral acceleration (m/s²): yaw rate times the step's mean speed.
    pub lat_accel: f64,
    /// Yaw acceleration (rad/s²): change of the yaw rate; `None` at the first step.
    pub yaw_accel: Option<f64>,
}

/// The kinematics of a step from state `before` to `after` (x, y, ψ, v) with applied
/// acceleration `accel` (m/s²), given the previous step's applied acceleration and yaw rate
/// (`None` at the first step).
#[must_use]
pub fn kinematics(
    before: [f64; 4],
    after: [f64; 4],
    accel: f64,
    previous: Option<(f64, f64)>,
) -> Kinematics {
    let yaw_rate = (after[2] - before[2]) / DT;
    Kinematics {
        jerk: previous.map(|(a, _)| (accel - a) / DT),
        yaw_rate,
        lat_accel: yaw_rate * 0.5 * (before[3] + after[3]),
        yaw_accel: previous.map(|(_, r)| (yaw_rate - r) / DT),
    }
}

/// What one step is judged by.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StepMetrics {
    /// [`road_excess`] of the ego's box (m): > 0 when a corner is beyond the road's edge.
    pub road_excess: f64,
    /// Off the road: `road_excess` exceeds the start overhang + [`OFF_ROAD_MARGIN_M`].
    pub off_road: bool,
    /// The ego's box spans a lane line.
    pub straddle: bool,
    /// The ego's centre is inside the target lane.
    pub in_target_lane: bool,
    /// Speed of the surrounding traffic ([`traffic_speed`], m/s).
    pub traffic_v: Option<f64>,
    /// The ego's speed after the step is slow in live traffic ([`is_slow`]).
    pub slow: bool,
    /// The speed at the end of the applied plan is slow in live traffic.
    pub slow_planned: bool,
    /// Bumper gap to the nearest vehicle ahead in the ego's path ([`lead_gap`], m).
    #[serde(default)]
    pub lead_gap: Option<f64>,
    /// `slow_planned` while the road ahead is free ([`road_free`] at the ego's speed after the
    /// step): a planned standstill in a live lane on a free-flowing road.
    #[serde(default)]
    pub slow_planned_free: bool,
    /// Time to collision with the vehicle ahead ([`min_ttc_ahead`], s).
    pub ttc: Option<f64>,
    /// The ego's x minus its start x (m).
    pub progress: f64,
    /// Jerk, yaw rate, lateral acceleration, yaw acceleration.
    pub kinematics: Kinematics,
}

/// Largest magnitudes and RMS of the comfort quantities over a run, and nuPlan's verdict.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Comfort {
    /// max |jerk| (m/s³), 0 with fewer than two steps.
    pub max_abs_jerk: f64,
    /// RMS jerk (m/s³).
    pub rms_jerk: f64,
    /// max |lateral acceleration| (m/s²).
    pub max_abs_lat_accel: f64,
    /// RMS lateral acceleration (m/s²).
    pub rms_lat_accel: f64,
    /// max |yaw rate| (rad/s).
    pub max_abs_yaw_rate: f64,
    /// RMS yaw rate (rad/s).
    pub rms_yaw_rate: f64,
    /// max |yaw acceleration| (rad/s²).
    pub max_abs_yaw_accel: f64,
    /// Smallest and largest applied acceleration (m/s²; 0, 0 without a step).
    pub accel_range: (f64, f64),
    /// Every value within [`COMFORT`].
    pub comfortable: bool,
}

impl Comfort {
    /// The comfort of a run's steps: their kinematics and applied accelerations (m/s²).
    #[must_use]
    pub fn of(kinematics: &[Kinematics], accels: &[f64]) -> Self {
        let stats = |v: Vec<f64>| -> (f64, f64) {
            if v.is_empty() {
                return (0.0, 0.0);
            }
            let max = v.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
            let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
            (max, rms)
        };
        let (max_abs_jerk, rms_jerk) = stats(kinematics.iter().filter_map(|k| k.jerk).collect());
        let (max_abs_lat_accel, rms_lat_accel) =
            stats(kinematics.iter().map(|k| k.lat_accel).collect());
        let (max_abs_yaw_rate, rms_yaw_rate) =
            stats(kinematics.iter().map(|k| k.yaw_rate).collect());
        let (max_abs_yaw_accel, _) = stats(kinematics.iter().filter_map(|k| k.yaw_accel).collect());
        let accel_range = if accels.is_empty() {
            (0.0, 0.0)
        } else {
            accels
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &a| {
                    (lo.min(a), hi.max(a))
                })
        };
        let comfortable = accel_range.0 >= COMFORT.accel.0
            && accel_range.1 <= COMFORT.accel.1
            && max_abs_jerk <= COMFORT.jerk
            && max_abs_lat_accel <= COMFORT.lat_accel
            && max_abs_yaw_rate <= COMFORT.yaw_rate
            && max_abs_yaw_accel <= COMFORT.yaw_accel;
        Self {
            max_abs_jerk,
            rms_jerk,
            max_abs_lat_accel,
            rms_lat_accel,
            max_abs_yaw_rate,
            rms_yaw_rate,
            max_abs_yaw_accel,
            accel_range,
            comfortable,
        }
    }
}

/// What one run is judged by.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct RunMetrics {
    /// Collision events with the ego at fault.
    pub collisions_at_fault: usize,
    /// Collision events with the ego not at fault.
    pub collisions_not_at_fault: usize,
    /// Collision events with the ego at fault under nuPlan's rule
    /// ([`NuplanCollision::at_fault`]; beside `collisions_at_fault`, for comparison).
    pub collisions_at_fault_nuplan: usize,
    /// The ego's overhang beyond the road's edge at the start (m, ≥ 0).
    pub start_overhang: f64,
    /// Steps off the road.
    pub off_road_steps: usize,
    /// Steps straddling a lane line.
    pub straddle_steps: usize,
    /// Steps until the ego's centre first lay inside the target lane (the step's index + 1).
    pub steps_to_lane: Option<usize>,
    /// Steps slow in a live lane (executed speed).
    pub slow_steps: usize,
    /// Steps whose applied plan ended slow in a live lane.
    pub slow_planned_steps: usize,
    /// Of those, the steps at which the road ahead was free ([`StepMetrics::slow_planned_free`]).
    #[serde(default)]
    pub slow_planned_free_steps: usize,
    /// Smallest time to collision over the run (s); `None` when nobody ahead closed in.
    pub min_ttc: Option<f64>,
    /// The ego's progress along the road over the run (m).
    pub progress: f64,
    /// The ego's progress over the logged ego's at the last step the log covers; `None` when
    /// the log covers no step or the logged ego progressed less than [`MIN_LOG_PROGRESS_M`].
    pub progress_ratio: Option<f64>,
    /// Comfort.
    pub comfort: Comfort,
    /// The largest |heading| relative to the road over the run (rad).
    pub max_abs_heading: f64,
    /// The farthest the ego's centre went beyond the target lane's centre in the direction of
    /// the lane change (m, ≥ 0).
    pub max_overshoot: f64,
    /// The free gap in the target lane at the start ([`free_gap`], m).
    pub free_gap: f64,
    /// The aggregate score in [0, 1] ([`score`]).
    pub score: f64,
}

/// The score of a run in [0, 1]: 0 with an at-fault collision or an off-road step, else the
/// weighted average ([`SCORE_WEIGHTS`]) of success (0/1), progress (min(1, ego / logged
/// progress); 1 when the log covers no step or the logged ego barely moved), TTC within bound
/// (min TTC > [`TTC_BOUND_S`] or none), the share of steps not slow in a live lane, and
/// comfort (0/1).
#[must_use]
pub fn score(m: &RunMetrics, success: bool, n_steps: usize) -> f64 {
    if m.collisions_at_fault > 0 || m.off_road_steps > 0 {
        return 0.0;
    }
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    let progress = m.progress_ratio.map_or(1.0, |r| r.clamp(0.0, 1.0));
    let ttc = flag(m.min_ttc.is_none_or(|t| t > TTC_BOUND_S));
    let speed = if n_steps == 0 {
        1.0
    } else {
        1.0 - m.slow_steps as f64 / n_steps as f64
    };
    let parts = [
        flag(success),
        progress,
        ttc,
        speed,
        flag(m.comfort.comfortable),
    ];
    let total: f64 = SCORE_WEIGHTS.iter().sum();
    SCORE_WEIGHTS
        .iter()
        .zip(parts)
        .map(|(w, p)| w * p)
        .sum::<f64>()
        / total
}

/// Follows one run step by step: the per-step metrics, the collision events, and at the end
/// the run's metrics.
#[derive(Debug, Clone)]
pub struct RunObserver {
    bounds: Vec<f64>,
    /// Target lane's (right, left) bounds (m).
    target: (f64, f64),
    /// Target lane's centre (m) and the sign of the lane change (+1 to the left).
    target_centre: (f64, f64),
    ego_size: [f64; 2],
    start: [f64; 4],
    start_overhang: f64,
    brake_limit: f64,
    /// The ego's rear axle behind its centre (m), for nuPlan's classification.
    rear_axle: f64,
    free_gap: f64,
    /// The log's ego x per future step (1-based index k − 1), `None` where not valid.
    log_x: Vec<Option<f64>>,
    previous: [f64; 4],
    previous_inputs: Option<(f64, f64)>,
    touching: Vec<usize>,
    collisions: Vec<Collision>,
    steps: Vec<(StepMetrics, f64)>,
    /// The ego's state after every step.
    states: Vec<[f64; 4]>,
}

impl RunObserver {
    /// The observer of a run of scene `sc` towards lane `target_lane` with the at-fault
    /// braking limit `brake_limit` (m/s²) and the ego's rear axle `rear_axle` (m) behind its
    /// centre (the planner's `l_r`); the ego starts at the scene's last observation.
    #[must_use]
    pub fn new(sc: &Scenario, target_lane: usize, brake_limit: f64, rear_axle: f64) -> Self {
        let p = sc.position(0, T_OBS - 1);
        let start = [p[0], p[1], sc.heading[0], sc.speed[0]];
        let b = &sc.lane_bounds;
        Self {
            bounds: b.clone(),
            target: (b[target_lane], b[target_lane + 1]),
            target_centre: (
                sc.lane_centres[target_lane],
                (sc.lane_centres[target_lane] - p[1]).signum(),
            ),
            ego_size: sc.size[0],
            start,
            start_overhang: road_excess(&ego_box(start, sc.size[0]), b).max(0.0),
            brake_limit,
            rear_axle,
            free_gap: free_gap(sc, target_lane),
            log_x: (1..=sc.n_future)
                .map(|k| sc.future_at(0, k).map(|q| q[0]))
                .collect(),
            previous: start,
            previous_inputs: None,
            touching: Vec::new(),
            collisions: Vec::new(),
            steps: Vec::new(),
            states: Vec::new(),
        }
    }

    /// The off-road tolerance (m): the start overhang + [`OFF_ROAD_MARGIN_M`].
    #[must_use]
    pub fn off_road_tolerance(&self) -> f64 {
        self.start_overhang + OFF_ROAD_MARGIN_M
    }

    /// Judges step `step`: the ego now in `ego` (x, y, ψ, v) after applying `accel` (m/s²),
    /// its plan ending at speed `v_planned` (m/s), the others at `others`
    /// (agent k + 1 at index k). Returns the step's metrics, the agents in contact, and the
    /// nearest other vehicle.
    pub fn observe(
        &mut self,
        step: usize,
        ego: [f64; 4],
        accel: f64,
        v_planned: f64,
        others: &[Vehicle],
    ) -> (StepMetrics, Vec<usize>, Option<(usize, f64, f64)>) {
        let b = ego_box(ego, self.ego_size);
        let tolerance = self.off_road_tolerance();
        let touching = contacts(&b, others);
        for &k in &touching {
            if !self.touching.contains(&k) {
                self.collisions.push(classify_collision(
                    step,
                    &b,
                    ego[3],
                    accel,
                    k,
                    &others[k - 1],
                    &self.bounds,
                    tolerance,
                    self.brake_limit,
                    self.rear_axle,
                ));
            }
        }
        self.touching.clone_from(&touching);
        let excess = road_excess(&b, &self.bounds);
        let traffic_v = traffic_speed(&b, others, &self.bounds);
        let lead = lead_gap(&b, others);
        let slow_planned = is_slow(v_planned, traffic_v);
        let kin = kinematics(self.previous, ego, accel, self.previous_inputs);
        self.previous = ego;
        self.previous_inputs = Some((accel, kin.yaw_rate));
        let m = StepMetrics {
            road_excess: excess,
            off_road: excess > tolerance,
            straddle: straddles(&b, &self.bounds),
            in_target_lane: self.target.0 <= ego[1] && ego[1] < self.target.1,
            traffic_v,
            slow: is_slow(ego[3], traffic_v),
            slow_planned,
            lead_gap: lead,
            slow_planned_free: slow_planned && road_free(lead, ego[3], traffic_v),
            ttc: min_ttc_ahead(&b, ego[3] * ego[2].cos(), others),
            progress: ego[0] - self.start[0],
            kinematics: kin,
        };
        self.steps.push((m, accel));
        self.states.push(ego);
        let near = nearest(&b, others);
        (m, touching, near)
    }

    /// The run's collision events and metrics, `success` being whether it settled in the
    /// target lane without a collision.
    #[must_use]
    pub fn finish(self, success: bool) -> (Vec<Collision>, RunMetrics) {
        let n = self.steps.len();
        let count =
            |f: &dyn Fn(&StepMetrics) -> bool| self.steps.iter().filter(|(m, _)| f(m)).count();
        let at_fault = self.collisions.iter().filter(|c| c.at_fault).count();
        let min_ttc = self
            .steps
            .iter()
            .filter_map(|(m, _)| m.ttc)
            .fold(None, |best: Option<f64>, t| {
                Some(best.map_or(t, |b| b.min(t)))
            });
        let progress = self.steps.last().map_or(0.0, |(m, _)| m.progress);
        // The last step both the run and the log cover.
        let progress_ratio = (1..=n.min(self.log_x.len()))
            .rev()
            .find_map(|k| self.log_x[k - 1].map(|x| (k, x - self.start[0])))
            .filter(|&(_, logged)| logged >= MIN_LOG_PROGRESS_M)
            .map(|(k, logged)| self.steps[k - 1].0.progress / logged);
        let kin: Vec<Kinematics> = self.steps.iter().map(|(m, _)| m.kinematics).collect();
        let (y_target, side) = self.target_centre;
        let accels: Vec<f64> = self.steps.iter().map(|(_, a)| *a).collect();
        let mut m = RunMetrics {
            collisions_at_fault: at_fault,
            collisions_not_at_fault: self.collisions.len() - at_fault,
            collisions_at_fault_nuplan: self
                .collisions
                .iter()
                .filter(|c| c.nuplan_at_fault)
                .count(),
            start_overhang: self.start_overhang,
            off_road_steps: count(&|m| m.off_road),
            straddle_steps: count(&|m| m.straddle),
            steps_to_lane: self
                .steps
                .iter()
                .position(|(m, _)| m.in_target_lane)
                .map(|k| k + 1),
            slow_steps: count(&|m| m.slow),
            slow_planned_steps: count(&|m| m.slow_planned),
            slow_planned_free_steps: count(&|m| m.slow_planned_free),
            min_ttc,
            progress,
            progress_ratio,
            comfort: Comfort::of(&kin, &accels),
            max_abs_heading: self.states.iter().fold(0.0, |m, z| m.max(z[2].abs())),
            max_overshoot: self
                .states
                .iter()
                .fold(0.0, |m, z| m.max((z[1] - y_target) * side)),
            free_gap: self.free_gap,
            score: 0.0,
        };
        m.score = score(&m, success, n);
        (self.collisions, m)
    }
}

#[cfg(test)]
#[path = "metrics_tests.rs"]
mod tests;
