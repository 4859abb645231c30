//! What a closed-loop run records: [`StepRecord`] per planning step, [`RunRecord`] per run,
//! and the typed [`StepStatus`] (the name of the step's [`nudge_planner::PlanStatus`]).

use serde::{Deserialize, Serialize};

use nudge_planner::BindingVehicle;
pub use nudge_planner::StepStatus;

use super::config::World;
use super::metrics::{Collision, RunMetrics, StepMetrics};

/// What happened at one closed-loop step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    /// Step index (0-based); time after the start = (step + 1) · 0.3 s.
    pub step: usize,
    /// Wall time of the whole MPC call (s).
    pub mpc_s: f64,
    /// Wall time of each Z-update (s), `[iterations]`.
    pub z_updates_s: Vec<f64>,
    /// ADMM iterations.
    pub iterations: usize,
    /// Predictor calls.
    pub predictor_calls: usize,
    /// Plan cost J.
    pub cost: f64,
    /// Primal residual ‖F‖∞ of the plan.
    pub primal_residual: f64,
    /// Minimum b_i over the vehicles checked at planning time, at the executed step (the ego's
    /// and the others' actual new positions), as the planner's constraint evaluates step 1
    /// ([`nudge_planner::SafetyConstraint::executed_min_b`]); `None` when none is checked.
    pub min_b: Option<f64>,
    /// The ego's box overlaps another vehicle's after this step.
    pub collision: bool,
    /// How the applied plan came about.
    pub status: StepStatus,
    /// What decided the applied plan's inputs ([`nudge_planner::DecidedBy`]).
    pub decided_by: nudge_planner::DecidedBy,
    /// The applied plan's largest violation of each soft constraint
    /// ([`nudge_planner::Plan::violation`]).
    #[serde(default)]
    pub violation: nudge_planner::Violation,
    /// The limit of the planning call's work budget that was reached, if any
    /// ([`nudge_planner::Plan::budget_reached`]; `"Seconds"` makes the step depend on the
    /// machine's speed); `None` (and absent from JSON) when the call ran to its end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget_reached: Option<nudge_planner::BudgetLimit>,
    /// Applied steering (rad).
    pub delta: f64,
    /// Applied acceleration (m/s²).
    pub accel: f64,
    /// Ego state after the step (x, y, ψ, v) (m, m, rad, m/s).
    pub ego: [f64; 4],
    /// The nearest other vehicle after the step: (agent index, x − x_ego, y − y_ego) (m).
    pub nearest: Option<(usize, f64, f64)>,
    /// Lateral position the planner aimed at this step (m): the target lane's centre, or the
    /// ego's own lane's centre while a lane-change abort holds.
    pub y_goal: f64,
    /// Speed at the end of the applied plan (its last planned state) (m/s).
    pub v_planned: f64,
    /// The applied plan's first planned state whose centre lies in a lane that has not begun
    /// or has ended ([`nudge_planner::Plan::lane_violation`]; such a plan is `Unsafe`); `None` when
    /// there is none or the scene has no lane extents.
    #[serde(default)]
    pub lane_violation: Option<nudge_planner::extents::LaneViolation>,
    /// What the step is judged by ([`crate::metrics`]).
    pub metrics: StepMetrics,
    /// The step's plan and the planning predictor's predicted reaction to it, kept only when
    /// a run is asked to trace ([`crate::RunControl::trace`]); `None` (and absent from
    /// JSON) otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trace: Option<StepTrace>,
}

/// What the planner planned and expected at one closed-loop step: enough to draw the step
/// (the animations of the `nudge` crate).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepTrace {
    /// The applied plan: the measured ego state it starts from, then the planned states,
    /// z_0..z_T as (x, y, ψ, v) in the road frame (m, m, rad, m/s), `[T + 1]`.
    pub plan: Vec<[f64; 4]>,
    /// The planning predictor's prediction of the other vehicles given the plan's positions
    /// z_1..z_T: positions (m, road frame) `[n − 1][T]`, agents 1..n at plan steps 1..T.
    pub predicted: Vec<Vec<[f64; 2]>>,
    /// The vehicle the plan's safety binds on under that prediction, with its safety
    /// ellipses ([`nudge_planner::SafetyConstraint::binding`]); `None` when no vehicle is checked.
    pub binding: Option<BindingVehicle>,
    /// Every agent's position after the step (m, road frame), `[n]`, agent 0 = the ego.
    pub agents: Vec<[f64; 2]>,
}

/// How a closed-loop run ended (the run column `outcome`, by [`RunOutcome::as_str`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[non_exhaustive]
pub enum RunOutcome {
    /// Settled in the target lane without any collision.
    Success,
    /// A step with a bounding-box collision (the run went on, and was not a success).
    Collision,
    /// The ego's centre was in a lane past its real end (scenes with lane extents); the run
    /// stopped at that step.
    LaneEnded,
    /// The ego's centre was in a lane before its real begin; the run stopped at that step.
    LaneNotBegun,
    /// The step limit came with the ego's centre still in a lane that really ends ahead of
    /// it, at most `deadline_distance` ahead, without a collision: the merge was not made and the end not passed (a blocked
    /// merge waiting for a gap, held by the stopping rule of [`nudge_planner::extents`]; the last
    /// step's speed says whether it stood).
    Waiting,
    /// None of the above by `max_steps` (or the ego turned across the road).
    #[default]
    Unfinished,
}

impl RunOutcome {
    /// Every outcome, in declaration order.
    pub const ALL: [Self; 6] = [
        Self::Success,
        Self::Collision,
        Self::LaneEnded,
        Self::LaneNotBegun,
        Self::Waiting,
        Self::Unfinished,
    ];

    /// The name, as in records and tables.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Success => "Success",
            Self::Collision => "Collision",
            Self::LaneEnded => "LaneEnded",
            Self::LaneNotBegun => "LaneNotBegun",
            Self::Waiting => "Waiting",
            Self::Unfinished => "Unfinished",
        }
    }
}

impl std::fmt::Display for RunOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One closed-loop run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    /// Scenario name.
    pub scenario: String,
    /// Seed that chose the target lane.
    pub seed: u64,
    /// Planning predictor (its [`nudge_predictor::Predictor::name`]).
    pub predictor: String,
    /// How the others moved.
    pub world: World,
    /// Vehicles in the scene (ego included).
    pub n_agents: usize,
    /// Target lane index.
    pub target_lane: usize,
    /// Target lateral position: the target lane's centre (m).
    pub y_target: f64,
    /// Settled in the target lane before `max_steps` without any collision.
    pub success: bool,
    /// Steps until settled (the last of the `settle_steps` consecutive steps), if successful.
    pub steps_to_target: Option<usize>,
    /// Any step with a bounding-box collision.
    pub collision: bool,
    /// Every collision event (first step of a contact with one vehicle), classified at fault
    /// or not.
    pub collisions: Vec<Collision>,
    /// What the run is judged by ([`crate::metrics`]).
    pub metrics: RunMetrics,
    /// Lane-change aborts ([`crate::SimConfig::abort_after`]).
    pub aborts: usize,
    /// How the run ended: a collision first, then a lane that ended (or had not begun) under
    /// the ego, then success, then waiting in a lane that ends ahead.
    #[serde(default)]
    pub outcome: RunOutcome,
    /// Per-step records.
    pub steps: Vec<StepRecord>,
}
