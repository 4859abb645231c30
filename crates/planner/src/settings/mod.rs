//! [`PlannerSettings`]: every weight, bound, tolerance and limit of the ADMM MPC, grouped by
//! the phase of the MPC call that uses it, validated, serde-(de)serialisable.
//!
//! Each group is declared once, a line per field ([`settings_struct!`](crate::settings_struct)): the struct, its
//! default, its range table and its value lookup all come from that declaration, and
//! `docs/reference/settings.md` is generated from it (`nudge settings --format markdown`).
//! In JSON the groups are nested objects (`{"cost": {"w_y": 20}}`); every field may be
//! left out (it takes its default), unknown fields are refused, and a key of the flat
//! settings of earlier versions is refused with a message naming where it moved or why it
//! was removed ([`MOVED`], [`REMOVED`]).

pub mod schema;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::SettingsError;
use crate::settings_struct;
pub use schema::{FieldRange, FieldSpec, show};
use schema::{closed, first_out_of_range, open, open_max, open_min};

/// Largest settings file accepted by [`PlannerSettings::from_file`] (bytes).
pub const MAX_SETTINGS_BYTES: u64 = 1 << 20;

/// Upper bound of every cost weight.
const W_MAX: f64 = 1e6;

/// The default speed (m/s) from which the last-resort rules of the fallback apply
/// (`repair.lattice_min_speed`, `repair.lead_min_speed`).
const LAST_RESORT_MIN_SPEED: f64 = 10.0;

settings_struct! {
    /// The vehicle model and the discretisation.
    pub struct ModelSettings("model.") {
        /// Planning horizon T (steps); must equal the predictor's (6 for the shipped student).
        horizon: usize = 6, closed(1.0, nudge_predictor::MAX_HORIZON as f64, "steps");
        /// Step length (s).
        dt: f64 = 0.3, closed(0.01, 1.0, "s");
        /// Distance from the centre of gravity to the front axle l_f (m).
        l_f: f64 = 1.4, closed(0.5, 5.0, "m");
        /// Distance from the centre of gravity to the rear axle l_r (m).
        l_r: f64 = 1.4, closed(0.5, 5.0, "m");
    }
}

settings_struct! {
    /// The weights of the cost J = Φ1(Δ) + Φ2(α) + Φ3(Z), per step.
    pub struct CostSettings("cost.") {
        /// Weight of (y − y_target)² (1/m²).
        w_y: f64 = 15.0, closed(0.0, W_MAX, "1/m²");
        /// Weight of (v − v_ref)² (s²/m²).
        w_v: f64 = 3.0, closed(0.0, W_MAX, "s²/m²");
        /// Weight of ψ², the heading relative to the road (1/rad²).
        w_psi: f64 = 1.0, closed(0.0, W_MAX, "1/rad²");
        /// Weight of δ² (1/rad²).
        w_delta: f64 = 3.0, closed(0.0, W_MAX, "1/rad²");
        /// Weight of (δ_k − δ_{k−1})² (1/rad²).
        w_ddelta: f64 = 3.0, closed(0.0, W_MAX, "1/rad²");
        /// Weight of a² (s⁴/m²).
        w_a: f64 = 1.0, closed(0.0, W_MAX, "s⁴/m²");
        /// Weight of (a_k − a_{k−1})² (s⁴/m²).
        w_da: f64 = 1.0, closed(0.0, W_MAX, "s⁴/m²");
    }
}

settings_struct! {
    /// The input and state bounds every plan keeps.
    pub struct BoundSettings("bounds.") {
        /// Steering bound: |δ| ≤ delta_max (rad).
        delta_max: f64 = 0.15, open(0.0, 1.5, "rad");
        /// Steering rate bound: |δ_k − δ_{k−1}| ≤ ddelta_max (rad per step).
        ddelta_max: f64 = 0.05, open_min(0.0, 1.5, "rad per step");
        /// Lower acceleration bound (m/s², below `a_max`).
        a_min: f64 = -5.0, open_max(-15.0, 15.0, "m/s²");
        /// Upper acceleration bound (m/s²).
        a_max: f64 = 3.0, open_min(-15.0, 15.0, "m/s²");
        /// Jerk bound: |a_k − a_{k−1}| ≤ da_max (m/s² per step).
        da_max: f64 = 1.5, open_min(0.0, 30.0, "m/s² per step");
        /// Upper speed bound (m/s); the lower bound is 0.
        v_max: f64 = 30.0, open_min(0.0, 60.0, "m/s");
        /// Extra clearance between the ego's side and the road's edges (m).
        edge_margin: f64 = 0.0, closed(0.0, 5.0, "m");
        /// Heading bound relative to the road (rad); π/2 or more leaves the heading unbounded.
        heading_max: f64 = 0.2, open_min(0.0, 10.0, "rad");
        /// Rate at which the bound of an ego starting beyond `heading_max` returns to it
        /// (rad per step).
        heading_recovery: f64 = 0.05, open_min(0.0, 1.5, "rad per step");
        /// Lateral overshoot allowed beyond the lateral goal and behind the start (m).
        overshoot_max: f64 = 0.3, closed(0.0, 100.0, "m");
    }
}

settings_struct! {
    /// The safety constraint b_i: the inflated ellipse between the ego and each checked vehicle.
    pub struct SafetySettings("safety.") {
        /// Scale s of the summed half sizes in the ellipse's semi-axes (√2 circumscribes the
        /// box-overlap rectangle).
        ellipse_scale: f64 = std::f64::consts::SQRT_2, closed(1.0, 4.0, "");
        /// Margin added to the ellipse's semi-axis along the road (m).
        margin_x: f64 = 1.5, closed(0.0, 20.0, "m");
        /// Margin added to the ellipse's semi-axis across the road (m).
        margin_y: f64 = 0.3, closed(0.0, 5.0, "m");
        /// Longest slice of the ego one ellipse covers (m; 0: one ellipse for the whole ego,
        /// else at least 0.5).
        ego_segment_length: f64 = 6.0, closed(0.0, 100.0, "m");
        /// Deceleration of the terminal closing-speed margin (m/s²; 0 disables it).
        brake_decel: f64 = 4.0, closed(0.0, 15.0, "m/s²");
        /// Only vehicles within this distance of the ego are checked (m).
        check_range: f64 = 60.0, closed(0.0, nudge_predictor::limits::MAX_AGENT_OFFSET, "m");
        /// A point is safe when every checked b_i exceeds this (units of b).
        safety_min: f64 = 0.0, closed(0.0, 10.0, "units of b");
        /// Ablate the predicted reaction: the predictor sees the ego's keep-lane path instead of
        /// each candidate (the control of the interaction experiments).
        ablate_reaction: bool = false, schema::any();
    }
}

settings_struct! {
    /// The ADMM loop and its Z-update.
    pub struct AdmmSettings("admm.") {
        /// ADMM penalty ρ.
        rho: f64 = 1000.0, closed(1e-6, 1e8, "");
        /// Most ADMM iterations per MPC call.
        max_iter: usize = 30, closed(1.0, PlannerSettings::MAX_ITER as f64, "iterations");
        /// Convergence tolerance on the primal residual ‖F‖∞ (m, rad, m/s).
        eps_primal: f64 = 1e-2, closed(1e-9, 1.0, "");
        /// Convergence tolerance on the change ‖Z − Z_prev‖∞.
        eps_change: f64 = 1e-2, closed(1e-9, 1.0, "");
        /// Descent steps per Z-update.
        pgd_steps: usize = 5, closed(1.0, 100.0, "steps");
        /// Step halvings tried before a Z-update keeps its point.
        pgd_halvings: usize = 3, closed(0.0, 30.0, "halvings");
        /// Weight of the position pull in the pinned-Newton and restoration trials (1/m²).
        pin_weight: f64 = 1e4, closed(0.0, 1e8, "1/m²");
        /// Largest position move of a feasibility-restoration trial (m).
        restore_step: f64 = 1.0, open_min(0.0, 10.0, "m");
        /// Speed below which the linearisation point's speed is clamped (m/s).
        v_lin_min: f64 = 1.0, open_min(0.0, 10.0, "m/s");
    }
}

settings_struct! {
    /// The repairs of an inadmissible ADMM roll-out: refinement and the fallback's ranking.
    pub struct RepairSettings("repair.") {
        /// SQP refinement steps on the nonlinear roll-out (0 disables the refinement).
        refine_iters: usize = 5, closed(0.0, 20.0, "iterations");
        /// The refinement's target above `safety_min` for the linearised safety rows
        /// (units of b).
        refine_margin: f64 = 0.02, closed(0.0, 10.0, "units of b");
        /// Trust region of one refinement step on each steering input (rad).
        refine_trust_delta: f64 = 0.05, open_min(0.0, 1.5, "rad");
        /// Trust region of one refinement step on each acceleration input (m/s²).
        refine_trust_accel: f64 = 2.0, open_min(0.0, 30.0, "m/s²");
        /// Speed floor of the clear-path rank key, a fraction of v_ref (0 disables the key).
        fallback_speed_floor: f64 = 0.5, closed(0.0, 1.0, "–");
        /// State-bound excess that still counts as within the bounds (Σ over the horizon;
        /// m, rad, m/s).
        bounds_slack: f64 = 0.05, closed(0.0, 10.0, "m, rad, m/s (Σ over the horizon)");
        /// Speed from which the input lattice is searched when nothing is admissible (m/s).
        lattice_min_speed: f64 = LAST_RESORT_MIN_SPEED, closed(0.0, 100.0, "m/s");
        /// Speed from which the lead rule ranks fallbacks (keep the lane, then the violation
        /// ahead) (m/s).
        lead_min_speed: f64 = LAST_RESORT_MIN_SPEED, closed(0.0, 100.0, "m/s");
    }
}

settings_struct! {
    /// The work budget of one MPC call.
    pub struct BudgetSettings("budget.") {
        /// Wall-clock budget of one MPC call (s; 0: the cap `PlannerSettings::MAX_SECONDS`,
        /// which every call keeps whatever the other settings; timing-dependent once it binds).
        seconds: f64 = 0.0, closed(0.0, PlannerSettings::MAX_SECONDS, "s");
        /// Predictor-call budget of one MPC call (deterministic; 0: the cap
        /// `PlannerSettings::MAX_CALLS`, which every call keeps whatever the other settings).
        calls: usize = 0, closed(0.0, PlannerSettings::MAX_CALLS as f64, "predictor calls");
    }
}

settings_struct! {
    /// Lanes that end: the merge deadline in the cost and the stopping rule.
    pub struct LaneEndSettings("lane_ends.") {
        /// Deadline weight of a merge (1/m²; 0 disables it): the lateral weight grows towards
        /// the real end of the ego's lane.
        w_deadline: f64 = 60.0, closed(0.0, W_MAX, "1/m²");
        /// Distance to the end of the ego's lane from which the deadline weight counts (m).
        deadline_distance: f64 = 100.0, open_min(0.0, 1e4, "m");
        /// Deceleration of the stopping rule (m/s²).
        stop_decel: f64 = 3.0, open_min(0.0, 15.0, "m/s²");
        /// Distance before the real end of a lane by which the ego's centre must stop (m).
        stop_margin: f64 = 12.0, closed(0.0, 1e3, "m");
    }
}

/// Every number the planner uses, grouped by the phase that uses it. Units: metres, seconds,
/// radians, m/s, m/s².
///
/// Deserialises from JSON with every group and field optional (missing ones take the
/// [`Default`]) and unknown ones refused; [`PlannerSettings::from_json`] accepts only a JSON
/// object. Always call [`PlannerSettings::validate`] (done by [`crate::Planner::new`]) before
/// use.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerSettings {
    /// The vehicle model and the discretisation.
    pub model: ModelSettings,
    /// The weights of the cost.
    pub cost: CostSettings,
    /// The input and state bounds.
    pub bounds: BoundSettings,
    /// The safety constraint.
    pub safety: SafetySettings,
    /// The ADMM loop.
    pub admm: AdmmSettings,
    /// The repairs of an inadmissible ADMM roll-out.
    pub repair: RepairSettings,
    /// The work budget of one call.
    pub budget: BudgetSettings,
    /// Lanes that end.
    pub lane_ends: LaneEndSettings,
}

/// The groups of [`PlannerSettings`], in order: name and field table.
pub const GROUPS: [(&str, &[FieldSpec]); 8] = [
    ("model", ModelSettings::FIELDS),
    ("cost", CostSettings::FIELDS),
    ("bounds", BoundSettings::FIELDS),
    ("safety", SafetySettings::FIELDS),
    ("admm", AdmmSettings::FIELDS),
    ("repair", RepairSettings::FIELDS),
    ("budget", BudgetSettings::FIELDS),
    ("lane_ends", LaneEndSettings::FIELDS),
];

/// Keys of the flat settings of earlier versions that moved into a group: (old key, new
/// dotted key).
pub const MOVED: &[(&str, &str)] = &[
    ("horizon", "model.horizon"),
    ("dt", "model.dt"),
    ("l_f", "model.l_f"),
    ("l_r", "model.l_r"),
    ("w_y", "cost.w_y"),
    ("w_v", "cost.w_v"),
    ("w_psi", "cost.w_psi"),
    ("w_delta", "cost.w_delta"),
    ("w_ddelta", "cost.w_ddelta"),
    ("w_a", "cost.w_a"),
    ("w_da", "cost.w_da"),
    ("delta_max", "bounds.delta_max"),
    ("ddelta_max", "bounds.ddelta_max"),
    ("a_min", "bounds.a_min"),
    ("a_max", "bounds.a_max"),
    ("da_max", "bounds.da_max"),
    ("v_max", "bounds.v_max"),
    ("edge_margin", "bounds.edge_margin"),
    ("heading_max", "bounds.heading_max"),
    ("heading_recovery", "bounds.heading_recovery"),
    ("overshoot_max", "bounds.overshoot_max"),
    ("ellipse_scale", "safety.ellipse_scale"),
    ("margin_x", "safety.margin_x"),
    ("margin_y", "safety.margin_y"),
    ("ego_segment_length", "safety.ego_segment_length"),
    ("brake_decel", "safety.brake_decel"),
    ("check_range", "safety.check_range"),
    ("safety_min", "safety.safety_min"),
    ("ablate_reaction", "safety.ablate_reaction"),
    ("rho", "admm.rho"),
    ("max_iter", "admm.max_iter"),
    ("eps_primal", "admm.eps_primal"),
    ("eps_change", "admm.eps_change"),
    ("pgd_steps", "admm.pgd_steps"),
    ("pgd_halvings", "admm.pgd_halvings"),
    ("pin_weight", "admm.pin_weight"),
    ("restore_step", "admm.restore_step"),
    ("v_lin_min", "admm.v_lin_min"),
    ("refine_iters", "repair.refine_iters"),
    ("refine_margin", "repair.refine_margin"),
    ("refine_trust_delta", "repair.refine_trust_delta"),
    ("refine_trust_accel", "repair.refine_trust_accel"),
    ("fallback_speed_floor", "repair.fallback_speed_floor"),
    ("bounds_slack", "repair.bounds_slack"),
    ("lattice_min_speed", "repair.lattice_min_speed"),
    ("lead_min_speed", "repair.lead_min_speed"),
    ("budget_s", "budget.seconds"),
    ("budget_calls", "budget.calls"),
    ("w_deadline", "lane_ends.w_deadline"),
    ("deadline_distance", "lane_ends.deadline_distance"),
    ("stop_decel", "lane_ends.stop_decel"),
    ("stop_margin", "lane_ends.stop_margin"),
];

/// Keys of earlier versions that were removed, with where their evidence lives: switches
/// measured and refused (their code is gone; the report names the last commit that had it),
/// their parameters, and adopted rules that lost their switch (always on now).
pub const REMOVED: &[(&str, &str)] = &[
    ("z_safe_step", "refused: docs/results/latency.md"),
    (
        "z_step_margin",
        "refused with z_safe_step: docs/results/latency.md",
    ),
    ("z_cuts", "refused: docs/results/latency.md"),
    ("z_rollout_trial", "refused: docs/results/latency.md"),
    ("relinearise", "refused: docs/results/latency.md"),
    ("safe_start", "refused: docs/results/latency.md"),
    ("z_retighten", "refused: docs/results/latency.md"),
    (
        "warm_start_dual",
        "refused, the duals start at 0: docs/results/settings_v2.md",
    ),
    ("plan_buffer", "refused: docs/results/latency.md"),
    (
        "ellipse_lateral_scale",
        "refused: docs/results/ellipse_lateral.md",
    ),
    (
        "safety_geometry",
        "refused (boxes, grown_boxes): docs/results/nudge_safety.md",
    ),
    ("contingency", "refused: docs/results/nudge_safety.md"),
    (
        "contingency_accel",
        "refused with contingency: docs/results/nudge_safety.md",
    ),
    (
        "contingency_steps",
        "refused with contingency: docs/results/nudge_safety.md",
    ),
    ("follower_ttc", "refused: docs/results/follower_gap.md"),
    (
        "follower_min_gap",
        "refused with follower_ttc: docs/results/follower_gap.md",
    ),
    (
        "follower_clearance",
        "refused with follower_ttc: docs/results/follower_gap.md",
    ),
    (
        "fallback_brake_hold",
        "refused: docs/results/planned_slow.md",
    ),
    (
        "fallback_full_accel",
        "refused: docs/results/fallback_escape.md",
    ),
    ("fallback_shy", "refused: docs/results/planned_slow.md"),
    (
        "fallback_match_speed",
        "refused: docs/results/match_speed.md",
    ),
    (
        "match_admissible_only",
        "refused with fallback_match_speed: docs/results/match_speed.md",
    ),
    (
        "match_min_speed",
        "refused with fallback_match_speed: docs/results/match_speed.md",
    ),
    (
        "lattice_when_fallback_hits",
        "refused: docs/results/avoidability.md",
    ),
    (
        "fallback_nonreactive",
        "refused: docs/results/follower_gap.md",
    ),
    (
        "fallback_avoid_nonreactive",
        "refused: docs/results/avoidability.md",
    ),
    (
        "avoid_min_speed",
        "refused with fallback_avoid_nonreactive: docs/results/avoidability.md",
    ),
    ("lateral_drift", "refused: docs/results/avoidability.md"),
    (
        "lateral_drift_min_speed",
        "refused with lateral_drift: docs/results/avoidability.md",
    ),
    (
        "lead_first",
        "adopted, always on: docs/results/lead_first.md",
    ),
    (
        "lead_in_lane",
        "adopted, always on: docs/results/lead_first.md",
    ),
    (
        "lead_keep_lane",
        "adopted, always on: docs/results/lead_first.md",
    ),
    (
        "bounds_first",
        "adopted, always on: docs/results/long_egos.md",
    ),
    (
        "contact_first",
        "adopted, always on: docs/results/long_egos.md",
    ),
    (
        "edge_first",
        "adopted, always on: docs/results/long_egos.md",
    ),
    (
        "fallback_lattice",
        "adopted, always on: docs/results/avoidability.md",
    ),
    (
        "lattice_clear_nonreactive",
        "adopted, always on: docs/results/avoidability.md",
    ),
    (
        "heading_governor",
        "adopted, always on: docs/results/heading_governor.md",
    ),
    (
        "hessian_scaled",
        "adopted, always on: docs/results/settings_v2.md",
    ),
    (
        "rollout_check",
        "the execution check is the planner's safety, always on: docs/results/settings_v2.md",
    ),
];

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

impl PlannerSettings {
    /// Largest horizon accepted (steps): the predictors' [`nudge_predictor::MAX_HORIZON`].
    pub const MAX_HORIZON: usize = nudge_predictor::MAX_HORIZON;
    /// Largest `admm.max_iter` accepted.
    pub const MAX_ITER: usize = 10_000;
    /// Shortest non-zero `safety.ego_segment_length` (m): short enough that the longest ego
    /// cut into [`Self::MAX_EGO_SEGMENTS`] slices (16 m) is a plausible vehicle
    /// ([`crate::scenario::VEHICLE_LENGTH`]), long enough that a 30 m ego needs 120.
    pub const MIN_EGO_SEGMENT_LENGTH: f64 = 0.25;
    /// Most predictor calls of one MPC call, whatever the settings (`budget.calls` may only
    /// lower it): 4× the most any validation step of the shipped defaults made (1,248), so it
    /// bounds the work of settings that would otherwise call the predictor without end.
    pub const MAX_CALLS: usize = 5_000;
    /// Longest wall-clock time of one MPC call, whatever the settings (s; `budget.seconds`
    /// may only lower it): a call ends within it plus at most one predictor call and the QP
    /// work of its execution check. The slowest validation step of the shipped defaults took
    /// 5.2 s with the teacher planning (661 predictor calls; 60 of the validation scenes, one
    /// thread, on a 2-core machine shared with other jobs at load 13; 0.6 s unloaded) and
    /// 1.3 s with the student (all 713 scenes, 10,566 steps), so at about 6× the slowest it
    /// never binds on an ordinary step and the records of the shipped defaults stay
    /// deterministic, while it bounds settings and predictors that would run for minutes
    /// ([`Self::MAX_CALLS`] calls of a slow Python predictor).
    pub const MAX_SECONDS: f64 = 30.0;
    /// Most slices an ego may be cut into by `safety.ego_segment_length`.
    pub const MAX_EGO_SEGMENTS: usize = 64;

    /// Every field with its dotted name and range, group by group.
    pub fn fields() -> impl Iterator<Item = &'static FieldSpec> {
        GROUPS.iter().flat_map(|(_, f)| f.iter())
    }

    /// The value of the field at dotted path `field` (e.g. `"cost.w_y"`) as f64; `None` for a
    /// switch or an unknown path.
    #[must_use]
    pub fn numeric(&self, field: &str) -> Option<f64> {
        let (group, name) = field.split_once('.')?;
        match group {
            "model" => self.model.value(name),
            "cost" => self.cost.value(name),
            "bounds" => self.bounds.value(name),
            "safety" => self.safety.value(name),
            "admm" => self.admm.value(name),
            "repair" => self.repair.value(name),
            "budget" => self.budget.value(name),
            "lane_ends" => self.lane_ends.value(name),
            _ => None,
        }
    }

    /// Checks every numeric field against its range and the relations between fields.
    ///
    /// # Errors
    /// [`SettingsError::OutOfRange`] naming the first field out of its range (NaN and
    /// infinity never are in range), [`SettingsError::Invalid`] for `bounds.a_max` ≤
    /// `bounds.a_min` or a `safety.ego_segment_length` in (0, 0.25).
    pub fn validate(&self) -> Result<(), SettingsError> {
        let specs: Vec<FieldSpec> = Self::fields().copied().collect();
        if let Some((range, value)) = first_out_of_range(&specs, |f| self.numeric(f)) {
            return Err(SettingsError::OutOfRange {
                field: range.field,
                value,
                range,
            });
        }
        if self.bounds.a_max <= self.bounds.a_min {
            return Err(SettingsError::Invalid {
                field: "bounds.a_max",
                value: format!("{}", self.bounds.a_max),
                reason: "must be > bounds.a_min (empty acceleration bounds)",
            });
        }
        let seg = self.safety.ego_segment_length;
        if seg != 0.0 && seg < Self::MIN_EGO_SEGMENT_LENGTH {
            return Err(SettingsError::Invalid {
                field: "safety.ego_segment_length",
                value: format!("{seg}"),
                reason: "must be 0 (off) or at least MIN_EGO_SEGMENT_LENGTH = 0.25 m",
            });
        }
        Ok(())
    }

    /// Parses a JSON object of groups (missing groups and fields take their defaults) and
    /// validates it.
    ///
    /// # Errors
    /// [`SettingsError::Invalid`] naming `<json>` when the text is not JSON or not an object,
    /// naming a key of the flat settings of earlier versions with where it moved or why it was
    /// removed, naming a repeated key, or when a field is unknown, naming the field (dotted)
    /// when it is of the wrong type; otherwise as [`Self::validate`].
    pub fn from_json(text: &str) -> Result<Self, SettingsError> {
        let not_json = |e: serde_json::Error| SettingsError::Invalid {
            field: "<json>",
            value: nudge_predictor::json::brief(&e, "docs/reference/settings.md"),
            reason: "not valid planner settings JSON",
        };
        // A repeated key is an error naming it (serde_json would keep the last one).
        let value = nudge_predictor::json::parse(text).map_err(not_json)?;
        let Some(object) = value.as_object() else {
            return Err(SettingsError::Invalid {
                field: "<json>",
                value: json_kind(&value).to_owned(),
                reason: "planner settings must be a JSON object of groups",
            });
        };
        for key in object.keys() {
            check_key(key)?;
        }
        let s: Self = serde_json::from_value(value.clone()).map_err(|e| {
            // serde names no field in a type error: find it by parsing each field alone.
            let mut err = not_json(e);
            if let SettingsError::Invalid { field, .. } = &mut err
                && let Some(f) = Self::failing_field(object)
            {
                *field = f;
            }
            err
        })?;
        s.validate()?;
        Ok(s)
    }

    /// The dotted name of the first field of `object` (a JSON object of groups) that does not
    /// deserialise on its own; `None` when none fails alone (an unknown field or group).
    fn failing_field(object: &serde_json::Map<String, serde_json::Value>) -> Option<&'static str> {
        for (group, fields) in object {
            for (key, v) in fields.as_object()? {
                let alone = serde_json::json!({ group: { key: v } });
                if serde_json::from_value::<Self>(alone).is_err() {
                    let dotted = format!("{group}.{key}");
                    return Self::fields().find(|f| f.field == dotted).map(|f| f.field);
                }
            }
        }
        None
    }

    /// Reads and parses a settings file (at most [`MAX_SETTINGS_BYTES`]).
    ///
    /// # Errors
    /// [`SettingsError::File`] when it cannot be read or is not UTF-8; otherwise as
    /// [`Self::from_json`].
    pub fn from_file(path: impl AsRef<std::path::Path>) -> Result<Self, SettingsError> {
        let path = path.as_ref();
        let bytes = nudge_predictor::file::read_bounded(path, MAX_SETTINGS_BYTES)
            .map_err(|e| SettingsError::File(e.to_string()))?;
        let text = String::from_utf8(bytes)
            .map_err(|e| SettingsError::File(format!("{}: not UTF-8 text: {e}", path.display())))?;
        Self::from_json(&text)
    }
}

/// Refuses a top-level key of the flat settings of earlier versions with where it moved or
/// why it was removed.
///
/// # Errors
/// [`SettingsError::Moved`] or [`SettingsError::Removed`].
pub fn check_key(key: &str) -> Result<(), SettingsError> {
    if let Some((old, new)) = MOVED.iter().find(|(old, _)| *old == key) {
        return Err(SettingsError::Moved { key: old, to: new });
    }
    if let Some((old, why)) = REMOVED.iter().find(|(old, _)| *old == key) {
        return Err(SettingsError::Removed { key: old, why });
    }
    Ok(())
}
