//! [`PlannerSettings`]: every weight, bound, tolerance and limit of the ADMM MPC in one
//! validated, serde-(de)serialisable struct.

use serde::{Deserialize, Serialize};

use crate::error::SettingsError;

/// Every number the planner uses. Units: metres, seconds, radians, m/s, m/s².
///
/// Deserialises from JSON with every field optional (missing fields take the [`Default`]) and
/// unknown fields rejected. Always call [`PlannerSettings::validate`] (done by
/// [`crate::Planner::new`]) before use.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerSettings {
    /// Planning horizon T (steps); must equal the predictor's horizon (6 for shipped models).
    pub horizon: usize,
    /// Step length (s).
    pub dt: f64,
    /// Distance from the centre of gravity to the front axle l_f (m).
    pub l_f: f64,
    /// Distance from the centre of gravity to the rear axle l_r (m).
    pub l_r: f64,

    /// Weight of (y − y_target)² per step (1/m²).
    pub w_y: f64,
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
    /// Longitudinal ellipse margin m_x added to the half lengths (m).
    pub margin_x: f64,
    /// Lateral ellipse margin m_y added to the half widths (m).
    pub margin_y: f64,
    /// Only vehicles whose current centre is within this distance of the ego's are checked (m).
    pub check_range: f64,
    /// A point is safe when every checked b_i ≥ this value (≥ 0; 0 means b_i > 0 strictly
    /// up to rounding).
    pub safety_min: f64,
    /// Constraint tightening (≥ 0, units of b): the Z-update accepts only states with every
    /// b_i > safety_min + plan_buffer, while the executed roll-out must only keep
    /// b_i > safety_min. Z otherwise settles on the constraint boundary and the roll-out of
    /// the inputs, which deviates from Z by the primal residual, dips below it.
    pub plan_buffer: f64,

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
    /// Try the Hessian-scaled step H⁻¹∇G (H = ∇²G, constant per call) before the plain 1/L
    /// gradient step in each Z-update step. Plain 1/L steps alone converge slowly (H's
    /// condition number is ~10⁴ at highway speeds).
    pub hessian_scaled: bool,
    /// Weight w_pin of the position pull in the pinned-Newton and restoration trials
    /// (minimise G + w_pin/2 Σ‖p_k − p*_k‖²); large values keep positions near the target.
    pub pin_weight: f64,
    /// Warm-start the dual variable μ from the previous call (shifted); otherwise μ = 0.
    pub warm_start_dual: bool,
    /// Check the nonlinear roll-out of the returned inputs with the predictor and fall back to
    /// the least-violating simple input sequence when it is unsafe.
    pub rollout_check: bool,
    /// Largest position move (m) of a feasibility-restoration trial.
    pub restore_step: f64,

    /// Heading bound relative to the road (rad): every returned state has |ψ_k| ≤ heading_max
    /// (an ego that starts beyond it gets a bound that returns to it by `heading_recovery`
    /// per step). A value ≥ π/2 leaves the heading unbounded.
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

impl Default for PlannerSettings {
    fn default() -> Self {
        Self {
            horizon: 6,
            dt: 0.3,
            l_f: 1.4,
            l_r: 1.4,
            w_y: 15.0,
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
            check_range: 60.0,
            safety_min: 0.0,
            plan_buffer: 0.0,
            max_iter: 30,
            eps_primal: 1e-2,
            eps_change: 1e-2,
            pgd_steps: 5,
            pgd_halvings: 3,
            hessian_scaled: true,
            pin_weight: 1e4,
            warm_start_dual: false,
            rollout_check: true,
            restore_step: 1.0,
            heading_max: 0.2,
            heading_recovery: 0.05,
            overshoot_max: 0.3,
            refine_iters: 5,
            refine_margin: 0.02,
            refine_trust_delta: 0.05,
            refine_trust_accel: 2.0,
            budget_s: 0.0,
            budget_calls: 0,
        }
    }
}

fn check(
    field: &'static str,
    value: f64,
    ok: bool,
    reason: &'static str,
) -> Result<(), SettingsError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(SettingsError::Invalid {
            field,
            value: format!("{value}"),
            reason,
        })
    }
}

impl PlannerSettings {
    /// Largest horizon accepted (steps).
    pub const MAX_HORIZON: usize = 60;
    /// Largest ADMM iteration count accepted.
    pub const MAX_ITER: usize = 100_000;

    /// Checks every field.
    ///
    /// # Errors
    /// [`SettingsError::Invalid`] naming the first bad field: a negative or non-finite weight,
    /// a non-positive ρ, step or geometry, an empty bound interval (`a_min ≥ a_max`,
    /// `delta_max ≤ 0`, ...), horizon 0 or above [`Self::MAX_HORIZON`], zero iterations.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let h = self.horizon;
        if h == 0 || h > Self::MAX_HORIZON {
            return Err(SettingsError::Invalid {
                field: "horizon",
                value: h.to_string(),
                reason: "must be in 1..=60",
            });
        }
        if self.max_iter == 0 || self.max_iter > Self::MAX_ITER {
            return Err(SettingsError::Invalid {
                field: "max_iter",
                value: self.max_iter.to_string(),
                reason: "must be in 1..=100000",
            });
        }
        if self.pgd_steps == 0 || self.pgd_steps > 10_000 {
            return Err(SettingsError::Invalid {
                field: "pgd_steps",
                value: self.pgd_steps.to_string(),
                reason: "must be in 1..=10000",
            });
        }
        if self.pgd_halvings > 60 {
            return Err(SettingsError::Invalid {
                field: "pgd_halvings",
                value: self.pgd_halvings.to_string(),
                reason: "must be at most 60",
            });
        }
        let positive = "must be finite and > 0";
        let nonneg = "must be finite and >= 0";
        check("dt", self.dt, self.dt > 0.0, positive)?;
        check("l_f", self.l_f, self.l_f > 0.0, positive)?;
        check("l_r", self.l_r, self.l_r > 0.0, positive)?;
        for (field, w) in [
            ("w_y", self.w_y),
            ("w_v", self.w_v),
            ("w_psi", self.w_psi),
            ("w_delta", self.w_delta),
            ("w_ddelta", self.w_ddelta),
            ("w_a", self.w_a),
            ("w_da", self.w_da),
        ] {
            check(field, w, w >= 0.0, nonneg)?;
        }
        check("rho", self.rho, self.rho > 0.0, positive)?;
        check(
            "delta_max",
            self.delta_max,
            self.delta_max > 0.0 && self.delta_max < 1.5,
            "must be in (0, 1.5) rad",
        )?;
        check(
            "ddelta_max",
            self.ddelta_max,
            self.ddelta_max > 0.0,
            positive,
        )?;
        check(
            "a_min",
            self.a_min,
            self.a_min.is_finite(),
            "must be finite",
        )?;
        check(
            "a_max",
            self.a_max,
            self.a_max > self.a_min,
            "must be finite and > a_min (empty acceleration bounds)",
        )?;
        check("da_max", self.da_max, self.da_max > 0.0, positive)?;
        check("v_max", self.v_max, self.v_max > 0.0, positive)?;
        check(
            "edge_margin",
            self.edge_margin,
            self.edge_margin >= 0.0,
            nonneg,
        )?;
        check("v_lin_min", self.v_lin_min, self.v_lin_min > 0.0, positive)?;
        check(
            "ellipse_scale",
            self.ellipse_scale,
            self.ellipse_scale >= 1.0,
            "must be finite and >= 1",
        )?;
        check("margin_x", self.margin_x, self.margin_x >= 0.0, nonneg)?;
        check("margin_y", self.margin_y, self.margin_y >= 0.0, nonneg)?;
        check(
            "check_range",
            self.check_range,
            self.check_range >= 0.0,
            nonneg,
        )?;
        check(
            "safety_min",
            self.safety_min,
            self.safety_min >= 0.0,
            nonneg,
        )?;
        check(
            "plan_buffer",
            self.plan_buffer,
            self.plan_buffer >= 0.0,
            nonneg,
        )?;
        check(
            "eps_primal",
            self.eps_primal,
            self.eps_primal > 0.0,
            positive,
        )?;
        check(
            "eps_change",
            self.eps_change,
            self.eps_change > 0.0,
            positive,
        )?;
        check(
            "heading_max",
            self.heading_max,
            self.heading_max > 0.0 && self.heading_max <= 10.0,
            "must be in (0, 10] rad",
        )?;
        check(
            "heading_recovery",
            self.heading_recovery,
            self.heading_recovery > 0.0,
            positive,
        )?;
        check(
            "overshoot_max",
            self.overshoot_max,
            self.overshoot_max >= 0.0,
            nonneg,
        )?;
        if self.refine_iters > 100 {
            return Err(SettingsError::Invalid {
                field: "refine_iters",
                value: self.refine_iters.to_string(),
                reason: "must be at most 100",
            });
        }
        check("refine_margin", self.refine_margin, self.refine_margin >= 0.0, nonneg)?;
        check(
            "refine_trust_delta",
            self.refine_trust_delta,
            self.refine_trust_delta > 0.0,
            positive,
        )?;
        check(
            "refine_trust_accel",
            self.refine_trust_accel,
            self.refine_trust_accel > 0.0,
            positive,
        )?;
        check("budget_s", self.budget_s, self.budget_s >= 0.0, nonneg)?;
        check(
            "restore_step",
            self.restore_step,
            self.restore_step > 0.0,
            positive,
        )?;
        Ok(())
    }

    /// Parses JSON (missing fields default, unknown fields rejected) and validates.
    ///
    /// # Errors
    /// [`SettingsError::Invalid`] with field `"<json>"` on a parse error, otherwise as
    /// [`Self::validate`].
    pub fn from_json(text: &str) -> Result<Self, SettingsError> {
        let s: Self = serde_json::from_str(text).map_err(|e| SettingsError::Invalid {
            field: "<json>",
            value: e.to_string(),
            reason: "not valid planner settings JSON",
        })?;
        s.validate()?;
        Ok(s)
    }
}
