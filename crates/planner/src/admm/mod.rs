//! The ADMM MPC of the paper's Algorithm 1. One call of [`Planner::plan`] is
//!
//! 1. **set-up** ([`linearised`]): the nominal trajectory (the shifted previous plan), the
//!    dynamics linearised around it, the bounds, the checked vehicles ([`constraint`]), and a
//!    workspace allocated once for the call ([`workspace`]);
//! 2. **the ADMM loop**, until ‖F‖∞ ≤ eps_primal and ‖Z − Z_prev‖∞ ≤ eps_change or `max_iter`:
//!    the Δ-update and α-update (box/rate QPs solved by Clarabel, [`inputs`]), the Z-update
//!    (projected descent whose every trial point is checked by the predictor, [`z_update`],
//!    with feasibility restoration from an unsafe Z, [`restoration`]), and the dual update
//!    μ ← μ + ρF;
//! 3. **the execution check** ([`repair`]): the nonlinear roll-out of (Δ, α) is checked by
//!    the predictor and repaired (refinement, backtracking, then the ranked fallback families)
//!    when it is not admissible; a QP failure goes straight to the fallbacks. The plan records
//!    what decided it ([`DecidedBy`]).
//!
//! The solution warm-starts the next call. [`Planner::reference_qp`] solves the same
//! linearised problem as one joint QP ([`reference`]).

mod constraint;
mod decision;
mod heading;
mod inputs;
mod lagrangian;
mod linearised;
mod problem;
mod reference;
mod refine;
mod repair;
mod restoration;
mod workspace;
mod z_update;

#[cfg(test)]
mod ablation_tests;
#[cfg(test)]
mod budget_tests;
#[cfg(test)]
mod lead_first_tests;
#[cfg(test)]
mod tests;

use std::time::Instant;

use nudge_predictor::{Checked, ConstantVelocity, Predictor};

use crate::cancel::Cancel;
use crate::error::PlannerError;
use crate::model::{Bicycle, State};
use crate::qp::QpFailure;
use crate::settings::PlannerSettings;

pub use constraint::{BindingVehicle, CheckedVehicle, PairGeometry, SafetyConstraint};
pub use decision::{DecidedBy, Family, RANK_ORDER, RankKey};
pub use problem::{
    BudgetLimit, EgoState, PhaseTimings, Plan, PlanStatus, PlanningProblem, StepStatus, Violation,
};
pub use reference::JointSolution;

use constraint::{Budget, SafetyEval};
use inputs::Input;
use inputs::InputQps;
use linearised::{LinearisedProblem, WarmStart};
use repair::{Candidate, Repairer};
use workspace::{CurrentSafety, Iterates, Workspace, max_abs};

/// The ADMM MPC planner of the paper's Algorithm 1. One call of [`Planner::plan`] is
///
/// 1. **set-up**: the nominal trajectory (the shifted previous plan, constant velocity on a
///    cold start), the dynamics linearised around it, the input and state bounds, the
///    vehicles the safety constraint checks ([`SafetyConstraint`]), and a workspace allocated
///    once for the call;
/// 2. **the ADMM loop**, until ‖F‖∞ ≤ `admm.eps_primal` and ‖Z − Z_prev‖∞ ≤ `admm.eps_change`
///    or `admm.max_iter`: the Δ-update and the α-update (box/rate QPs solved by Clarabel), the
///    Z-update (Newton, pinned-Newton or gradient trials on G, each checked by the predictor;
///    feasibility restoration from an unsafe Z), the dual update μ ← μ + ρF;
/// 3. **the execution check**: the nonlinear roll-out of (Δ, α), which is what the vehicle
///    does and what the plan's states always are (its steering first governed to the heading
///    bound), must be *admissible*: safe by the predictor (b > `safety.safety_min` at every
///    step, with the closing-speed margin `safety.brake_decel` at the last), within the heading
///    bound `bounds.heading_max` relative to the road, within the lateral corridor between the
///    start and the target widened by `bounds.overshoot_max`, and with every corner of the
///    ego's box on the road. When it is not, the refinement takes up to `repair.refine_iters`
///    sequential-QP steps on the nonlinear model ([`PlanStatus::Refined`]), then backtracking
///    towards the nominal ([`PlanStatus::Backtracked`]), then the best of the fallback families
///    by the fixed key order [`RANK_ORDER`] ([`PlanStatus::Fallback`], or
///    [`PlanStatus::Unsafe`] when nothing is admissible: the least-violating plan); a QP
///    failure goes straight to the fallbacks ([`PlanStatus::SolverFailed`]).
///
/// Every plan says what decided it ([`Plan::decided_by`]): [`DecidedBy::Admm`] exactly when
/// the ADMM iterate's inputs were applied unchanged. The measurements behind each rule are in
/// `docs/results` (`docs/results/README.md` indexes them).
///
/// ```
/// use nudge_planner::{EgoState, Planner, PlannerSettings, PlanningProblem};
/// use nudge_predictor::{ConstantVelocity, History, T_OBS};
///
/// // The ego at 12 m/s in its lane, a car 40 m behind in the target lane 3.7 m to the left.
/// let mut pos = Vec::new();
/// for (x, y) in [(0.0, 0.0), (-40.0, 3.7)] {
///     for t in 0..T_OBS {
///         pos.extend([x - 12.0 * 0.3 * (T_OBS - 1 - t) as f64, y]);
///     }
/// }
/// let history = History::new(pos, 2).unwrap();
/// let sizes = [[4.5, 1.9], [4.5, 1.9]];
/// let problem = PlanningProblem {
///     ego: EgoState { x: 0.0, y: 0.0, psi: 0.0, v: 12.0 },
///     last_delta: 0.0,
///     last_accel: 0.0,
///     history: &history,
///     sizes: &sizes,
///     y_target: 3.7,
///     v_ref: 12.0,
///     road: [-1.85, 5.55],
///     y_retreat: None,
///     lanes: None,
/// };
/// let mut planner = Planner::new(PlannerSettings::default()).unwrap();
/// let mut cv = ConstantVelocity::new(6).unwrap();
/// let plan = planner.plan(&problem, &mut cv).unwrap();
/// assert_eq!(plan.states.len(), 6);
/// println!("{} decided by {}", plan.status.name(), plan.decided_by);
/// ```
#[derive(Debug, Clone)]
pub struct Planner {
    settings: PlannerSettings,
    model: Bicycle,
    warm: Option<WarmStart>,
    cancel: Option<Cancel>,
}

/// Why the ADMM loop stopped.
#[derive(Debug, Clone, PartialEq)]
enum Stop {
    /// ‖F‖∞ ≤ eps_primal and ‖Z − Z_prev‖∞ ≤ eps_change.
    Converged,
    /// `max_iter` iterations.
    MaxIterations,
    /// A QP gave no usable solution.
    SolverFailed(QpFailure),
    /// The work budget ran out.
    Budget,
}

/// What the ADMM loop hands to the execution check.
struct AdmmResult {
    iterates: Iterates,
    iterations: usize,
    change_residual: f64,
    qp_solves: usize,
    stop: Stop,
}

/// The plan after the execution check, in the call's frame.
struct Finished {
    delta: Vec<f64>,
    accel: Vec<f64>,
    z: Vec<State>,
    /// ADMM's Z at the end of its loop (empty after a QP failure).
    admm_z: Vec<State>,
    min_b: Option<f64>,
    rollout_min_b: Option<f64>,
    status: PlanStatus,
    decided_by: DecidedBy,
    iterations: usize,
    change_residual: f64,
    qp_solves: usize,
}

impl Planner {
    /// A planner with validated settings.
    ///
    /// # Errors
    /// [`PlannerError::Settings`] when `settings.validate()` fails.
    pub fn new(settings: PlannerSettings) -> Result<Self, PlannerError> {
        settings.validate()?;
        let model = Bicycle {
            l_f: settings.model.l_f,
            l_r: settings.model.l_r,
            dt: settings.model.dt,
        };
        Ok(Self {
            settings,
            model,
            warm: None,
            cancel: None,
        })
    }

    /// Lets `cancel` end this planner's calls: once it is set, the call in progress (and any
    /// later one) evaluates no further candidate and returns [`PlannerError::Cancelled`]
    /// within one predictor call, keeping the previous warm start. `None` removes it. A flag
    /// that is never set changes nothing.
    pub fn set_cancel(&mut self, cancel: Option<Cancel>) {
        self.cancel = cancel;
    }

    /// The settings in use.
    #[must_use]
    pub fn settings(&self) -> &PlannerSettings {
        &self.settings
    }

    /// The bicycle model in use.
    #[must_use]
    pub fn model(&self) -> &Bicycle {
        &self.model
    }

    /// Forgets the warm start (the next call starts from a constant-velocity roll-out).
    pub fn reset(&mut self) {
        self.warm = None;
    }

    /// Solves one MPC call (Algorithm 1) and stores the solution as the next warm start.
    ///
    /// `problem` holds the measured ego state, the history `[n, 8, 2]` and sizes `[n]` of
    /// every vehicle (agent 0 = ego), the lateral target and the road; `predictor` (horizon
    /// T = `settings.horizon`) predicts the other vehicles for every trial trajectory.
    /// Returns inputs `[T]`, states `[T]` (road frame) and how the call ended
    /// ([`Plan::status`]); a Clarabel failure is not an error but the status
    /// [`PlanStatus::SolverFailed`] with a checked fallback plan.
    ///
    /// # Errors
    /// [`PlannerError::BadProblem`] for a malformed problem or an ego that needs more than
    /// [`PlannerSettings::MAX_EGO_SEGMENTS`] safety slices (field `sizes`),
    /// [`PlannerError::HorizonMismatch`] when the predictor's horizon differs,
    /// [`PlannerError::Predictor`] when the predictor
    /// rejects the scene or a candidate, or when a prediction is non-finite or implausible
    /// (every predictor's output is checked, see [`nudge_predictor::Checked`]).
    ///
    /// # Examples
    ///
    /// A lane change to the left lane (y = 3.7 m) on a straight two-lane road with a slower car
    /// ahead, planned with the constant-velocity predictor:
    ///
    /// ```
    /// use nudge_planner::{EgoState, PlanStatus, Planner, PlannerSettings, PlanningProblem};
    /// use nudge_predictor::{ConstantVelocity, History, T_OBS};
    ///
    /// // Ego at (0, 0) and a car 15 m ahead, both observed for T_OBS steps of 0.3 s.
    /// let mut positions = Vec::new();
    /// for (x0, y, v) in [(0.0, 0.0, 12.0), (15.0, 0.0, 9.0)] {
    ///     for t in 0..T_OBS {
    ///         positions.extend([x0 - v * 0.3 * (T_OBS - 1 - t) as f64, y]);
    ///     }
    /// }
    /// let history = History::new(positions, 2)?;
    /// let sizes = [[4.5, 1.9], [4.5, 1.9]];
    /// let problem = PlanningProblem {
    ///     ego: EgoState { x: 0.0, y: 0.0, psi: 0.0, v: 12.0 },
    ///     last_delta: 0.0,
    ///     last_accel: 0.0,
    ///     history: &history,
    ///     sizes: &sizes,
    ///     y_target: 3.7,
    ///     v_ref: 12.0,
    ///     road: [-1.85, 5.55],
    ///     y_retreat: None,
    ///     lanes: None,
    /// };
    /// let mut planner = Planner::new(PlannerSettings::default())?;
    /// let plan = planner.plan(&problem, &mut ConstantVelocity::new(6)?)?;
    /// assert_eq!(plan.states.len(), 6);
    /// assert!(plan.states[5][1] > 0.0, "the ego moves towards the left lane");
    /// assert!(plan.min_safety.is_some_and(|b| b > 0.0) && plan.status != PlanStatus::Unsafe);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        let start = Instant::now();
        self.check(problem, predictor)?;
        if self.cancel.as_ref().is_some_and(Cancel::is_cancelled) {
            return Err(PlannerError::Cancelled);
        }
        // Every prediction is checked finite and plausible, whoever implemented the predictor.
        let mut checked = Checked::new(predictor);
        let predictor: &mut dyn Predictor = &mut checked;
        let s = &self.settings;
        // Set-up: the linearised problem, the checked vehicles, the workspace.
        let mut lp = LinearisedProblem::new(s, &self.model, self.warm.as_ref(), problem);
        let constraint = SafetyConstraint::new(problem, s);
        if !constraint.vehicles().is_empty() {
            predictor.set_scene(problem.history)?;
        }
        let n_agents = problem.history.n_agents();
        let mut safety = SafetyEval::new(
            &constraint,
            lp.origin,
            lp.horizon,
            n_agents,
            s.safety.safety_min,
        );
        safety.budget = Budget::new(s, start, self.cancel.clone());
        safety.count_overlap = true;
        safety.ego_last = Some(problem.history.at(0, nudge_predictor::T_OBS - 1));
        if s.safety.ablate_reaction {
            safety.ablate_reaction(crate::keep_lane_path(&problem.ego, lp.horizon, s.model.dt));
        }
        let mut timings = PhaseTimings::default();
        let iterates = Iterates::start(&lp);
        let first = safety.eval(predictor, &iterates.z)?;
        let current = CurrentSafety::new(first, &safety);
        let mut ws = Workspace::new(s, &lp, iterates, current);
        // ADMM: loop {(re-linearisation;) Δ-update; α-update; Z-update; dual update}.
        let run = admm_loop(s, &mut lp, &mut ws, &mut safety, predictor, &mut timings)?;
        let admm = AdmmResult::new(ws, run.stop, run.iterations, run.qp_solves);
        // Execution check: the roll-out of (Δ, α), repaired when unsafe; it may use the calls
        // the budget held back.
        safety.budget.reserve = 0;
        let mut nonreactive = nonreactive_predictor(&constraint, problem, lp.horizon)?;
        let mut repairer = Repairer {
            s,
            model: &self.model,
            lp: &lp,
            safety: &mut safety,
            predictor,
            nonreactive: nonreactive.as_mut().map(|p| p as &mut dyn Predictor),
        };
        let finished = check_execution(&mut repairer, admm)?;
        if safety.budget.cancelled() {
            return Err(PlannerError::Cancelled);
        }
        let counts = (safety.calls, constraint.vehicles().len(), safety.refused);
        let (mut plan, warm) = finished.into_plan(s, &lp, counts, timings);
        plan.budget_reached = safety.budget.reached;
        self.warm = Some(warm);
        plan.timings.total_s = start.elapsed().as_secs_f64();
        Ok(plan)
    }

    /// Checks the problem, the number of ego slices it needs (at most
    /// [`PlannerSettings::MAX_EGO_SEGMENTS`]) and the predictor's horizon.
    fn check(
        &self,
        problem: &PlanningProblem<'_>,
        predictor: &dyn Predictor,
    ) -> Result<(), PlannerError> {
        problem.check()?;
        let s = &self.settings;
        let ego_length = problem.sizes[0][0];
        if constraint::ego_slice_count(ego_length, s.safety.ego_segment_length)
            > PlannerSettings::MAX_EGO_SEGMENTS as f64
        {
            return Err(PlannerError::BadProblem {
                field: "sizes",
                reason: format!(
                    "the ego (agent 0) of length {ego_length} m needs more than \
                     MAX_EGO_SEGMENTS = {} slices of ego_segment_length = {} m",
                    PlannerSettings::MAX_EGO_SEGMENTS,
                    s.safety.ego_segment_length
                ),
            });
        }
        if predictor.horizon() != self.settings.model.horizon {
            return Err(PlannerError::HorizonMismatch {
                predictor: predictor.horizon(),
                planner: self.settings.model.horizon,
            });
        }
        Ok(())
    }

    /// Solves the linearised problem this planner's next [`Planner::plan`] call would set up
    /// (same nominal, same warm start) as ONE Clarabel QP in (Δ, α, Z), without the safety
    /// constraint. With no vehicle in range, ADMM converges to this solution.
    ///
    /// # Errors
    /// As [`Planner::plan`] for a malformed problem; [`PlannerError::QpSetup`] /
    /// [`PlannerError::QpFailed`] (QP `joint`) when Clarabel does not solve it.
    pub fn reference_qp(
        &self,
        problem: &PlanningProblem<'_>,
    ) -> Result<JointSolution, PlannerError> {
        problem.check()?;
        let lp = LinearisedProblem::new(&self.settings, &self.model, self.warm.as_ref(), problem);
        reference::solve_joint(&self.settings, &lp)
    }
}

/// How the ADMM loop ended.
struct AdmmRun {
    stop: Stop,
    iterations: usize,
    qp_solves: usize,
}

/// The ADMM loop: Δ-update, α-update, Z-update and dual update until both residuals meet their
/// tolerances ([`Stop::Converged`]), `max_iter` iterations, a QP failure or the budget.
fn admm_loop(
    s: &PlannerSettings,
    lp: &mut LinearisedProblem,
    ws: &mut Workspace,
    safety: &mut SafetyEval<'_>,
    predictor: &mut dyn Predictor,
    timings: &mut PhaseTimings,
) -> Result<AdmmRun, PlannerError> {
    let mut qps = match InputQps::new(s, lp) {
        Ok(qps) => qps,
        Err(failure) => {
            return Ok(AdmmRun {
                stop: Stop::SolverFailed(failure),
                iterations: 0,
                qp_solves: 0,
            });
        }
    };
    let mut stop = Stop::MaxIterations;
    let mut iterations = 0;
    for iteration in 0..s.admm.max_iter {
        if safety.budget.spent(safety.calls) {
            stop = Stop::Budget;
            break;
        }
        iterations = iteration + 1;
        let (delta_s, alpha_s) = (&mut timings.delta_s, &mut timings.alpha_s);
        let inputs = qps
            .update(Input::Steering, s, lp, ws, iteration, delta_s)
            .and_then(|()| qps.update(Input::Acceleration, s, lp, ws, iteration, alpha_s));
        if let Err(failure) = inputs {
            stop = Stop::SolverFailed(failure);
            break;
        }
        ws.update_z(s, lp, safety, predictor, timings)?;
        let converged = ws.update_duals(s, lp);
        if safety.budget.exhausted {
            stop = Stop::Budget;
            break;
        }
        if converged {
            stop = Stop::Converged;
            break;
        }
    }
    Ok(AdmmRun {
        stop,
        iterations,
        qp_solves: qps.solves(),
    })
}

impl AdmmResult {
    /// The workspace's iterates after the loop stopped.
    fn new(ws: Workspace, stop: Stop, iterations: usize, qp_solves: usize) -> Self {
        Self {
            iterations,
            change_residual: ws.change,
            qp_solves,
            iterates: ws.iterates,
            stop,
        }
    }
}

/// The constant-velocity predictor, set to the problem's scene, under which a lattice
/// sequence must hit nobody to replace the fallback ([`repair`]); `None` when nothing is
/// checked.
fn nonreactive_predictor(
    constraint: &SafetyConstraint,
    problem: &PlanningProblem<'_>,
    horizon: usize,
) -> Result<Option<ConstantVelocity>, PlannerError> {
    if constraint.vehicles().is_empty() {
        return Ok(None);
    }
    let mut cv = ConstantVelocity::new(horizon)?;
    cv.set_scene(problem.history)?;
    Ok(Some(cv))
}

/// The execution check: the ADMM roll-out when admissible, else the repairs in order
/// (refinement, backtracking, the best fallback); with nothing admissible the least-violating
/// of the roll-out and the best fallback. Every outcome names what decided it.
fn check_execution(r: &mut Repairer<'_, '_>, admm: AdmmResult) -> Result<Finished, PlannerError> {
    let Iterates {
        delta,
        accel,
        z: admm_z,
        ..
    } = admm.iterates;
    let counts = (admm.iterations, admm.change_residual, admm.qp_solves);
    let status = match admm.stop {
        Stop::SolverFailed(failure) => {
            let c = r.best_fallback()?;
            let status = PlanStatus::SolverFailed {
                qp: failure.qp,
                status: failure.status,
            };
            let by = fallback(&c);
            return Ok(Finished::adopt(c, Vec::new(), (status, by), counts));
        }
        Stop::Converged => PlanStatus::Converged,
        Stop::MaxIterations => PlanStatus::MaxIterations,
        Stop::Budget => PlanStatus::BudgetExhausted,
    };
    let rollout = r.check(delta, accel)?;
    let admm_by = if rollout.governed {
        DecidedBy::AdmmGoverned
    } else {
        DecidedBy::Admm
    };
    if rollout.rank.safe {
        return Ok(Finished::adopt(rollout, admm_z, (status, admm_by), counts));
    }
    let unsafe_outcome = if status == PlanStatus::BudgetExhausted {
        // The budget's reserved second call: the shifted previous plan.
        let nominal = r.check(r.lp.nominal_delta.clone(), r.lp.nominal_accel.clone())?;
        if nominal.rank.safe {
            let outcome = (PlanStatus::BudgetExhausted, DecidedBy::Nominal);
            return Ok(Finished::adopt(nominal, admm_z, outcome, counts));
        }
        (nominal, DecidedBy::Nominal)
    } else {
        if let Some(c) = r.refine(&rollout)? {
            let outcome = (PlanStatus::Refined, DecidedBy::Refined);
            return Ok(Finished::adopt(c, admm_z, outcome, counts));
        }
        if let Some(c) = r.backtrack(&rollout.delta, &rollout.accel)? {
            let outcome = (PlanStatus::Backtracked, DecidedBy::Backtracked);
            return Ok(Finished::adopt(c, admm_z, outcome, counts));
        }
        let c = r.best_fallback()?;
        let by = fallback(&c);
        if c.rank.safe {
            return Ok(Finished::adopt(
                c,
                admm_z,
                (PlanStatus::Fallback, by),
                counts,
            ));
        }
        (c, by)
    };
    // Nothing admissible: the least-violating of the repair and the ADMM roll-out.
    let (best, by) = if unsafe_outcome.0.rank.beats(&rollout.rank) {
        unsafe_outcome
    } else {
        (rollout, admm_by)
    };
    Ok(Finished::adopt(
        best,
        admm_z,
        (PlanStatus::Unsafe, by),
        counts,
    ))
}

/// What decided a candidate returned by [`Repairer::best_fallback`].
fn fallback(c: &Candidate) -> DecidedBy {
    let (family, key) = c.chosen.unwrap_or((Family::Nominal, None));
    DecidedBy::Fallback { family, key }
}

impl Finished {
    /// The plan of candidate `c` with its (status, what decided it); `counts` = (iterations,
    /// change residual, QP solves) of the ADMM loop.
    fn adopt(
        c: Candidate,
        admm_z: Vec<State>,
        (status, decided_by): (PlanStatus, DecidedBy),
        counts: (usize, f64, usize),
    ) -> Self {
        Self {
            delta: c.delta,
            accel: c.accel,
            z: c.rollout,
            admm_z,
            min_b: c.min_b,
            rollout_min_b: c.min_b,
            status,
            decided_by,
            iterations: counts.0,
            change_residual: counts.1,
            qp_solves: counts.2,
        }
    }

    /// The plan in the road frame and the next call's warm start; `counts` = (predictor
    /// calls, checked vehicles, refused candidates).
    fn into_plan(
        self,
        s: &PlannerSettings,
        lp: &LinearisedProblem,
        counts: (usize, usize, usize),
        timings: PhaseTimings,
    ) -> (Plan, WarmStart) {
        let mut residual = vec![State::zeros(); lp.horizon];
        lp.linearisation
            .residual(&self.delta, &self.accel, &self.z, &mut residual);
        let plan = Plan {
            states: lp.to_world(&self.z),
            admm_states: lp.to_world(&self.admm_z),
            cost: lp.cost(s, &self.delta, &self.accel, &self.z),
            primal_residual: max_abs(&residual),
            delta: self.delta.clone(),
            accel: self.accel.clone(),
            iterations: self.iterations,
            predictor_calls: counts.0,
            refused_candidates: counts.2,
            qp_solves: self.qp_solves,
            change_residual: self.change_residual,
            min_safety: self.min_b,
            rollout_min_safety: self.rollout_min_b,
            checked: counts.1,
            lane_violation: lp.lane_violation(&self.z),
            violation: lp.violation(s.safety.safety_min, &self.z, self.min_b),
            timings,
            status: self.status,
            decided_by: self.decided_by,
            budget_reached: None,
        };
        let warm = WarmStart {
            delta: self.delta,
            accel: self.accel,
        };
        (plan, warm)
    }
}
