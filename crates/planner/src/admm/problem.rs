//! What one MPC call is given ([`PlanningProblem`], [`EgoState`]) and what it returns
//! ([`Plan`], [`PlanStatus`], [`PhaseTimings`]), with the checks a problem must pass.

use nudge_predictor::{History, T_OBS};
use serde::{Deserialize, Serialize};

use crate::error::PlannerError;
use crate::extents::{LaneViolation, Lanes};
use crate::qp::{QpName, QpStatus};
use crate::scenario::Scenario;

use super::decision::DecidedBy;

/// The ego's measured state in the road frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EgoState {
    /// Longitudinal position of the centre of gravity (m).
    pub x: f64,
    /// Lateral position (m, positive left).
    pub y: f64,
    /// Heading (rad, 0 = along the road, positive left).
    pub psi: f64,
    /// Speed (m/s).
    pub v: f64,
}

/// Everything one MPC call needs besides the settings and the predictor.
#[derive(Debug, Clone, Copy)]
pub struct PlanningProblem<'a> {
    /// The ego's current state.
    pub ego: EgoState,
    /// Steering applied at the previous step δ_{−1} (rad).
    pub last_delta: f64,
    /// Acceleration applied at the previous step a_{−1} (m/s²).
    pub last_accel: f64,
    /// Observed positions `[n, T_OBS, 2]` (m), agent 0 = ego (its last entry should be the
    /// ego's current position).
    pub history: &'a History,
    /// Vehicle sizes `[n]` of (length, width) (m), agent 0 = ego.
    pub sizes: &'a [[f64; 2]],
    /// Lateral target y (m): the target lane's centre.
    pub y_target: f64,
    /// Reference speed (m/s).
    pub v_ref: f64,
    /// Road edges (right, left) as lateral y (m), right < left.
    pub road: [f64; 2],
    /// The lane centre the ego may fall back to (m, lateral y): during a lane change the
    /// centre of the lane it came from (`None`: no such lane). The lateral corridor includes
    /// it, and when no admissible plan exists the fallbacks also steer towards it, so the
    /// least-violating plan may cancel the change instead of holding the ego across the line.
    pub y_retreat: Option<f64>,
    /// The lane layout with where each lane begins and ends ([`Lanes`]; a
    /// "nudge.scenario/2" scene's): a planned state whose centre lies in a lane that has
    /// not begun or has ended is inadmissible, and a merge out of a lane that ends gets a
    /// deadline term ([`crate::extents`]). `None`: every lane runs through (the plan is
    /// the same, bit for bit, as with lanes whose extents are never reached).
    pub lanes: Option<Lanes<'a>>,
}

impl<'a> PlanningProblem<'a> {
    /// The problem at the last observed step of scenario `sc` (the closed loop's first step):
    /// the ego's observed position, heading and speed (the speed also the reference), no
    /// previous inputs, `history` (the scenario's, `[n, T_OBS, 2]`), lateral target
    /// `y_target` (m), the scenario's lane layout when it has extents.
    #[must_use]
    pub fn at_scenario_start(sc: &'a Scenario, history: &'a History, y_target: f64) -> Self {
        let p = sc.position(0, T_OBS - 1);
        Self {
            ego: EgoState {
                x: p[0],
                y: p[1],
                psi: sc.heading[0],
                v: sc.speed[0].max(0.0),
            },
            last_delta: 0.0,
            last_accel: 0.0,
            history,
            sizes: &sc.size,
            y_target,
            v_ref: sc.speed[0],
            road: sc.road(),
            y_retreat: None,
            lanes: sc.lanes(),
        }
    }
}

impl PlanningProblem<'_> {
    /// Widest road accepted (m): [`crate::scenario::MAX_LANES`] lanes of the widest plausible
    /// lane ([`crate::scenario::LANE_WIDTH`]).
    pub const MAX_ROAD_WIDTH: f64 =
        crate::scenario::MAX_LANES as f64 * crate::scenario::LANE_WIDTH[1];
    /// Largest reference speed accepted (m/s): the largest plausible speed of a scenario
    /// ([`crate::scenario::MAX_SPEED`]), also the largest admissible `v_max`.
    pub const MAX_V_REF: f64 = crate::scenario::MAX_SPEED;
    /// Largest measured ego speed accepted (m/s): the predictors' bound on observed motion,
    /// [`nudge_predictor::limits::MAX_STEP`] per 0.3 s step.
    pub const MAX_EGO_SPEED: f64 = nudge_predictor::limits::MAX_STEP / nudge_predictor::DT;
    /// Largest |previous steering| accepted (rad): the widest admissible `delta_max`.
    pub const MAX_LAST_DELTA: f64 = 1.5;
    /// Largest |previous acceleration| accepted (m/s²): the widest admissible `a_min`/`a_max`.
    pub const MAX_LAST_ACCEL: f64 = 15.0;
    /// Farthest the ego's centre may lie beyond an edge of the road (m): half the widest
    /// plausible vehicle ([`crate::scenario::VEHICLE_WIDTH`]), so an ego refused as off the
    /// road has its whole box beyond the edge whatever its width.
    pub const MAX_OFF_ROAD: f64 = crate::scenario::VEHICLE_WIDTH[1] / 2.0;

    /// Checks that the problem can be planned: finite numbers; the ego within
    /// ±[`nudge_predictor::limits::MAX_ABS_POSITION`] m, its speed in
    /// 0..=[`Self::MAX_EGO_SPEED`] m/s, its heading within ±π/2 of the road; previous inputs
    /// within ±[`Self::MAX_LAST_DELTA`] rad and ±[`Self::MAX_LAST_ACCEL`] m/s²; an ordered road
    /// at most [`Self::MAX_ROAD_WIDTH`] m wide whose edges lie within the same coordinate
    /// range; `y_target` and `y_retreat` (when given) on the road (edges included); `v_ref` in 0..=[`Self::MAX_V_REF`]
    /// m/s; the ego's centre at most [`Self::MAX_OFF_ROAD`] m beyond an edge of the road; one
    /// plausible size per agent (length in [`crate::scenario::VEHICLE_LENGTH`], width in
    /// [`crate::scenario::VEHICLE_WIDTH`], the bounds of the scenario files); a lane layout
    /// (when given) as [`Lanes::check`] requires.
    ///
    /// # Errors
    /// [`PlannerError::BadProblem`] naming the first offending field,
    /// [`PlannerError::BadLane`] naming the lane and field of a bad lane layout.
    pub fn check(&self) -> Result<(), PlannerError> {
        self.check_ego()?;
        self.check_road()?;
        self.check_agents()
    }

    /// The ego's state and previous inputs ([`Self::check`]).
    fn check_ego(&self) -> Result<(), PlannerError> {
        use crate::settings::show;
        use nudge_predictor::limits::MAX_ABS_POSITION;
        let bad =
            |field: &'static str, reason: String| Err(PlannerError::BadProblem { field, reason });
        let e = self.ego;
        for (field, v) in [
            ("ego.x", e.x),
            ("ego.y", e.y),
            ("ego.psi", e.psi),
            ("ego.v", e.v),
            ("last_delta", self.last_delta),
            ("last_accel", self.last_accel),
            ("y_target", self.y_target),
            ("v_ref", self.v_ref),
            ("road", self.road[0]),
            ("road", self.road[1]),
        ] {
            if !v.is_finite() {
                return bad(field, format!("non-finite value {v}"));
            }
        }
        for (field, v) in [("ego.x", e.x), ("ego.y", e.y)] {
            if v.abs() > MAX_ABS_POSITION {
                return bad(
                    field,
                    format!(
                        "{} m is outside the accepted ±{} m",
                        show(v),
                        show(MAX_ABS_POSITION)
                    ),
                );
            }
        }
        if !(0.0..=Self::MAX_EGO_SPEED).contains(&e.v) {
            return bad(
                "ego.v",
                format!(
                    "speed {} m/s is outside 0..={} m/s",
                    show(e.v),
                    Self::MAX_EGO_SPEED
                ),
            );
        }
        if e.psi.abs() > std::f64::consts::FRAC_PI_2 {
            return bad(
                "ego.psi",
                format!("heading {} rad points off the road", e.psi),
            );
        }
        if self.last_delta.abs() > Self::MAX_LAST_DELTA {
            return bad(
                "last_delta",
                format!(
                    "{} rad is outside ±{} rad",
                    show(self.last_delta),
                    Self::MAX_LAST_DELTA
                ),
            );
        }
        if self.last_accel.abs() > Self::MAX_LAST_ACCEL {
            return bad(
                "last_accel",
                format!(
                    "{} m/s² is outside ±{} m/s²",
                    show(self.last_accel),
                    Self::MAX_LAST_ACCEL
                ),
            );
        }
        Ok(())
    }

    /// The road, the lateral goals and the reference speed ([`Self::check`]).
    fn check_road(&self) -> Result<(), PlannerError> {
        use crate::settings::show;
        use nudge_predictor::limits::MAX_ABS_POSITION;
        let bad =
            |field: &'static str, reason: String| Err(PlannerError::BadProblem { field, reason });
        let [right, left] = self.road;
        if right >= left {
            return bad(
                "road",
                format!("right edge {right} is not below left edge {left}"),
            );
        }
        if right.abs().max(left.abs()) > MAX_ABS_POSITION || left - right > Self::MAX_ROAD_WIDTH {
            return bad(
                "road",
                format!(
                    "edges [{}, {}] m: the road must lie within ±{} m and be at most {} m wide",
                    show(right),
                    show(left),
                    show(MAX_ABS_POSITION),
                    Self::MAX_ROAD_WIDTH
                ),
            );
        }
        if !(right..=left).contains(&self.y_target) {
            return bad(
                "y_target",
                format!("{:e} m is off the road [{right}, {left}] m", self.y_target),
            );
        }
        if let Some(y) = self.y_retreat
            && !(right..=left).contains(&y)
        {
            return bad(
                "y_retreat",
                format!("{y:e} m is off the road [{right}, {left}] m (or not finite)"),
            );
        }
        let y = self.ego.y;
        let beyond = (right - y).max(y - left);
        if beyond > Self::MAX_OFF_ROAD {
            let side = if y < right { "right" } else { "left" };
            return bad(
                "ego.y",
                format!(
                    "the ego (agent 0) at y = {} m is {beyond:.2} m beyond the road's {side} edge \
                     (road [{}, {}] m; at most MAX_OFF_ROAD = {} m)",
                    show(y),
                    show(right),
                    show(left),
                    Self::MAX_OFF_ROAD
                ),
            );
        }
        if !(0.0..=Self::MAX_V_REF).contains(&self.v_ref) {
            return bad(
                "v_ref",
                format!("{} m/s is outside 0..={} m/s", self.v_ref, Self::MAX_V_REF),
            );
        }
        Ok(())
    }

    /// One positive size per agent and the lane layout ([`Self::check`]).
    fn check_agents(&self) -> Result<(), PlannerError> {
        let bad =
            |field: &'static str, reason: String| Err(PlannerError::BadProblem { field, reason });
        let n = self.history.n_agents();
        if self.sizes.len() != n {
            return bad(
                "sizes",
                format!("{} sizes for {n} agents", self.sizes.len()),
            );
        }
        use crate::scenario::{VEHICLE_LENGTH, VEHICLE_WIDTH};
        for (i, s) in self.sizes.iter().enumerate() {
            let who = if i == 0 {
                "agent 0 (the ego)".to_string()
            } else {
                format!("agent {i}")
            };
            for (what, v, [lo, hi]) in [
                ("length", s[0], VEHICLE_LENGTH),
                ("width", s[1], VEHICLE_WIDTH),
            ] {
                if !(lo..=hi).contains(&v) {
                    return bad(
                        "sizes",
                        format!("{who} has {what} {v} m, outside the plausible {lo}..={hi} m"),
                    );
                }
            }
        }
        if let Some(lanes) = &self.lanes {
            lanes.check()?;
        }
        Ok(())
    }
}

/// How an MPC call ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum PlanStatus {
    /// ‖F‖∞ ≤ eps_primal and ‖Z − Z_prev‖∞ ≤ eps_change, and the nonlinear roll-out of the
    /// ADMM inputs is admissible (safe and within the state bounds): the plan is the ADMM
    /// answer.
    Converged,
    /// `max_iter` reached; the roll-out of the ADMM inputs is admissible: the plan is the ADMM
    /// answer.
    MaxIterations,
    /// The roll-out of the ADMM inputs was not admissible (ADMM satisfies the linearised
    /// dynamics only up to `eps_primal`, and Z sits on the safety boundary); SQP refinement
    /// steps on the nonlinear model from those inputs made it admissible.
    Refined,
    /// No admissible plan was found (refinement, backtracking and fallbacks failed, or the
    /// work budget ran out before one was); the plan is the least-violating one found.
    Unsafe,
    /// The work budget (`budget.seconds`, `budget.calls`) ran out during the ADMM loop; the plan is
    /// the roll-out of the ADMM inputs at that point, or else the shifted previous plan, and it
    /// is admissible (checked with the calls the budget held back).
    BudgetExhausted,
    /// The roll-out of the ADMM inputs was not admissible and the refinement failed; the plan
    /// is the ADMM inputs pulled towards the shifted previous plan (by 3/4, 1/2 or 1/4) until
    /// the roll-out was admissible, and that roll-out.
    Backtracked,
    /// Refinement and backtracking failed; the plan is the cheapest admissible simple input
    /// sequence and its roll-out.
    Fallback,
    /// A QP of the ADMM (Δ- or α-update) gave no usable solution, also after the
    /// equilibration-off retry; the ADMM iterates were dropped and the plan is chosen as for
    /// [`PlanStatus::Fallback`] (the cheapest safe, else the least-violating, simple input
    /// sequence, checked on its roll-out).
    SolverFailed {
        /// The QP that failed.
        qp: QpName,
        /// Clarabel's status.
        status: QpStatus,
    },
}

impl PlanStatus {
    /// The variant's name (`"Converged"`, ..., `"SolverFailed"`), as in records and tables.
    #[must_use]
    pub fn name(&self) -> &'static str {
        StepStatus::from(*self).as_str()
    }

    /// The plan is a repair or a heuristic chosen after the ADMM answer could not be used
    /// (its roll-out was unsafe, or a QP failed).
    #[must_use]
    pub fn is_repaired(&self) -> bool {
        matches!(
            self,
            Self::Backtracked | Self::Fallback | Self::SolverFailed { .. }
        )
    }
}

/// The name of a [`PlanStatus`] without its details, serialised as the name: how the plan
/// applied at a closed-loop step came about (the records' `status`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum StepStatus {
    /// ADMM converged; its plan is admissible.
    Converged,
    /// ADMM reached `max_iter`; its plan is admissible.
    MaxIterations,
    /// The ADMM inputs, refined on the nonlinear model, are admissible.
    Refined,
    /// No admissible plan was found.
    Unsafe,
    /// The work budget ran out; the plan (ADMM's inputs at that point, or the previous plan)
    /// is admissible.
    BudgetExhausted,
    /// The ADMM inputs were pulled towards the previous plan until their roll-out was safe.
    Backtracked,
    /// A simple input sequence replaced the ADMM inputs.
    Fallback,
    /// A QP failed; a simple input sequence is the plan.
    SolverFailed,
}

impl StepStatus {
    /// Every status, in declaration order.
    pub const ALL: [Self; 8] = [
        Self::Converged,
        Self::MaxIterations,
        Self::Refined,
        Self::Unsafe,
        Self::BudgetExhausted,
        Self::Backtracked,
        Self::Fallback,
        Self::SolverFailed,
    ];

    /// The name, as in records and tables.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Converged => "Converged",
            Self::MaxIterations => "MaxIterations",
            Self::Refined => "Refined",
            Self::Unsafe => "Unsafe",
            Self::BudgetExhausted => "BudgetExhausted",
            Self::Backtracked => "Backtracked",
            Self::Fallback => "Fallback",
            Self::SolverFailed => "SolverFailed",
        }
    }

    /// No safe lane-change plan was found (counts towards a lane-change abort).
    #[must_use]
    pub fn is_unsafe_plan(self) -> bool {
        matches!(self, Self::Fallback | Self::Unsafe | Self::SolverFailed)
    }
}

impl From<PlanStatus> for StepStatus {
    fn from(s: PlanStatus) -> Self {
        match s {
            PlanStatus::Converged => Self::Converged,
            PlanStatus::MaxIterations => Self::MaxIterations,
            PlanStatus::Refined => Self::Refined,
            PlanStatus::Unsafe => Self::Unsafe,
            PlanStatus::BudgetExhausted => Self::BudgetExhausted,
            PlanStatus::Backtracked => Self::Backtracked,
            PlanStatus::Fallback => Self::Fallback,
            PlanStatus::SolverFailed { .. } => Self::SolverFailed,
        }
    }
}

impl std::fmt::Display for StepStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Wall-clock time of each ADMM phase over one MPC call.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PhaseTimings {
    /// All Δ-updates (s).
    pub delta_s: f64,
    /// All α-updates (s).
    pub alpha_s: f64,
    /// All Z-updates (s).
    pub z_s: f64,
    /// Each Z-update (s), in order, `[iterations]` (one fewer when a QP failed).
    pub z_updates_s: Vec<f64>,
    /// The whole call, set-up included (s).
    pub total_s: f64,
}

/// The applied plan's largest violation of each soft constraint over its states (0 where it
/// holds): what an exact-penalty optimiser reports beside its status instead of refusing a
/// plan. Measured on the returned states ([`Plan::states`]) under the planning predictor's
/// prediction of them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Violation {
    /// max(0, `safety.safety_min` − min b) over the checked vehicles and steps (units of b:
    /// the ellipse value; ∞ when the plan got no prediction).
    pub safety: f64,
    /// The largest |ψ| beyond the heading bound (`bounds.heading_max`, relaxed from a steeper
    /// start by `bounds.heading_recovery` per step) (rad).
    pub heading: f64,
    /// The largest lateral excess of the centre beyond the corridor (between the start and the
    /// goal widened by `bounds.overshoot_max`, within the road less the box's half extent and
    /// `bounds.edge_margin`) (m).
    pub corridor: f64,
    /// The largest excess of the box's corners beyond the road's edges (m).
    pub road_edge: f64,
    /// The largest excess of the centre outside its lane's extent or of the stopping rule in a
    /// lane that ends (m; 0 without a lane layout).
    pub lane: f64,
}

/// The result of one MPC call.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Steering δ_0..δ_{T−1} (rad), `[T]`.
    pub delta: Vec<f64>,
    /// Acceleration a_0..a_{T−1} (m/s²), `[T]`.
    pub accel: Vec<f64>,
    /// Planned states z_1..z_T as (x, y, ψ, v) in the road frame (m, m, rad, m/s), `[T]`.
    pub states: Vec<[f64; 4]>,
    /// ADMM's own states Z at the end of its loop, (x, y, ψ, v) in the road frame, `[T]`
    /// (empty after a QP failure): they satisfy the linearised dynamics up to the primal
    /// residual; [`Plan::states`] are the nonlinear roll-out of the returned inputs.
    pub admm_states: Vec<[f64; 4]>,
    /// Cost J = Φ1 + Φ2 + Φ3 at the returned (Δ, α, Z).
    pub cost: f64,
    /// ADMM iterations run (the failed one included after a QP failure).
    pub iterations: usize,
    /// Predictor calls (one candidate each; at most one with `ablate_reaction`).
    pub predictor_calls: usize,
    /// Candidates judged not safe without a predictor call because the predictors would
    /// refuse them (non-finite, or beyond `nudge_predictor::limits::check_candidates`: an
    /// ADMM trial point that overshot by over 1 km in one step); 0 in an ordinary call.
    pub refused_candidates: usize,
    /// Clarabel solves (retries included).
    pub qp_solves: usize,
    /// Final primal residual ‖F(Δ, α, Z)‖∞.
    pub primal_residual: f64,
    /// Final change residual ‖Z − Z_prev‖∞ (∞ when no Z-update ran).
    pub change_residual: f64,
    /// Minimum b_i over checked vehicles and steps under the predictor's prediction of the
    /// returned states (`None` when no vehicle is checked).
    pub min_safety: Option<f64>,
    /// Minimum b_i under the predictor's prediction of the nonlinear roll-out of the returned
    /// (Δ, α) from the measured state (what the vehicle will actually do); `None` when no
    /// vehicle is checked.
    pub rollout_min_safety: Option<f64>,
    /// Number of vehicles checked (within `check_range`).
    pub checked: usize,
    /// The first planned state whose centre lies in a lane that has not begun or has ended
    /// ([`PlanningProblem::lanes`]); such a plan is never admissible (its status is
    /// [`PlanStatus::Unsafe`]). `None` when every state is inside its lane's extent or the
    /// problem has no lane layout.
    #[serde(default)]
    pub lane_violation: Option<LaneViolation>,
    /// The returned plan's largest violation of each soft constraint ([`Violation`]).
    #[serde(default)]
    pub violation: Violation,
    /// Phase timings.
    pub timings: PhaseTimings,
    /// How the call ended.
    pub status: PlanStatus,
    /// What decided the applied inputs.
    pub decided_by: DecidedBy,
    /// The limit of the call's work budget that was reached, if any ([`BudgetLimit`]): the
    /// call stopped evaluating candidates there, and its plan is the best found until then
    /// (status [`PlanStatus::BudgetExhausted`] when it was reached in the ADMM loop and the
    /// plan is admissible). `None` when the call ran to its end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget_reached: Option<BudgetLimit>,
}

/// Which limit of an MPC call's work budget was reached ([`Plan::budget_reached`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum BudgetLimit {
    /// The predictor-call budget (`budget.calls`, at most `PlannerSettings::MAX_CALLS`):
    /// deterministic.
    Calls,
    /// The wall-clock budget (`budget.seconds`, at most `PlannerSettings::MAX_SECONDS`): the
    /// plan depends on the machine's speed.
    Seconds,
}

impl BudgetLimit {
    /// The name as in records (`"Calls"`, `"Seconds"`).
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Calls => "Calls",
            Self::Seconds => "Seconds",
        }
    }
}
