//! One closed-loop lane change ([`simulate`]): at every step, plan; apply the first input to
//! the vehicle; move the other vehicles with the world ([`super::world`]); shift the
//! histories; record the step's safety (the planner's own constraint,
//! [`SafetyConstraint::executed_min_b`]) and judge it ([`super::metrics`]); stop when the ego
//! has settled in the target lane.

use std::time::Instant;

use nudge_predictor::limits::MAX_AGENT_OFFSET;
use nudge_predictor::{Checked, History, Predictor, T_OBS};

use crate::error::SimError;
use crate::policy::Policy;
use nudge_planner::State;
use nudge_planner::extents::LaneViolationKind;
use nudge_planner::lane::{LaneChange, Neighbour};
use nudge_planner::scenario::Scenario;
use nudge_planner::settings::PlannerSettings;
use nudge_planner::{
    Bicycle, EgoState, Plan, Planner, PlannerError, PlanningProblem, SafetyConstraint,
};

use super::config::SimConfig;
use super::metrics::{RunObserver, others_from_history};
use super::records::{RunOutcome, RunRecord, StepRecord, StepStatus, StepTrace};
use super::world::{Mover, WorldModel};

/// The cancellation flag shared by the runs of a batch and whoever may stop it (a Ctrl-C
/// handler, a time limit): once [`Cancel::cancel`] is called, every run stops with
/// [`SimError::Cancelled`] — within its current planning step, which the planner ends within
/// one predictor call ([`nudge_planner::Cancel`]) — and the runs not started yet do not
/// start. Clones share the flag.
pub use nudge_planner::Cancel;

/// SplitMix64: a tiny deterministic generator for the target-lane draw.
fn splitmix(seed: u64) -> u64 {
    let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// How far ahead of the ego (m) an adjacent lane must still run to be drawn as the target
/// ([`target_lane`]): the distance the ego covers over the whole run at its speed,
/// `max_steps` · `dt` · v_0 (v_0: its speed at the last observed step), plus
/// `deadline_distance` (where the planner starts to count a lane's end). A lane that really
/// ends within this distance of the ego's x ends before the ego could finish a change into it
/// and travel on: the ego would settle in it only to face its end (on US-101 the auxiliary
/// lane, offered to egos in the lane beside it 44 m before its end). At the defaults
/// (30 steps of 0.3 s, 100 m) an ego at 20 m/s needs 280 m.
#[must_use]
pub fn target_reach(sc: &Scenario, settings: &PlannerSettings, cfg: &SimConfig) -> f64 {
    let v0 = sc.speed.first().copied().unwrap_or(0.0).max(0.0);
    cfg.max_steps as f64 * settings.model.dt * v0 + settings.lane_ends.deadline_distance
}

/// The target lane drawn from `seed` for a run of `sc` under `settings` and `cfg`: an adjacent
/// lane of the ego's that exists. On a scene with lane extents the adjacent lane must be open
/// where the ego is (not before its real begin nor past its real end at the ego's x), must not
/// really end within [`target_reach`] of the ego's x, and when the ego's own lane really ends,
/// must still run at that end: the ego merges out of a lane that ends, never into one that
/// ends before it or soon after. Only real begins and ends count, so on a scene without them
/// (or without extents) the draw depends on `seed` and the scene alone. The one rule of every
/// front end (the simulator, the CLI and Python's `Scenario.target_lane`).
///
/// # Errors
/// [`SimError::NoAdjacentLane`] on a one-lane road, or when no adjacent lane is open.
pub fn target_lane(
    sc: &Scenario,
    seed: u64,
    settings: &PlannerSettings,
    cfg: &SimConfig,
) -> Result<usize, SimError> {
    let mut options = Vec::new();
    if sc.ego_lane > 0 {
        options.push(sc.ego_lane - 1);
    }
    if sc.ego_lane + 1 < sc.lane_centres.len() {
        options.push(sc.ego_lane + 1);
    }
    if let Some(ext) = &sc.lane_extents
        && let Some(&own) = ext.get(sc.ego_lane)
    {
        let x = sc.position(0, T_OBS - 1)[0];
        let reach = x + target_reach(sc, settings, cfg);
        options.retain(|&j| {
            let Some(&e) = ext.get(j) else {
                return false;
            };
            let closed = (e.begins && x < e.begin) || (e.ends && x > e.end);
            let outlasts = !own.ends || !e.ends || e.end >= own.end;
            let ends_within_reach = e.ends && e.end < reach;
            !closed && outlasts && !ends_within_reach
        });
    }
    if options.is_empty() {
        return Err(SimError::NoAdjacentLane {
            scene: sc.name.clone(),
            ego_lane: sc.ego_lane,
            lanes: sc.lane_centres.len(),
        });
    }
    Ok(options[((splitmix(seed) >> 32) % options.len() as u64) as usize])
}

/// Whether the ego in `ego` (x, y, ψ, v) waits in a lane of `sc` that really ends ahead of
/// its centre (not past the end), at most `within` (m) ahead.
fn waiting(sc: &Scenario, ego: &State, within: f64) -> bool {
    sc.lanes()
        .and_then(|l| l.stop_line(ego[0], ego[1], 0.0))
        .is_some_and(|end| end - ego[0] <= within)
}

/// The state of one run between steps.
struct ClosedLoop<'a> {
    sc: &'a Scenario,
    settings: &'a PlannerSettings,
    /// What plans the ego's motion.
    policy: &'a mut dyn Policy,
    /// The ego's dynamics (the planner settings' bicycle model).
    model: Bicycle,
    /// Observed positions per agent, `[n][T_OBS]` (m).
    observed: Vec<Vec<[f64; 2]>>,
    ego: State,
    v_ref: f64,
    last_inputs: (f64, f64),
    lane: LaneChange,
    observer: RunObserver,
    /// Keep each step's [`StepTrace`].
    trace: bool,
}

/// How one run is run besides its settings: when it stops early and what it records beyond
/// its columns.
#[derive(Debug, Clone, Copy)]
pub struct RunControl<'c> {
    /// Checked before every closed-loop step: once set, the run stops with
    /// [`SimError::Cancelled`].
    pub cancel: &'c Cancel,
    /// Keep every step's plan and the planning predictor's predicted reaction to it
    /// ([`StepRecord::trace`]; one more predictor call per step). Off, the records are those of
    /// an untraced run, bit for bit.
    pub trace: bool,
}

impl ClosedLoop<'_> {
    /// The reference speed of the next planning step: the run's starting speed, raised by the
    /// lane change's flow-speed floor and moved by its gap seeking ([`LaneChange::v_ref`])
    /// among the vehicles as last observed, at most the planner's `v_max`.
    fn v_ref(&mut self) -> f64 {
        let others: Vec<Neighbour> = others_from_history(self.sc, &self.observed)
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

    /// The agents the planner and a teacher world see at this step (scene indices, the ego
    /// first; see [`view_of`]).
    fn view(&self) -> Vec<usize> {
        view_of(&self.observed)
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

    /// The trace of a step planned from `history` with the ego at `ego` (the measured state):
    /// the plan from `ego`, the planning predictor's prediction of the others given the plan
    /// (given the keep-lane path when the reaction is ablated; checked finite and plausible), the binding vehicle under that prediction, and the
    /// agents' positions `moved` after the step.
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

    /// Applies the plan's first input, moves the others, shifts the histories; returns the
    /// step's record.
    fn step(
        &mut self,
        step: usize,
        planner_pred: &mut dyn Predictor,
        mover: &mut Mover<'_>,
    ) -> Result<StepRecord, SimError> {
        let sc = self.sc;
        let view = self.view();
        let history = self.history(&view)?;
        let sizes: Vec<[f64; 2]> = view.iter().map(|&i| sc.size[i]).collect();
        let v_ref = self.v_ref();
        let problem = PlanningProblem {
            ego: EgoState {
                x: self.ego[0],
                y: self.ego[1],
                psi: self.ego[2],
                v: self.ego[3].max(0.0),
            },
            last_delta: self.last_inputs.0,
            last_accel: self.last_inputs.1,
            history: &history,
            sizes: &sizes,
            y_target: self.lane.goal(),
            v_ref,
            road: sc.road(),
            y_retreat: self.lane.retreat(self.ego[1]),
            lanes: sc.lanes(),
        };
        let t0 = Instant::now();
        let plan: Plan = self.policy.plan(&problem, planner_pred).map_err(
            |source: PlannerError| match source {
                PlannerError::Cancelled => SimError::Cancelled {
                    scene: self.sc.name.clone(),
                    step,
                },
                source => SimError::Planner {
                    scene: self.sc.name.clone(),
                    step,
                    source,
                },
            },
        )?;
        let mpc_s = t0.elapsed().as_secs_f64();
        let status = StepStatus::from(plan.status);
        let y_goal = problem.y_target;
        let constraint = SafetyConstraint::new(&problem, self.settings);
        self.lane.after_plan(status, self.ego[1]);
        let next = self.model.advance(&self.ego, plan.delta[0], plan.accel[0]);
        let moved = mover.advance(
            sc,
            &history,
            &view,
            &self.observed,
            step,
            &self.ego,
            &next,
            &plan.states,
        )?;
        let trace = if self.trace {
            let e = &problem.ego;
            let measured = [e.x, e.y, e.psi, e.v];
            let t = self.trace(
                &history,
                &view,
                measured,
                &plan,
                &constraint,
                planner_pred,
                &moved,
            )?;
            Some(t)
        } else {
            None
        };
        let moved_view: Vec<[f64; 2]> = view.iter().map(|&i| moved[i]).collect();
        for (h, p) in self.observed.iter_mut().zip(&moved) {
            h.remove(0);
            h.push(*p);
        }
        self.ego = next;
        self.last_inputs = (plan.delta[0], plan.accel[0]);
        let v_planned = plan.states.last().map_or(next[3], |z| z[3]);
        let others = others_from_history(sc, &self.observed);
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
}

/// The agents the planner (and a teacher world) see, given every agent's observed positions
/// `observed` (`[n][T_OBS]`, m): all of them when every two are at most
/// [`MAX_AGENT_OFFSET`] apart at the last observed step (the predictors' accepted span; every
/// run whose vehicles stay that close is planned exactly as before), otherwise the ego and
/// the agents within [`MAX_AGENT_OFFSET`] / 2 of it (so any two of them are within the span).
/// A vehicle 500 m from the ego cannot matter within a planning horizon of seconds; it is
/// still simulated, judged by the metrics and drawn. Scene indices, ascending, the ego first.
#[must_use]
pub fn view_of(observed: &[Vec<[f64; 2]>]) -> Vec<usize> {
    let n = observed.len();
    let last = |i: usize| observed[i][T_OBS - 1];
    let d2 = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
    let span2 = MAX_AGENT_OFFSET * MAX_AGENT_OFFSET;
    if (0..n).all(|i| (i + 1..n).all(|j| d2(last(i), last(j)) <= span2)) {
        return (0..n).collect();
    }
    let half2 = span2 / 4.0;
    (0..n)
        .filter(|&i| i == 0 || d2(last(i), last(0)) <= half2)
        .collect()
}

/// The path of an agent observed at `observed` (`[T_OBS]`, m) over `t` steps at its last
/// observed displacement per step (m): k-th point = last + k · (last − previous).
pub(crate) fn constant_velocity(observed: &[[f64; 2]], t: usize) -> Vec<[f64; 2]> {
    let last = observed[T_OBS - 1];
    let prev = observed[T_OBS - 2];
    (1..=t)
        .map(|k| {
            let k = k as f64;
            [
                last[0] + k * (last[0] - prev[0]),
                last[1] + k * (last[1] - prev[1]),
            ]
        })
        .collect()
}

/// Runs one closed-loop lane change of scenario `sc` towards the lane drawn from `seed`.
///
/// `planner_pred` predicts inside the MPC; `world` moves the other vehicles and must match
/// `cfg.world`: the teacher of a [`crate::World::Teacher`] world, the driver population of a
/// [`crate::World::Idm`] world, nothing for [`crate::World::LogReplay`]. Every step is judged
/// by [`crate::metrics`] (per step in [`StepRecord::metrics`], per run in
/// [`RunRecord::metrics`] and [`RunRecord::collisions`]); a run with a collision is never a
/// success.
///
/// # Errors
/// [`SimError::Settings`] / [`SimError::Config`] for invalid settings or settings that do not
/// fit the predictors and scenes ([`nudge_planner::fit::check_closed_loop`]),
/// [`SimError::WorldModel`] when `world` does not match `cfg.world`,
/// [`SimError::NoAdjacentLane`], [`SimError::Predictor`] (the scene does not fit a predictor),
/// [`SimError::Planner`] when planning fails (a bad problem or a predictor error; a QP failure
/// is a [`StepStatus::SolverFailed`] step).
///
/// # Examples
///
/// A lane change on a shipped real scene, planned with constant velocity, the others
/// following their logged trajectories:
///
/// ```
/// use nudge_planner::{PlannerSettings, Scenario};
/// use nudge_sim::{SimConfig, World, WorldModel, simulate};
/// use nudge_predictor::ConstantVelocity;
///
/// let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
///     .join("../../assets/scenes/us101-11_1-t02.1-ego144.safetensors");
/// let sc = Scenario::from_file(&scene)?;
/// let cfg = SimConfig { world: World::LogReplay, ..SimConfig::default() };
/// let mut cv = ConstantVelocity::default();
/// let run = simulate(&sc, &PlannerSettings::default(), &cfg, 0, &mut cv, WorldModel::LogReplay)?;
/// assert!(run.success && !run.collision);
/// assert_eq!(run.metrics.collisions_at_fault + run.metrics.off_road_steps, 0);
/// assert_eq!(run.steps.len(), run.steps_to_target.unwrap_or(0));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn simulate(
    sc: &Scenario,
    settings: &PlannerSettings,
    cfg: &SimConfig,
    seed: u64,
    planner_pred: &mut dyn Predictor,
    world: WorldModel<'_>,
) -> Result<RunRecord, SimError> {
    let never = Cancel::new();
    let control = RunControl {
        cancel: &never,
        trace: false,
    };
    simulate_with(sc, settings, cfg, seed, planner_pred, world, control)
}

/// [`simulate`] under `control`: checking its cancel flag before every closed-loop step and,
/// when it asks to trace, keeping every step's [`StepTrace`].
///
/// # Errors
/// As [`simulate`]; [`SimError::Cancelled`] once the cancel flag is set;
/// [`SimError::Predictor`] when the traced prediction fails.
pub fn simulate_with(
    sc: &Scenario,
    settings: &PlannerSettings,
    cfg: &SimConfig,
    seed: u64,
    planner_pred: &mut dyn Predictor,
    world: WorldModel<'_>,
    control: RunControl<'_>,
) -> Result<RunRecord, SimError> {
    cfg.validate()?;
    let mut planner = Planner::new(settings.clone()).map_err(|e| match e {
        PlannerError::Settings(s) => SimError::Settings(s),
        other => SimError::Planner {
            scene: sc.name.clone(),
            step: 0,
            source: other,
        },
    })?;
    // The flag also ends a planning step in progress, within one predictor call.
    planner.set_cancel(Some(control.cancel.clone()));
    simulate_policy(
        sc,
        settings,
        cfg,
        seed,
        &mut planner,
        planner_pred,
        world,
        control,
    )
}

/// [`simulate_with`] with the ego driven by `policy` instead of a [`Planner`] built from
/// `settings` (which still give the ego's model, the safety check the records judge the plans
/// by, the lane-end rules and the planning horizon the world predicts over). The policy is
/// [`Policy::reset`] before the first step.
///
/// # Errors
/// As [`simulate_with`].
#[allow(clippy::too_many_arguments)]
pub fn simulate_policy(
    sc: &Scenario,
    settings: &PlannerSettings,
    cfg: &SimConfig,
    seed: u64,
    policy: &mut dyn Policy,
    planner_pred: &mut dyn Predictor,
    world: WorldModel<'_>,
    control: RunControl<'_>,
) -> Result<RunRecord, SimError> {
    let cancel = control.cancel;
    cfg.validate()?;
    settings.validate()?;
    policy.reset();
    let mut fit = vec![(planner_pred.name(), planner_pred.horizon())];
    if let WorldModel::Teacher(w) = &world {
        fit.push((w.name(), w.horizon()));
    }
    nudge_planner::fit::check_closed_loop(settings, &fit)?;
    let lane = target_lane(sc, seed, settings, cfg)?;
    let mut mover = Mover::new(cfg, world, sc, seed, settings.model.horizon)?;
    let y_target = sc.lane_centres[lane];
    let p0 = sc.position(0, T_OBS - 1);
    let mut run = ClosedLoop {
        sc,
        settings,
        policy,
        model: Bicycle {
            l_f: settings.model.l_f,
            l_r: settings.model.l_r,
            dt: settings.model.dt,
        },
        observed: (0..sc.n_agents)
            .map(|i| (0..T_OBS).map(|t| sc.position(i, t)).collect())
            .collect(),
        ego: State::new(p0[0], p0[1], sc.heading[0], sc.speed[0]),
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
        observer: RunObserver::new(sc, lane, cfg.fault_brake_limit, settings.model.l_r),
        trace: control.trace,
    };
    let mut rec = RunRecord {
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
        metrics: super::metrics::RunMetrics::default(),
        aborts: 0,
        outcome: RunOutcome::Unfinished,
        steps: Vec::new(),
    };
    let mut lane_out = None;
    let mut settled = 0;
    for step in 0..cfg.max_steps {
        if cancel.is_cancelled() {
            return Err(SimError::Cancelled {
                scene: sc.name.clone(),
                step,
            });
        }
        // An ego turned across the road (only seen with erratic predictors) ends the run as a
        // failure instead of handing the planner a problem it rejects.
        if run.ego[2].abs() >= std::f64::consts::FRAC_PI_2 {
            break;
        }
        let record = run.step(step, planner_pred, &mut mover)?;
        rec.collision |= record.collision;
        rec.steps.push(record);
        let ego = run.ego;
        // A lane that ended (or has not begun) under the ego's centre ends the run as failed.
        lane_out = sc.lanes().and_then(|l| l.outside(ego[0], ego[1]));
        if lane_out.is_some() {
            break;
        }
        if (ego[1] - y_target).abs() <= cfg.settle_y && ego[2].abs() <= cfg.settle_psi {
            settled += 1;
        } else {
            settled = 0;
        }
        if settled >= cfg.settle_steps {
            rec.steps_to_target = Some(step + 1);
            break;
        }
    }
    let waits = waiting(sc, &run.ego, settings.lane_ends.deadline_distance);
    finish_record(&mut rec, lane_out, waits);
    rec.aborts = run.lane.aborts();
    (rec.collisions, rec.metrics) = run.observer.finish(rec.success);
    Ok(rec)
}

/// Success and outcome of a run that has stopped: a run with any collision is never a success;
/// `lane_out` is the lane violation that ended it, `waits` whether the ego waits at the end of
/// its lane for a gap.
fn finish_record(rec: &mut RunRecord, lane_out: Option<(usize, LaneViolationKind)>, waits: bool) {
    if rec.collision {
        rec.steps_to_target = None;
    }
    rec.success = rec.steps_to_target.is_some();
    rec.outcome = if rec.collision {
        RunOutcome::Collision
    } else {
        match lane_out {
            Some((_, LaneViolationKind::Ended)) => RunOutcome::LaneEnded,
            Some((_, LaneViolationKind::NotBegun)) => RunOutcome::LaneNotBegun,
            None if rec.success => RunOutcome::Success,
            None if waits => RunOutcome::Waiting,
            None => RunOutcome::Unfinished,
        }
    };
}
