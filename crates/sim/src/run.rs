//! One closed-loop lane change ([`simulate`]): at every step, plan; apply the first input to
//! the vehicle; move the other vehicles with the world ([`super::world`]); shift the
//! histories; record the step's safety (the planner's own constraint,
//! [`nudge_planner::SafetyConstraint::executed_min_b`]) and judge it ([`super::metrics`]);
//! stop when the ego has settled in the target lane. The steps themselves are
//! [`crate::Session`]'s; [`simulate_policy`] runs a session to its end.

use std::borrow::Cow;

use nudge_predictor::limits::MAX_AGENT_OFFSET;
use nudge_predictor::{Predictor, T_OBS};

use crate::error::SimError;
use crate::policy::Policy;
use crate::session::Session;
use nudge_planner::State;
use nudge_planner::extents::LaneViolationKind;
use nudge_planner::scenario::Scenario;
use nudge_planner::settings::PlannerSettings;
use nudge_planner::{Planner, PlannerError};

use super::config::SimConfig;
use super::records::{RunOutcome, RunRecord};
use super::world::WorldModel;

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
pub(crate) fn waiting(sc: &Scenario, ego: &State, within: f64) -> bool {
    sc.lanes()
        .and_then(|l| l.stop_line(ego[0], ego[1], 0.0))
        .is_some_and(|end| end - ego[0] <= within)
}

/// How one run is run besides its settings: when it stops early and what it records beyond
/// its columns.
#[derive(Debug, Clone, Copy)]
pub struct RunControl<'c> {
    /// Checked before every closed-loop step: once set, the run stops with
    /// [`SimError::Cancelled`].
    pub cancel: &'c Cancel,
    /// Keep every step's plan and the planning predictor's predicted reaction to it
    /// ([`crate::StepRecord::trace`]; one more predictor call per step). Off, the records are those of
    /// an untraced run, bit for bit.
    pub trace: bool,
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
/// by [`crate::metrics`] (per step in [`crate::StepRecord::metrics`], per run in
/// [`RunRecord::metrics`] and [`RunRecord::collisions`]); a run with a collision is never a
/// success.
///
/// # Errors
/// [`SimError::Settings`] / [`SimError::Config`] for invalid settings or settings that do not
/// fit the predictors and scenes ([`nudge_planner::fit::check_closed_loop`]),
/// [`SimError::WorldModel`] when `world` does not match `cfg.world`,
/// [`SimError::NoAdjacentLane`], [`SimError::Predictor`] (the scene does not fit a predictor),
/// [`SimError::Planner`] when planning fails (a bad problem or a predictor error; a QP failure
/// is a [`crate::StepStatus::SolverFailed`] step).
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
/// when it asks to trace, keeping every step's [`crate::StepTrace`].
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
    let mut world = world;
    let mut session = Session::new(
        Cow::Borrowed(sc),
        Cow::Borrowed(settings),
        cfg,
        seed,
        planner_pred,
        &world,
        control.trace,
    )?;
    policy.reset();
    while session.ended().is_none() {
        if cancel.is_cancelled() {
            return Err(SimError::Cancelled {
                scene: sc.name.clone(),
                step: session.step_index(),
            });
        }
        session.step(policy, planner_pred, &mut world)?;
    }
    Ok(session.finish())
}

/// Success and outcome of a run that has stopped: a run with any collision is never a success;
/// `lane_out` is the lane violation that ended it, `waits` whether the ego waits at the end of
/// its lane for a gap.
pub(crate) fn finish_record(
    rec: &mut RunRecord,
    lane_out: Option<(usize, LaneViolationKind)>,
    waits: bool,
) {
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
