//! The closed loop one step at a time ([`Session`]): the one implementation of a run, driven
//! by [`crate::simulate_policy`] (plan and advance until the run ends) and by anything that
//! steps it itself (the Gymnasium environment of `nudge.env`, where an agent outside nudge
//! chooses each step's inputs).
//!
//! A step has two halves: [`Session::plan`] asks a [`Policy`] for the step's plan from the
//! step's observation ([`Session::problem`]) and keeps it pending; [`Session::advance`]
//! applies the pending plan's first input to the ego, moves the others with the world, shifts
//! the histories, judges the step and decides whether the run ends ([`EndReason`]).
//! [`Session::step`] does both. [`Session::finish`] gives the run's record.

use std::borrow::Cow;
use std::time::Instant;

use nudge_predictor::{Checked, History, Predictor, T_OBS};

use crate::error::SimError;
use crate::policy::Policy;
use nudge_planner::State;
use nudge_planner::extents::LaneViolationKind;
use nudge_planner::lane::{LaneChange, Neighbour};
use nudge_planner::scenario::Scenario;
use nudge_planner::settings::PlannerSettings;
use nudge_planner::{
    Bicycle, EgoState, Plan, PlannerError, PlanningProblem, SafetyConstraint, StepStatus,
};

use super::config::SimConfig;
use super::metrics::{RunMetrics, RunObserver, others_from_history};
use super::records::{RunOutcome, RunRecord, StepRecord, StepTrace};
use super::run::{constant_velocity, finish_record, target_lane, view_of, waiting};
use super::world::{Mover, WorldModel};

/// Why a closed-loop run stopped stepping (its [`RunOutcome`] is decided by
/// [`Session::finish`] from this and the collisions).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum EndReason {
    /// The ego settled in the target lane: within `settle_y` of its centre and `settle_psi` of
    /// the road's heading for `settle_steps` steps in a row.
    Settled,
    /// The ego's centre lies in a lane that has ended or not begun (scenes with lane
    /// extents).
    LaneOut(LaneViolationKind),
    /// The ego turned across the road (|ψ| ≥ π/2).
    TurnedAcross,
    /// `max_steps` steps ran without any of the above.
    MaxSteps,
}

impl EndReason {
    /// The name: `settled`, `lane_ended`, `lane_not_begun`, `turned_across`, `max_steps`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Settled => "settled",
            Self::LaneOut(LaneViolationKind::Ended) => "lane_ended",
            Self::LaneOut(LaneViolationKind::NotBegun) => "lane_not_begun",
            Self::TurnedAcross => "turned_across",
            Self::MaxSteps => "max_steps",
        }
    }

    /// Whether the run's own rules ended it (`true`), or the step limit (`false`): a
    /// Gymnasium episode is `terminated` in the first case and `truncated` in the second.
    #[must_use]
    pub fn is_terminal(self) -> bool {
        self != Self::MaxSteps
    }
}

impl std::fmt::Display for EndReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What the current step's observation is made of, computed once per step (the gap-seeking
/// reference speed moves the lane change's state).
struct Prepared {
    /// The agents the planner sees (scene indices, the ego first; [`view_of`]).
    view: Vec<usize>,
    /// Their observed positions as the predictors take them.
    history: History,
    /// Their (length, width) (m).
    sizes: Vec<[f64; 2]>,
    /// The reference speed (m/s).
    v_ref: f64,
    /// The lateral goal (m).
    y_target: f64,
    /// The lane the ego may fall back to (m).
    y_retreat: Option<f64>,
}

/// One closed-loop run, stepped by its caller: the state between steps of a lane change of
/// one scene towards the lane drawn from one seed (see the module documentation).
///
/// The scene and the planner settings are borrowed or owned ([`Cow`]): a session that must
/// outlive its caller's borrows (Python's environment) owns copies. The planning predictor,
/// the world model and the policy are handed to each call instead of held, and must be the
/// same kinds throughout the run (a world model of another world is refused).
///
/// After an error the session is left mid-step: drop it.
pub struct Session<'a> {
    sc: Cow<'a, Scenario>,
    settings: Cow<'a, PlannerSettings>,
    cfg: SimConfig,
    /// Moves the other vehicles (its per-run state).
    mover: Mover,
    /// The ego's dynamics (the planner settings' bicycle model).
    model: Bicycle,
    /// Observed positions per agent, `[n][T_OBS]` (m).
    observed: Vec<Vec<[f64; 2]>>,
    ego: State,
    /// The run's starting speed (m/s), the base of every step's reference speed.
    v_ref: f64,
    last_inputs: (f64, f64),
    lane: LaneChange,
    observer: RunObserver,
    /// Keep each step's [`StepTrace`].
    trace: bool,
    rec: RunRecord,
    /// Steps in a row settled in the target lane.
    settled: usize,
    /// The lane violation that ended the run.
    lane_out: Option<(usize, LaneViolationKind)>,
    ended: Option<EndReason>,
    /// The current step's observation, once computed.
    prepared: Option<Prepared>,
    /// The current step's plan, with the wall time of the call that made it (s).
    pending: Option<(Plan, f64)>,
}

impl<'a> Session<'a> {
    /// Starts the run of scenario `sc` towards the lane drawn from `seed` ([`target_lane`]):
    /// nothing has been planned yet. `planner_pred` is the run's planning predictor (named in
    /// the record, checked against the settings' horizon); `world` the model of `cfg.world`.
    /// `trace` keeps every step's plan and predicted reaction ([`StepRecord::trace`]).
    ///
    /// # Errors
    /// [`SimError::Config`] / [`SimError::Settings`] for invalid settings or settings that do
    /// not fit the predictors ([`nudge_planner::fit::check_closed_loop`]),
    /// [`SimError::NoAdjacentLane`], [`SimError::WorldModel`] when `world` does not match
    /// `cfg.world`.
    pub fn new(
        sc: Cow<'a, Scenario>,
        settings: Cow<'a, PlannerSettings>,
        cfg: &SimConfig,
        seed: u64,
        planner_pred: &dyn Predictor,
        world: &WorldModel<'_>,
        trace: bool,
    ) -> Result<Self, SimError> {
        cfg.validate()?;
        settings.validate()?;
        let mut fit = vec![(planner_pred.name(), planner_pred.horizon())];
        if let WorldModel::Teacher(w) = world {
            fit.push((w.name(), w.horizon()));
        }
        nudge_planner::fit::check_closed_loop(&settings, &fit)?;
        let lane = target_lane(&sc, seed, &settings, cfg)?;
        let mover = Mover::new(cfg, world, &sc, seed, settings.model.horizon)?;
        let y_target = sc.lane_centres[lane];
        let p0 = sc.position(0, T_OBS - 1);
        let rec = RunRecord {
            scenario: sc.name.clone(),
            seed,
            predictor: planner_pred.name().to_string(),
            world: cfg.world,
            n_agents: sc.n_agents,
            target_lane: lane,
            y_target,
            success: false,
            steps_to_target: None,
            collision: false,
            collisions: Vec::new(),
            metrics: RunMetrics::default(),
            aborts: 0,
            outcome: RunOutcome::Unfinished,
            steps: Vec::new(),
        };
        let ego = State::new(p0[0], p0[1], sc.heading[0], sc.speed[0]);
        let session = Self {
            model: Bicycle {
                l_f: settings.model.l_f,
                l_r: settings.model.l_r,
                dt: settings.model.dt,
            },
            observed: (0..sc.n_agents)
                .map(|i| (0..T_OBS).map(|t| sc.position(i, t)).collect())
                .collect(),
            ego,
            v_ref: sc.speed[0],
            last_inputs: (0.0, 0.0),
            lane: LaneChange::new(
                sc.lane_centres[sc.ego_lane],
                y_target,
                sc.size[0][1],
                cfg.settle_y,
                cfg.abort_after,
                cfg.abort_hold,
            )
            .with_stall_abort(cfg.stall_progress)
            .with_start_abort(cfg.start_abort_after, p0[1])
            .with_gap_seeking(cfg.gap_speed, cfg.gap_window, sc.size[0][0])
            .with_crawl_reference(cfg.crawl_fraction),
            observer: RunObserver::new(&sc, lane, cfg.fault_brake_limit, settings.model.l_r),
            trace,
            rec,
            settled: 0,
            lane_out: None,
            // An ego turned across the road (only seen with erratic predictors) ends the run
            // as a failure instead of handing the planner a problem it rejects.
            ended: turned(&ego).then_some(EndReason::TurnedAcross),
            prepared: None,
            pending: None,
            cfg: *cfg,
            mover,
            sc,
            settings,
        };
        Ok(session)
    }

    /// The scenario.
    #[must_use]
    pub fn scenario(&self) -> &Scenario {
        &self.sc
    }

    /// The planner settings (the ego's model, the safety check, the horizon).
    #[must_use]
    pub fn settings(&self) -> &PlannerSettings {
        &self.settings
    }

    /// The closed-loop settings.
    #[must_use]
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// The run's record so far: its header and the steps that ran (the outcome, success and
    /// run metrics are set by [`Session::finish`]).
    #[must_use]
    pub fn record(&self) -> &RunRecord {
        &self.rec
    }

    /// The index of the next step (= steps run so far).
    #[must_use]
    pub fn step_index(&self) -> usize {
        self.rec.steps.len()
    }

    /// The ego now: x, y, ψ, v (m, m, rad, m/s).
    #[must_use]
    pub fn ego(&self) -> [f64; 4] {
        [self.ego[0], self.ego[1], self.ego[2], self.ego[3]]
    }

    /// Why the run ended; `None` while it goes on.
    #[must_use]
    pub fn ended(&self) -> Option<EndReason> {
        self.ended
    }

    /// The plan made for the current step and not applied yet ([`Session::plan`]).
    #[must_use]
    pub fn pending(&self) -> Option<&Plan> {
        self.pending.as_ref().map(|(p, _)| p)
    }

    /// Refuses a step of a run that has ended.
    fn check_running(&self) -> Result<(), SimError> {
        match self.ended {
            Some(end) => Err(SimError::Ended {
                scene: self.sc.name.clone(),
                steps: self.rec.steps.len(),
                reason: end.as_str(),
            }),
            None => Ok(()),
        }
    }

    /// Computes the current step's observation once.
    fn prepare(&mut self) -> Result<(), SimError> {
        if self.prepared.is_none() {
            let view = view_of(&self.observed);
            let history = self.history(&view)?;
            let sizes = view.iter().map(|&i| self.sc.size[i]).collect();
            let v_ref = self.next_v_ref();
            self.prepared = Some(Prepared {
                view,
                history,
                sizes,
                v_ref,
                y_target: self.lane.goal(),
                y_retreat: self.lane.retreat(self.ego[1]),
            });
        }
        Ok(())
    }

    /// The current step's planning problem (the observation a [`Policy`] plans from): the
    /// measured ego state, the inputs applied at the previous step, the observed histories
    /// and sizes of the agents in view, the lateral goal, the reference speed, the road and
    /// its lanes. Computed once per step; later calls within the step give the same problem.
    /// After the run has ended it is the problem a next step would have had (what an
    /// environment shows as the final observation).
    ///
    /// # Errors
    /// [`SimError::Predictor`] when the histories do not fit the predictors.
    pub fn problem(&mut self) -> Result<PlanningProblem<'_>, SimError> {
        self.prepare()?;
        let Some(p) = self.prepared.as_ref() else {
            return Err(self.missing("an observation"));
        };
        Ok(problem_of(&self.sc, p, &self.ego, self.last_inputs))
    }

    /// Plans the current step with `policy` (its wall time recorded as the step's `mpc_s`)
    /// and keeps the plan pending for [`Session::advance`], replacing any plan made before in
    /// this step.
    ///
    /// # Errors
    /// [`SimError::Ended`] once the run has ended; as [`Session::problem`];
    /// [`SimError::Planner`] when the policy fails.
    pub fn plan(
        &mut self,
        policy: &mut dyn Policy,
        planner_pred: &mut dyn Predictor,
    ) -> Result<&Plan, SimError> {
        self.check_running()?;
        self.prepare()?;
        let step = self.rec.steps.len();
        let Some(p) = self.prepared.as_ref() else {
            return Err(self.missing("an observation"));
        };
        let problem = problem_of(&self.sc, p, &self.ego, self.last_inputs);
        let t0 = Instant::now();
        let plan =
            policy
                .plan(&problem, planner_pred)
                .map_err(|source: PlannerError| match source {
                    PlannerError::Cancelled => SimError::Cancelled {
                        scene: self.sc.name.clone(),
                        step,
                    },
                    source => SimError::Planner {
                        scene: self.sc.name.clone(),
                        step,
                        source,
                    },
                })?;
        let mpc_s = t0.elapsed().as_secs_f64();
        Ok(&self.pending.insert((plan, mpc_s)).0)
    }

    /// Applies the pending plan's first input to the ego, moves the others with `world`,
    /// shifts the histories, judges the step and decides whether the run ends
    /// ([`Session::ended`]); returns the step's record.
    ///
    /// # Errors
    /// [`SimError::Ended`] once the run has ended; [`SimError::NoPlan`] when no plan is
    /// pending; [`SimError::WorldModel`] when `world` is not the model of the run's world;
    /// [`SimError::Predictor`] when the world's or the traced prediction fails.
    pub fn advance(
        &mut self,
        planner_pred: &mut dyn Predictor,
        world: &mut WorldModel<'_>,
    ) -> Result<&StepRecord, SimError> {
        self.check_running()?;
        crate::world::check(&self.cfg, world)?;
        let step = self.rec.steps.len();
        let Some((plan, mpc_s)) = self.pending.take() else {
            return Err(SimError::NoPlan {
                scene: self.sc.name.clone(),
                step,
            });
        };
        self.prepare()?;
        let Some(prep) = self.prepared.take() else {
            return Err(self.missing("an observation"));
        };
        let record = self.apply(step, &prep, plan, mpc_s, planner_pred, world)?;
        self.rec.collision |= record.collision;
        self.rec.steps.push(record);
        let ego = self.ego;
        let sc = &*self.sc;
        let cfg = &self.cfg;
        // A lane that ended (or has not begun) under the ego's centre ends the run as failed.
        self.lane_out = sc.lanes().and_then(|l| l.outside(ego[0], ego[1]));
        if let Some((_, kind)) = self.lane_out {
            self.ended = Some(EndReason::LaneOut(kind));
        } else {
            let y_target = self.rec.y_target;
            if (ego[1] - y_target).abs() <= cfg.settle_y && ego[2].abs() <= cfg.settle_psi {
                self.settled += 1;
            } else {
                self.settled = 0;
            }
            if self.settled >= cfg.settle_steps {
                self.rec.steps_to_target = Some(step + 1);
                self.ended = Some(EndReason::Settled);
            } else if step + 1 >= cfg.max_steps {
                self.ended = Some(EndReason::MaxSteps);
            } else if turned(&ego) {
                self.ended = Some(EndReason::TurnedAcross);
            }
        }
        match self.rec.steps.last() {
            Some(r) => Ok(r),
            None => Err(self.missing("a step record")),
        }
    }

    /// One whole step: [`Session::plan`] with `policy`, then [`Session::advance`].
    ///
    /// # Errors
    /// As [`Session::plan`] and [`Session::advance`].
    pub fn step(
        &mut self,
        policy: &mut dyn Policy,
        planner_pred: &mut dyn Predictor,
        world: &mut WorldModel<'_>,
    ) -> Result<&StepRecord, SimError> {
        self.plan(policy, planner_pred)?;
        self.advance(planner_pred, world)
    }

    /// The run's record: success (settled, without any collision), outcome, aborts, the
    /// collision events and the run's metrics. A run may be finished before it has ended (it
    /// reads as stopped at the step limit).
    #[must_use]
    pub fn finish(self) -> RunRecord {
        let waits = waiting(
            &self.sc,
            &self.ego,
            self.settings.lane_ends.deadline_distance,
        );
        close(self.rec, self.lane_out, waits, &self.lane, self.observer)
    }

    /// [`Session::finish`] without ending the session (a copy of the record so far, finished).
    #[must_use]
    pub fn result(&self) -> RunRecord {
        let waits = waiting(
            &self.sc,
            &self.ego,
            self.settings.lane_ends.deadline_distance,
        );
        close(
            self.rec.clone(),
            self.lane_out,
            waits,
            &self.lane,
            self.observer.clone(),
        )
    }

    /// An internal invariant broke (never expected): a typed error instead of a panic.
    fn missing(&self, what: &str) -> SimError {
        SimError::WorldModel {
            world: self.cfg.world.as_str(),
            reason: format!(
                "internal: scene {} step {} has no {what}",
                self.sc.name,
                self.rec.steps.len()
            ),
        }
    }

    /// The reference speed of the next planning step: the run's starting speed, raised by the
    /// lane change's flow-speed floor and moved by its gap seeking ([`LaneChange::v_ref`])
    /// among the vehicles as last observed, at most the planner's `v_max`.
    fn next_v_ref(&mut self) -> f64 {
        let others: Vec<Neighbour> = others_from_history(&self.sc, &self.observed)
            .iter()
            .map(|o| Neighbour {
                x: o.bbox.x,
                y: o.bbox.y,
                v: o.vx,
                length: o.bbox.length,
            })
            .collect();
        let horizon_s = self.settings.model.horizon as f64 * self.settings.model.dt;
        let e = &self.ego;
        let v = self
            .lane
            .v_ref(self.v_ref, [e[0], e[1], e[2], e[3]], &others, horizon_s);
        v.min(self.settings.bounds.v_max.max(self.v_ref))
    }

    /// The observed history of the agents `view` as the predictors take it.
    fn history(&self, view: &[usize]) -> Result<History, SimError> {
        let flat: Vec<f64> = view
            .iter()
            .flat_map(|&i| self.observed[i].iter().flat_map(|p| [p[0], p[1]]))
            .collect();
        History::new(flat, view.len()).map_err(|source| SimError::Predictor {
            scene: self.sc.name.clone(),
            source,
        })
    }

    /// Applies `plan` (made from `prep` in `mpc_s` seconds) at `step`: the ego's first
    /// input, the others moved, the histories shifted; returns the step's record.
    fn apply(
        &mut self,
        step: usize,
        prep: &Prepared,
        plan: Plan,
        mpc_s: f64,
        planner_pred: &mut dyn Predictor,
        world: &mut WorldModel<'_>,
    ) -> Result<StepRecord, SimError> {
        let status = StepStatus::from(plan.status);
        let problem = problem_of(&self.sc, prep, &self.ego, self.last_inputs);
        let y_goal = problem.y_target;
        let measured = {
            let e = &problem.ego;
            [e.x, e.y, e.psi, e.v]
        };
        let constraint = SafetyConstraint::new(&problem, &self.settings);
        self.lane.after_plan(status, self.ego[1]);
        let next = self.model.advance(&self.ego, plan.delta[0], plan.accel[0]);
        let moved = self.mover.advance(
            &self.sc,
            world,
            &prep.history,
            &prep.view,
            &self.observed,
            step,
            &self.ego,
            &next,
            &plan.states,
        )?;
        let trace = if self.trace {
            Some(self.trace(
                &prep.history,
                &prep.view,
                measured,
                &plan,
                &constraint,
                planner_pred,
                &moved,
            )?)
        } else {
            None
        };
        let moved_view: Vec<[f64; 2]> = prep.view.iter().map(|&i| moved[i]).collect();
        for (h, p) in self.observed.iter_mut().zip(&moved) {
            h.remove(0);
            h.push(*p);
        }
        self.ego = next;
        self.last_inputs = (plan.delta[0], plan.accel[0]);
        let v_planned = plan.states.last().map_or(next[3], |z| z[3]);
        let others = others_from_history(&self.sc, &self.observed);
        let (metrics, touching, nearest) = self.observer.observe(
            step,
            [next[0], next[1], next[2], next[3]],
            plan.accel[0],
            v_planned,
            &others,
        );
        Ok(StepRecord {
            step,
            mpc_s,
            z_updates_s: plan.timings.z_updates_s,
            iterations: plan.iterations,
            predictor_calls: plan.predictor_calls,
            cost: plan.cost,
            primal_residual: plan.primal_residual,
            min_b: constraint.executed_min_b([next[0], next[1], next[2], next[3]], &moved_view),
            collision: !touching.is_empty(),
            status,
            decided_by: plan.decided_by,
            budget_reached: plan.budget_reached,
            violation: plan.violation,
            delta: plan.delta[0],
            accel: plan.accel[0],
            ego: [next[0], next[1], next[2], next[3]],
            nearest,
            y_goal,
            v_planned,
            lane_violation: plan.lane_violation,
            metrics,
            trace,
        })
    }

    /// The trace of a step planned from `history` with the ego at `ego` (the measured state):
    /// the plan from `ego`, the planning predictor's prediction of the others given the plan
    /// (given the keep-lane path when the reaction is ablated; checked finite and plausible),
    /// the binding vehicle under that prediction, and the agents' positions `moved` after the
    /// step.
    #[allow(clippy::too_many_arguments)]
    fn trace(
        &self,
        history: &History,
        view: &[usize],
        ego: [f64; 4],
        plan: &Plan,
        constraint: &SafetyConstraint,
        planner_pred: &mut dyn Predictor,
        moved: &[[f64; 2]],
    ) -> Result<StepTrace, SimError> {
        let n_others = view.len() - 1;
        let t = plan.states.len();
        let mut prediction = vec![0.0; n_others * t * 2];
        if n_others > 0 {
            // With the reaction ablated the planner's safety check saw the keep-lane path.
            let candidate: Vec<f64> = if self.settings.safety.ablate_reaction {
                let e = EgoState {
                    x: ego[0],
                    y: ego[1],
                    psi: ego[2],
                    v: ego[3],
                };
                nudge_planner::keep_lane_path(&e, t, self.settings.model.dt)
            } else {
                plan.states.iter().flat_map(|z| [z[0], z[1]]).collect()
            };
            let mut checked = Checked::new(planner_pred);
            checked
                .set_scene(history)
                .and_then(|()| checked.predict(&candidate, &mut prediction))
                .map_err(|source| SimError::Predictor {
                    scene: self.sc.name.clone(),
                    source,
                })?;
        }
        let in_view: Vec<Vec<[f64; 2]>> = prediction
            .chunks_exact(t * 2)
            .map(|a| a.chunks_exact(2).map(|p| [p[0], p[1]]).collect())
            .collect();
        // Agents outside the view carry their constant-velocity path (not predicted).
        let mut predicted: Vec<Vec<[f64; 2]>> = (1..self.sc.n_agents)
            .map(|i| constant_velocity(&self.observed[i], t))
            .collect();
        for (j, path) in view.iter().skip(1).zip(in_view) {
            predicted[j - 1] = path;
        }
        let mut states = vec![ego];
        states.extend(plan.states.iter().copied());
        let binding = constraint.binding(&plan.states, &prediction).map(|mut b| {
            b.agent = view[b.agent];
            b
        });
        Ok(StepTrace {
            plan: states,
            predicted,
            binding,
            agents: moved.to_vec(),
        })
    }
}

/// The finished record of a run recorded as `rec` (success, outcome, aborts, collisions and
/// run metrics), `lane_out` the lane violation that ended it, `waits` whether the ego waits
/// at the end of its lane.
fn close(
    mut rec: RunRecord,
    lane_out: Option<(usize, LaneViolationKind)>,
    waits: bool,
    lane: &LaneChange,
    observer: RunObserver,
) -> RunRecord {
    finish_record(&mut rec, lane_out, waits);
    rec.aborts = lane.aborts();
    (rec.collisions, rec.metrics) = observer.finish(rec.success);
    rec
}

/// Whether the ego in `ego` has turned across the road (|ψ| ≥ π/2).
fn turned(ego: &State) -> bool {
    ego[2].abs() >= std::f64::consts::FRAC_PI_2
}

/// The planning problem of a step prepared as `p`, with the ego at `ego` after the inputs
/// `last_inputs` (δ, a).
fn problem_of<'p>(
    sc: &'p Scenario,
    p: &'p Prepared,
    ego: &State,
    last_inputs: (f64, f64),
) -> PlanningProblem<'p> {
    PlanningProblem {
        ego: EgoState {
            x: ego[0],
            y: ego[1],
            psi: ego[2],
            v: ego[3].max(0.0),
        },
        last_delta: last_inputs.0,
        last_accel: last_inputs.1,
        history: &p.history,
        sizes: &p.sizes,
        y_target: p.y_target,
        v_ref: p.v_ref,
        road: sc.road(),
        y_retreat: p.y_retreat,
        lanes: sc.lanes(),
    }
}
