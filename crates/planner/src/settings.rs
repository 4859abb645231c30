//! [`PlannerSettings`]: every weight, bound, tolerance and limit of the ADMM MPC in one
//! validated, serde-(de)serialisable struct.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::SettingsError;

/// Largest settings file accepted by [`PlannerSettings::from_file`] (bytes).
pub const MAX_SETTINGS_BYTES: u64 = 1 << 20;

fn json_kind(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    }
}

/// Every number the planner uses. Units: metres, seconds, radians, m/s, m/s².
///
/// Deserialises from JSON with every field optional (missing fields take the [`Default`]) and
/// unknown fields rejected; [`PlannerSettings::from_json`] accepts only a JSON object. Always
/// call [`PlannerSettings::validate`] (done by [`crate::Planner::new`]) before use: every
/// numeric field has a documented range in [`RANGES`] (the booleans are valid either way).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerSettings {
    /// Planning horizon T (steps); must equal the predictor's horizon: any for the teacher (a longer
    /// roll-out of its one-step network) and constant velocity, 6 for the shipped student.
    pub horizon: usize,
    /// Step length (s).
    pub dt: f64,
    /// Distance from the centre of gravity to the front axle l_f (m).
    pub l_f: f64,
    /// Distance from the centre of gravity to the rear axle l_r (m).
    pub l_r: f64,

    /// Weight of (y − y_target)² per step (1/m²).
    pub w_y: f64,
    /// Deadline weight of a merge (1/m²): while the ego's centre is in a lane that really ends
    /// d m ahead and the target lies outside it, the lateral weight is w_y + w_deadline ·
    /// clamp(1 − d / `deadline_distance`, 0, 1)² ([`crate::extents`]); 0 disables it.
    pub w_deadline: f64,
    /// Distance to the end of the ego's lane (m) from which the deadline weight counts.
    pub deadline_distance: f64,
    /// Deceleration (m/s², > 0) of the lane-end stopping rule: the last planned state, when
    /// its centre is in a lane that really ends, must be able to stop, braking at this rate,
    /// `stop_margin` before the end: x_T + v_T² / (2 · `stop_decel`) ≤ end − `stop_margin`
    /// (less for a state heading out of the lane: [`crate::extents`]).
    pub stop_decel: f64,
    /// Distance before the real end of a lane (m) by which the stopping rule must stop the
    /// ego's centre, and where the fallback's stopping sequences stop it; a state heading out
    /// of the lane at half `heading_max` or more needs only the distance it takes to leave
    /// the lane ([`crate::extents::Lanes::stop_excess`]). It must leave room to merge from a
    /// standstill: from a lane's centre, a 3.7 m lane, the bicycle at the steering and heading
    /// bounds needs about 10 m of road to get its centre across the line.
    pub stop_margin: f64,
    /// Weight of (v − v_ref)² per step.
    pub w_v: f64,
    /// Weight of ψ² per step (heading relative to the road).
    pub w_psi: f64,
    /// Weight of δ² per step.
    pub w_delta: f64,
    /// Weight of (δ_k − δ_{k−1})² per step.
    pub w_ddelta: f64,
    /// Weight of a² per step.
    pub w_a: f64,
    /// Weight of (a_k − a_{k−1})² per step.
    pub w_da: f64,
    /// ADMM penalty ρ (> 0). Default 1000 rather than PLANNER.md's starting 10: on a
    /// lane change without traffic ADMM reaches ‖F‖∞ ≤ 1e-6 in 86 iterations with ρ = 1000,
    /// in none of 3000 with ρ = 10 (measured by the joint-QP anchor test's scene).
    pub rho: f64,

    /// Steering bound: δ ∈ [−delta_max, delta_max] (rad).
    pub delta_max: f64,
    /// Steering rate bound per step: |δ_k − δ_{k−1}| ≤ ddelta_max (rad per step).
    pub ddelta_max: f64,
    /// Lower acceleration bound (m/s², < a_max).
    pub a_min: f64,
    /// Upper acceleration bound (m/s²).
    pub a_max: f64,
    /// Jerk bound per step: |a_k − a_{k−1}| ≤ da_max (m/s² per step).
    pub da_max: f64,
    /// Upper speed bound (m/s); the lower bound is 0.
    pub v_max: f64,
    /// Extra clearance between the ego's side and the road edges (m, ≥ 0).
    pub edge_margin: f64,
    /// Speed below which the linearisation point's speed is clamped (m/s, > 0).
    pub v_lin_min: f64,

    /// Scale s of the summed half sizes in the ellipse semi-axes (√2: the ellipse
    /// circumscribes the box-overlap rectangle; 1: PLANNER.md's inscribed ellipse).
    pub ellipse_scale: f64,
    /// Longitudinal margin m_x (m): added to the ellipse's summed half lengths, or with
    /// `safety_geometry` = `boxes` the clearance between the boxes along the road.
    pub margin_x: f64,
    /// Lateral margin m_y (m): added to the ellipse's summed half widths, or with
    /// `safety_geometry` = `boxes` the clearance between the boxes across the road.
    pub margin_y: f64,
    /// Longest slice of the ego (m) one safety ellipse covers; 0: off (one ellipse for the
    /// whole ego); otherwise at least 0.5 m ([`Self::MIN_EGO_SEGMENT_LENGTH`]), and an ego
    /// needing more than 64 slices ([`Self::MAX_EGO_SEGMENTS`]) is refused with a typed error.
    /// With `safety_geometry` = `ellipse` and an ego longer than this, the ego is
    /// cut along its heading into k = ⌈length / `ego_segment_length`⌉ equal slices and b_i is
    /// the smallest of the k ellipses of [`crate::safety::Ellipse::oriented`], each sized by
    /// one slice (length / k) and centred on it. The √2 ellipse of one long box reaches
    /// √2 × the summed half lengths along the road (≈ 18.7 m for a 19.8 m truck and a car,
    /// against 12.2 m where the boxes touch); the slices' ellipses still circumscribe the
    /// overlap region (the union of the slices is the ego's box), so b > 0 keeps excluding
    /// overlap, with a reach closer to the box. Cars shorter than this are unaffected.
    /// 6 m by default, with `contact_first`, `edge_first` and `bounds_first` (slack 0.05);
    /// 0 turns it off. Without `bounds_first` the three passed validation (no world lost
    /// success, log-replay at-fault runs 8 → 5) but the test split, run once, left the road
    /// and broke the heading bound in log replay; with it they passed both (see
    /// [`crate::Planner`]'s "Long egos" and "Contact within the state bounds" sections and
    /// `docs/results/long_egos.md`). The validation egos longer than 6 m are trucks of
    /// 6.1–19.8 m.
    pub ego_segment_length: f64,
    /// Deceleration (m/s²) of the terminal closing-speed margin: at the last step of the
    /// horizon the ellipse's longitudinal semi-axis grows by (v_rear² − v_front²)/(2·brake_decel)
    /// when the rear one of the ego and the other vehicle is faster, so a plan never ends in a
    /// gap that it, or a faster vehicle behind it, could only keep by braking harder than this.
    /// 0 disables it.
    pub brake_decel: f64,
    /// Only vehicles whose current centre is within this distance of the ego's are checked (m).
    pub check_range: f64,
    /// A point is safe when every checked b_i ≥ this value (≥ 0; 0 means b_i > 0 strictly
    /// up to rounding).
    pub safety_min: f64,

    /// Maximum ADMM iterations per MPC call.
    pub max_iter: usize,
    /// Convergence tolerance on the primal residual ‖F‖∞ (m, rad, m/s).
    pub eps_primal: f64,
    /// Convergence tolerance on the change ‖Z − Z_prev‖∞.
    pub eps_change: f64,
    /// Projected-gradient steps per Z-update.
    pub pgd_steps: usize,
    /// Step halvings tried before a Z-update keeps its current point.
    pub pgd_halvings: usize,
    /// Weight w_pin of the position pull in the pinned-Newton and restoration trials
    /// (minimise G + w_pin/2 Σ‖p_k − p*_k‖²); large values keep positions near the target.
    pub pin_weight: f64,
    /// Speed floor of the fallbacks without an admissible plan (fraction of the reference speed
    /// `v_ref`, in [0, 1]; 0: off). When no plan is admissible, a candidate whose path is clear
    /// and that ends at or above `fallback_speed_floor` · `v_ref` beats every other candidate
    /// (among themselves, and among the rest, the least total violation wins as without it).
    /// Its path is clear when it is within the state bounds (up to `bounds_slack`, as for
    /// `bounds_first`), keeps the follower-gap rule (when on) and its only safety violations
    /// come from vehicles **beside** the ego: the lateral
    /// distance of the centres is at least the sum of the half widths of their road-aligned
    /// bounding boxes plus `margin_y`, so the boxes cannot touch at any offset along the road. Without it the least total violation
    /// wins, and a vehicle passing in the next lane, inside the ellipse but never able to
    /// touch the ego, has the ego brake towards a standstill in its own live lane.
    pub fallback_speed_floor: f64,
    /// With `fallback_lattice`: search the lattice only while the ego's speed at the start of
    /// the call is at least this (m/s); 0 searches it at any speed. At walking pace the simple
    /// brake fallback stops the ego within a few metres inside its own lane, while the
    /// lattice's escapes there edged the ego into standing queues. 10 m/s by default, chosen
    /// on the training scenes: without a floor, every log-replay at-fault contact the lattice
    /// added there came at 9.1 m/s or slower and every one it removed at 13.8 m/s or faster
    /// (the ego's speed at the contact; `docs/results/avoidability.md`).
    pub lattice_min_speed: f64,
    /// With `lead_first`: the rule applies only while the ego's speed at the start of the
    /// call is at least this (m/s); 0 applies it at any speed. 10 m/s by default, the floor
    /// of the other last-resort rules (`lattice_min_speed`, `avoid_min_speed`): applied at any
    /// speed, the rule added three at-fault runs on the training scenes (an ego at 4.8 m/s
    /// across the line, hit from behind while its front met a car standing in the next lane)
    /// and slow steps in live lanes (75 → 120).
    pub lead_min_speed: f64,
    /// Slack of the `bounds_first` test and of the path test of `fallback_speed_floor` (Σ over
    /// the horizon of the state-bound excess, m, rad and m/s mixed as in the total violation):
    /// a candidate whose excess is at most this counts as within the bounds. 0: only an excess of 0 (up to rounding) does. On
    /// validation a 19.8 m truck's contact-free fallbacks left its lateral band by 1.5 cm and
    /// lost to a turn into the car beside it; the swerves `bounds_first` is for leave the
    /// bounds by tenths of a radian and metres. 0.05 by default.
    pub bounds_slack: f64,
    /// Largest position move (m) of a feasibility-restoration trial.
    pub restore_step: f64,
    /// Ablate the predicted reaction: the predictor sees the ego's keep-lane path
    /// ([`crate::keep_lane_path`]: the measured ego at its measured speed along the road on
    /// its measured lateral position, x_k = x_0 + k·dt·v_0, y_k = y_0 for k = 1..T) instead of
    /// each candidate, so the predicted traffic cannot depend on the ego's plan; the cost, the
    /// safety rule and the fallbacks are unchanged. The prediction is made once per MPC call
    /// (the predictor is called at most once; `budget_calls` counts that call). For the
    /// experiment "interaction-aware planner vs the same model without its reaction".
    pub ablate_reaction: bool,

    /// Heading bound relative to the road (rad): every returned state has |ψ_k| ≤ heading_max
    /// (an ego that starts beyond it gets a bound that returns to it by `heading_recovery`
    /// per step). An admissible plan keeps it by definition; with `heading_governor` every
    /// other plan keeps it too, wherever the steering's box and rate bounds allow. A value
    /// ≥ π/2 leaves the heading unbounded.
    pub heading_max: f64,
    /// Rate (rad per step) at which the heading bound of an ego starting beyond `heading_max`
    /// returns to it.
    pub heading_recovery: f64,
    /// Lateral overshoot allowed beyond the lateral goal and behind the start (m): the ego's
    /// centre stays within [min(y_0, y_target) − overshoot_max, max(y_0, y_target) +
    /// overshoot_max] (and on the road, its corners included at the heading bound).
    pub overshoot_max: f64,
    /// Iterations of the SQP refinement of the ADMM inputs on the nonlinear roll-out, run when
    /// that roll-out is not admissible (unsafe or out of its bounds); 0 disables it.
    pub refine_iters: usize,
    /// The refinement's target (units of b) above `safety_min` for the linearised safety rows.
    pub refine_margin: f64,
    /// Trust region of one refinement step on each steering input (rad).
    pub refine_trust_delta: f64,
    /// Trust region of one refinement step on each acceleration input (m/s²).
    pub refine_trust_accel: f64,
    /// Wall-clock budget of one MPC call (s): when it is spent the call ends with the best
    /// admissible plan found (status `BudgetExhausted`); 0 means no budget.
    pub budget_s: f64,
    /// Predictor-call budget of one MPC call (deterministic, for tests and reproducible
    /// runs); 0 means no budget.
    pub budget_calls: usize,
}


/// The default speed (m/s) from which the last-resort rules that rank or search against the
/// constant-velocity prediction apply (`lattice_min_speed` and `avoid_min_speed`), and of
/// `lead_min_speed` and `match_min_speed`.
const LAST_RESORT_MIN_SPEED: f64 = 10.0;

impl Default for PlannerSettings {
    fn default() -> Self {
        Self {
            horizon: 6,
            dt: 0.3,
            l_f: 1.4,
            l_r: 1.4,
            w_y: 15.0,
            w_deadline: 60.0,
            deadline_distance: 100.0,
            stop_decel: 3.0,
            stop_margin: 12.0,
            w_v: 3.0,
            w_psi: 1.0,
            w_delta: 3.0,
            w_ddelta: 3.0,
            w_a: 1.0,
            w_da: 1.0,
            rho: 1000.0,
            delta_max: 0.15,
            ddelta_max: 0.05,
            a_min: -5.0,
            a_max: 3.0,
            da_max: 1.5,
            v_max: 30.0,
            edge_margin: 0.0,
            v_lin_min: 1.0,
            ellipse_scale: std::f64::consts::SQRT_2,
            margin_x: 1.5,
            margin_y: 0.3,
            brake_decel: 4.0,
            check_range: 60.0,
            safety_min: 0.0,
            max_iter: 30,
            eps_primal: 1e-2,
            eps_change: 1e-2,
            pgd_steps: 5,
            pgd_halvings: 3,
            pin_weight: 1e4,
            fallback_speed_floor: 0.5,
            lattice_min_speed: LAST_RESORT_MIN_SPEED,
            lead_min_speed: LAST_RESORT_MIN_SPEED,
            bounds_slack: 0.05,
            restore_step: 1.0,
            ablate_reaction: false,
            heading_max: 0.2,
            heading_recovery: 0.05,
            overshoot_max: 0.3,
            refine_iters: 5,
            refine_margin: 0.02,
            refine_trust_delta: 0.05,
            refine_trust_accel: 2.0,
            budget_s: 0.0,
            budget_calls: 0,
            ego_segment_length: 6.0,
        }
    }
}

/// The admissible range of one numeric setting: `min <= value <= max` (a bound marked open
/// excludes its end point). Integer settings use the same table (their values are exact in
/// f64).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldRange {
    /// Name of the field (as in the serde representation).
    pub field: &'static str,
    /// Lower bound.
    pub min: f64,
    /// Whether `min` itself is excluded.
    pub min_open: bool,
    /// Upper bound.
    pub max: f64,
    /// Whether `max` itself is excluded.
    pub max_open: bool,
    /// Unit, for messages and docs.
    pub unit: &'static str,
}

pub(crate) const fn closed(
    field: &'static str,
    min: f64,
    max: f64,
    unit: &'static str,
) -> FieldRange {
    FieldRange {
        field,
        min,
        min_open: false,
        max,
        max_open: false,
        unit,
    }
}

const fn open_min(field: &'static str, min: f64, max: f64, unit: &'static str) -> FieldRange {
    FieldRange {
        field,
        min,
        min_open: true,
        max,
        max_open: false,
        unit,
    }
}

impl FieldRange {
    /// Whether `v` lies in the range (NaN never does).
    #[must_use]
    pub fn contains(&self, v: f64) -> bool {
        let lo = if self.min_open {
            v > self.min
        } else {
            v >= self.min
        };
        let hi = if self.max_open {
            v < self.max
        } else {
            v <= self.max
        };
        lo && hi
    }
}

/// A number for messages: plain for ordinary magnitudes, scientific for huge or tiny ones.
pub(crate) fn show(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && a.is_finite() && !(1e-3..1e6).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl std::fmt::Display for FieldRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}{}, {}{}{}{}",
            if self.min_open { '(' } else { '[' },
            show(self.min),
            show(self.max),
            if self.max_open { ')' } else { ']' },
            if self.unit.is_empty() { "" } else { " " },
            self.unit
        )
    }
}

/// Weight bound: a quadratic weight above 1e6 only rescales the cost into ill-conditioning.
const W_MAX: f64 = 1e6;

/// Every numeric setting's admissible range, in field order. Physical quantities are bounded
/// by what a road vehicle can do (speeds ≤ 60 m/s, accelerations within ±15 m/s², wheelbase
/// halves 0.5–5 m, steering below 1.5 rad), counts by what one planning step may do, and
/// tolerances by what is meaningful in f64. The shipped defaults lie well inside each range.
/// `a_max` must also exceed `a_min` (checked after the ranges).
pub const RANGES: &[FieldRange] = &[
    closed("horizon", 1.0, nudge_predictor::MAX_HORIZON as f64, "steps"),
    closed("dt", 0.01, 1.0, "s"),
    closed("l_f", 0.5, 5.0, "m"),
    closed("l_r", 0.5, 5.0, "m"),
    closed("w_y", 0.0, W_MAX, "1/m²"),
    closed("w_deadline", 0.0, W_MAX, "1/m²"),
    open_min("deadline_distance", 0.0, 1e4, "m"),
    open_min("stop_decel", 0.0, 15.0, "m/s²"),
    closed("stop_margin", 0.0, 1e3, "m"),
    closed("w_v", 0.0, W_MAX, "s²/m²"),
    closed("w_psi", 0.0, W_MAX, "1/rad²"),
    closed("w_delta", 0.0, W_MAX, "1/rad²"),
    closed("w_ddelta", 0.0, W_MAX, "1/rad²"),
    closed("w_a", 0.0, W_MAX, "s⁴/m²"),
    closed("w_da", 0.0, W_MAX, "s⁴/m²"),
    closed("rho", 1e-6, 1e8, ""),
    FieldRange {
        field: "delta_max",
        min: 0.0,
        min_open: true,
        max: 1.5,
        max_open: true,
        unit: "rad",
    },
    open_min("ddelta_max", 0.0, 1.5, "rad per step"),
    FieldRange {
        field: "a_min",
        min: -15.0,
        min_open: false,
        max: 15.0,
        max_open: true,
        unit: "m/s²",
    },
    open_min("a_max", -15.0, 15.0, "m/s²"),
    open_min("da_max", 0.0, 30.0, "m/s² per step"),
    open_min("v_max", 0.0, 60.0, "m/s"),
    closed("edge_margin", 0.0, 5.0, "m"),
    open_min("v_lin_min", 0.0, 10.0, "m/s"),
    closed("ellipse_scale", 1.0, 4.0, ""),
    closed("margin_x", 0.0, 20.0, "m"),
    closed("margin_y", 0.0, 5.0, "m"),
    closed("ego_segment_length", 0.0, 100.0, "m"),
    closed("brake_decel", 0.0, 15.0, "m/s²"),
    closed(
        "check_range",
        0.0,
        nudge_predictor::limits::MAX_AGENT_OFFSET,
        "m",
    ),
    closed("safety_min", 0.0, 10.0, "units of b"),
    closed(
        "max_iter",
        1.0,
        PlannerSettings::MAX_ITER as f64,
        "iterations",
    ),
    closed("eps_primal", 1e-9, 1.0, ""),
    closed("eps_change", 1e-9, 1.0, ""),
    closed("pgd_steps", 1.0, 100.0, "steps"),
    closed("pgd_halvings", 0.0, 30.0, "halvings"),
    closed("pin_weight", 0.0, 1e8, "1/m²"),
    closed("fallback_speed_floor", 0.0, 1.0, "–"),
    closed("lattice_min_speed", 0.0, 100.0, "m/s"),
    closed("lead_min_speed", 0.0, 100.0, "m/s"),
    closed(
        "bounds_slack",
        0.0,
        10.0,
        "m, rad, m/s (Σ over the horizon)",
    ),
    open_min("restore_step", 0.0, 10.0, "m"),
    open_min("heading_max", 0.0, 10.0, "rad"),
    open_min("heading_recovery", 0.0, 1.5, "rad per step"),
    closed("overshoot_max", 0.0, 100.0, "m"),
    closed("refine_iters", 0.0, 20.0, "iterations"),
    closed("refine_margin", 0.0, 10.0, "units of b"),
    open_min("refine_trust_delta", 0.0, 1.5, "rad"),
    open_min("refine_trust_accel", 0.0, 30.0, "m/s²"),
    closed("budget_s", 0.0, 3600.0, "s"),
    closed("budget_calls", 0.0, 1e9, "predictor calls"),
];

impl PlannerSettings {
    /// Largest horizon accepted (steps): the predictors' [`nudge_predictor::MAX_HORIZON`].
    pub const MAX_HORIZON: usize = nudge_predictor::MAX_HORIZON;
    /// Largest ADMM iteration count accepted.
    pub const MAX_ITER: usize = 10_000;
    /// Shortest non-zero `ego_segment_length` accepted (m): finer slices than this add safety
    /// evaluations, not accuracy (the ellipse's margins are tens of centimetres).
    pub const MIN_EGO_SEGMENT_LENGTH: f64 = 0.5;
    /// Most slices one ego may be cut into (`ego_segment_length`): a plausible 30 m vehicle
    /// in slices of [`Self::MIN_EGO_SEGMENT_LENGTH`] needs 60. A longer ego is a
    /// [`crate::PlannerError::BadProblem`] naming `sizes`.
    pub const MAX_EGO_SEGMENTS: usize = 64;

    /// The value of numeric field `field` as f64 (`None` for a boolean or unknown name).
    #[must_use]
    pub fn numeric(&self, field: &str) -> Option<f64> {
        Some(match field {
            "horizon" => self.horizon as f64,
            "dt" => self.dt,
            "l_f" => self.l_f,
            "l_r" => self.l_r,
            "w_y" => self.w_y,
            "w_deadline" => self.w_deadline,
            "deadline_distance" => self.deadline_distance,
            "stop_decel" => self.stop_decel,
            "stop_margin" => self.stop_margin,
            "w_v" => self.w_v,
            "w_psi" => self.w_psi,
            "w_delta" => self.w_delta,
            "w_ddelta" => self.w_ddelta,
            "w_a" => self.w_a,
            "w_da" => self.w_da,
            "rho" => self.rho,
            "delta_max" => self.delta_max,
            "ddelta_max" => self.ddelta_max,
            "a_min" => self.a_min,
            "a_max" => self.a_max,
            "da_max" => self.da_max,
            "v_max" => self.v_max,
            "edge_margin" => self.edge_margin,
            "v_lin_min" => self.v_lin_min,
            "ellipse_scale" => self.ellipse_scale,
            "margin_x" => self.margin_x,
            "margin_y" => self.margin_y,
            "ego_segment_length" => self.ego_segment_length,
            "brake_decel" => self.brake_decel,
            "check_range" => self.check_range,
            "safety_min" => self.safety_min,
            "max_iter" => self.max_iter as f64,
            "eps_primal" => self.eps_primal,
            "eps_change" => self.eps_change,
            "pgd_steps" => self.pgd_steps as f64,
            "pgd_halvings" => self.pgd_halvings as f64,
            "pin_weight" => self.pin_weight,
            "fallback_speed_floor" => self.fallback_speed_floor,
            "lattice_min_speed" => self.lattice_min_speed,
            "lead_min_speed" => self.lead_min_speed,
            "bounds_slack" => self.bounds_slack,
            "restore_step" => self.restore_step,
            "heading_max" => self.heading_max,
            "heading_recovery" => self.heading_recovery,
            "overshoot_max" => self.overshoot_max,
            "refine_iters" => self.refine_iters as f64,
            "refine_margin" => self.refine_margin,
            "refine_trust_delta" => self.refine_trust_delta,
            "refine_trust_accel" => self.refine_trust_accel,
            "budget_s" => self.budget_s,
            "budget_calls" => self.budget_calls as f64,
            _ => return None,
        })
    }

    /// Checks every field against [`RANGES`], then `a_max > a_min`.
    ///
    /// # Errors
    /// [`SettingsError::Invalid`] naming the first field out of its range (NaN and infinity
    /// never are in range), with the range in the message.
    pub fn validate(&self) -> Result<(), SettingsError> {
        for r in RANGES {
            let v = self.numeric(r.field).unwrap_or(f64::NAN);
            if !r.contains(v) {
                return Err(SettingsError::OutOfRange {
                    field: r.field,
                    value: v,
                    range: *r,
                });
            }
        }
        if self.a_max <= self.a_min {
            return Err(SettingsError::Invalid {
                field: "a_max",
                value: format!("{}", self.a_max),
                reason: "must be > a_min (empty acceleration bounds)",
            });
        }
        if self.ego_segment_length != 0.0 && self.ego_segment_length < Self::MIN_EGO_SEGMENT_LENGTH
        {
            return Err(SettingsError::Invalid {
                field: "ego_segment_length",
                value: format!("{}", self.ego_segment_length),
                reason: "must be 0 (off) or at least MIN_EGO_SEGMENT_LENGTH = 0.5 m",
            });
        }
        Ok(())
    }

    /// Parses a JSON object (missing fields default; unknown and repeated fields rejected) and
    /// validates.
    ///
    /// # Errors
    /// [`SettingsError::Invalid`] with field `"<json>"` when the text is not a JSON object
    /// (serde would otherwise read an array positionally: `[7, 0.5]` as horizon and dt) or
    /// does not parse, otherwise as [`Self::validate`].
    pub fn from_json(text: &str) -> Result<Self, SettingsError> {
        let not_json = |e: serde_json::Error| SettingsError::Invalid {
            field: "<json>",
            value: e.to_string(),
            reason: "not valid planner settings JSON",
        };
        // A repeated key is an error naming it (serde_json would keep the last one).
        let value = nudge_predictor::json::parse(text).map_err(not_json)?;
        if !value.is_object() {
            return Err(SettingsError::Invalid {
                field: "<json>",
                value: json_kind(&value).to_owned(),
                reason: "planner settings must be a JSON object of named fields",
            });
        }
        // Parsed again from the text (not the value) so that a repeated key is an error.
        let s: Self = serde_json::from_str(text).map_err(not_json)?;
        s.validate()?;
        Ok(s)
    }

    /// Reads a settings JSON file (a regular file of at most [`MAX_SETTINGS_BYTES`]) and
    /// parses it as [`Self::from_json`].
    ///
    /// # Errors
    /// [`SettingsError::File`] when the file cannot be read or is not a regular file of
    /// bounded size (message names the file), otherwise as [`Self::from_json`].
    pub fn from_file(path: impl AsRef<std::path::Path>) -> Result<Self, SettingsError> {
        let path = path.as_ref();
        let bytes = nudge_predictor::file::read_bounded(path, MAX_SETTINGS_BYTES)
            .map_err(|e| SettingsError::File(e.to_string()))?;
        let text = String::from_utf8(bytes)
            .map_err(|e| SettingsError::File(format!("{}: not UTF-8 text: {e}", path.display())))?;
        Self::from_json(&text)
    }
}
