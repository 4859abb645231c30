//! Closed-loop simulation of lane changes on real scenes: plan, apply the first input to the
//! nonlinear bicycle, move the other vehicles with a world model (a predictor's one-step
//! interactive prediction, or the logged future), shift the histories, repeat.

// SimError carries the planner's and predictor's errors by value; they are rare, cold paths.
#![allow(clippy::result_large_err)]

use std::time::Instant;

use nudge_predictor::{History, Predictor, PredictorError, T_OBS};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::admm::{EgoState, Plan, PlanStatus, Planner, PlanningProblem};
use crate::error::{PlannerError, SimError};
use crate::model::State;
use crate::safety::{Ellipse, OrientedBox, motion_heading};
use crate::scenario::Scenario;
use crate::settings::PlannerSettings;

/// An applied input sequence with its planned states: (δ `[T]`, a `[T]`, states `[T]`).
type InputPlan = (Vec<f64>, Vec<f64>, Vec<[f64; 4]>);

/// How the other vehicles move.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum WorldMode {
    /// One-step interactive prediction of a world-model predictor (the teacher), given the
    /// ego's executed motion.
    Predictor,
    /// The logged future ("future" tensor); constant velocity once the log ends.
    LogReplay,
}

/// Closed-loop settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SimConfig {
    /// Most planning steps per run.
    pub max_steps: usize,
    /// Settled when |y − y_target| ≤ this (m) ...
    pub settle_y: f64,
    /// ... and |ψ| ≤ this (rad) ...
    pub settle_psi: f64,
    /// ... for this many consecutive steps.
    pub settle_steps: usize,
    /// How the others move.
    pub world: WorldMode,
    /// Lane-change abort: after this many consecutive planning steps without a safe
    /// lane-change plan (status `Fallback`, `Unsafe` or a Clarabel failure) while the ego is not
    /// yet wholly inside the target lane, the ego aims back at its own lane's centre instead
    /// of idling across the lane boundary. 0 disables aborts.
    pub abort_after: usize,
    /// Steps an aborted ego keeps aiming at its own lane before it tries the lane change again.
    pub abort_hold: usize,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            max_steps: 30,
            settle_y: 0.3,
            settle_psi: 0.03,
            settle_steps: 2,
            world: WorldMode::Predictor,
            abort_after: 4,
            abort_hold: 3,
        }
    }
}

/// What happened at one closed-loop step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    /// Step index (0-based); time after the start = (step + 1) · 0.3 s.
    pub step: usize,
    /// Wall time of the whole MPC call (s).
    pub mpc_s: f64,
    /// Wall time of each Z-update (s).
    pub z_updates_s: Vec<f64>,
    /// ADMM iterations.
    pub iterations: usize,
    /// Predictor calls.
    pub predictor_calls: usize,
    /// Plan cost J.
    pub cost: f64,
    /// Primal residual ‖F‖∞ of the plan.
    pub primal_residual: f64,
    /// Minimum b_i over the vehicles checked at planning time, at the executed step (ego's and
    /// others' actual new positions); `None` when none is checked.
    pub min_b: Option<f64>,
    /// The ego's box overlaps another vehicle's after this step.
    pub collision: bool,
    /// Planner status (`Converged`, `MaxIterations`, `Unsafe`) or `QpFailed: ...` when the
    /// previous plan, shifted, was applied instead.
    pub status: String,
    /// Applied steering (rad).
    pub delta: f64,
    /// Applied acceleration (m/s²).
    pub accel: f64,
    /// Ego state after the step (x, y, ψ, v).
    pub ego: [f64; 4],
    /// The nearest other vehicle after the step: (agent index, x − x_ego, y − y_ego) (m).
    pub nearest: Option<(usize, f64, f64)>,
    /// Lateral position the planner aimed at this step (m): the target lane's centre, or the
    /// ego's own lane's centre while a lane-change abort holds.
    pub y_goal: f64,
}

/// One closed-loop run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    /// Scenario name.
    pub scenario: String,
    /// Seed that chose the target lane.
    pub seed: u64,
    /// Planning predictor.
    pub predictor: String,
    /// World model (`log_replay` or the predictor's name).
    pub world: String,
    /// Vehicles in the scene (ego included).
    pub n_agents: usize,
    /// Target lane index and its centre y (m).
    pub target_lane: usize,
    /// Target lateral position (m).
    pub y_target: f64,
    /// Settled in the target lane before `max_steps`.
    pub success: bool,
    /// Steps until settled (the last of the `settle_steps` consecutive steps), if successful.
    pub steps_to_target: Option<usize>,
    /// Any step with a bounding-box collision.
    pub collision: bool,
    /// Lane-change aborts ([`SimConfig::abort_after`]).
    pub aborts: usize,
    /// Per-step records.
    pub steps: Vec<StepRecord>,
}

/// SplitMix64: a tiny deterministic generator for the target-lane draw.
fn splitmix(seed: u64) -> u64 {
    let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The target lane drawn from `seed`: an adjacent lane of the ego's that exists.
///
/// # Errors
/// [`SimError::NoAdjacentLane`] on a one-lane road.
pub fn target_lane(sc: &Scenario, seed: u64) -> Result<usize, SimError> {
    let mut options = Vec::new();
    if sc.ego_lane > 0 {
        options.push(sc.ego_lane - 1);
    }
    if sc.ego_lane + 1 < sc.lane_centres.len() {
        options.push(sc.ego_lane + 1);
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

/// Others' heading for the collision boxes: the direction of their last displacement when
/// they move forward (clamped to ±0.5 rad: highway traffic does not turn across the road),
/// otherwise the scenario's heading at the start.
fn heading_of(hist: &[[f64; 2]], fallback: f64) -> f64 {
    motion_heading(hist[T_OBS - 2], hist[T_OBS - 1], fallback)
}

/// Runs one closed-loop lane change.
///
/// `planner_pred` predicts inside the MPC; `world` moves the other vehicles when
/// `cfg.world` is [`WorldMode::Predictor`] (ignored for log replay; `None` there falls back to
/// log replay).
///
/// # Errors
/// [`SimError::Settings`], [`SimError::NoAdjacentLane`], [`SimError::Predictor`] (the scene
/// does not fit the predictor), [`SimError::Planner`] for planner failures other than a
/// Clarabel failure (those are recorded in the step's status and the previous plan, shifted,
/// is applied).
pub fn simulate(
    sc: &Scenario,
    settings: &PlannerSettings,
    cfg: &SimConfig,
    seed: u64,
    planner_pred: &mut dyn Predictor,
    mut world: Option<&mut dyn Predictor>,
) -> Result<RunRecord, SimError> {
    let mut planner = Planner::new(settings.clone()).map_err(|e| match e {
        PlannerError::Settings(s) => SimError::Settings(s),
        other => SimError::Planner {
            scene: sc.name.clone(),
            step: 0,
            source: other,
        },
    })?;
    let t_plan = settings.horizon;
    let lane = target_lane(sc, seed)?;
    let y_target = sc.lane_centres[lane];
    let n = sc.n_agents;
    let mut hist: Vec<Vec<[f64; 2]>> = (0..n)
        .map(|i| (0..T_OBS).map(|t| sc.position(i, t)).collect())
        .collect();
    let p0 = sc.position(0, T_OBS - 1);
    let mut ego = State::new(p0[0], p0[1], sc.heading[0], sc.speed[0]);
    let v_ref = sc.speed[0];
    let (mut last_delta, mut last_accel) = (0.0, 0.0);
    let mut prev_plan: Option<InputPlan> = None;
    let use_world = cfg.world == WorldMode::Predictor && world.is_some();
    let mut rec = RunRecord {
        scenario: sc.name.clone(),
        seed,
        predictor: planner_pred.name().to_string(),
        world: if use_world {
            world
                .as_ref()
                .map_or("log_replay", |w| w.name())
                .to_string()
        } else {
            "log_replay".to_string()
        },
        n_agents: n,
        target_lane: lane,
        y_target,
        success: false,
        steps_to_target: None,
        collision: false,
        aborts: 0,
        steps: Vec::new(),
    };
    // Lane-change abort state: the ego's own lane, how far from the target centre the ego is
    // wholly inside the target lane, consecutive steps without a safe plan, hold steps left.
    let y_own = sc.lane_centres[sc.ego_lane];
    let inside = (0.5 * (y_target - y_own).abs() - 0.5 * sc.size[0][1]).max(cfg.settle_y);
    let (mut unsafe_steps, mut hold) = (0_usize, 0_usize);
    let mut settled = 0;
    let mut world_out = vec![0.0; (n.max(2) - 1) * t_plan * 2];
    let mut world_cand = vec![0.0; t_plan * 2];
    for step in 0..cfg.max_steps {
        // An ego turned across the road (only seen with erratic predictors) ends the run as a
        // failure instead of handing the planner a problem it rejects.
        if ego[2].abs() >= std::f64::consts::FRAC_PI_2 {
            break;
        }
        let flat: Vec<f64> = hist
            .iter()
            .flat_map(|h| h.iter().flat_map(|p| [p[0], p[1]]))
            .collect();
        let history = History::new(flat, n).map_err(|source| SimError::Predictor {
            scene: sc.name.clone(),
            source,
        })?;
        let y_goal = if hold > 0 { y_own } else { y_target };
        let problem = PlanningProblem {
            ego: EgoState {
                x: ego[0],
                y: ego[1],
                psi: ego[2],
                v: ego[3].max(0.0),
            },
            last_delta,
            last_accel,
            history: &history,
            sizes: &sc.size,
            y_target: y_goal,
            v_ref,
            road: sc.road(),
        };
        let t0 = Instant::now();
        let result = planner.plan(&problem, planner_pred);
        let mpc_s = t0.elapsed().as_secs_f64();
        let ((delta, accel, planned), status, plan): (InputPlan, String, Option<Plan>) =
            match result {
                Ok(plan) => (
                    (plan.delta.clone(), plan.accel.clone(), plan.states.clone()),
                    format!("{:?}", plan.status),
                    Some(plan),
                ),
                Err(e @ (PlannerError::QpFailed { .. } | PlannerError::QpSetup { .. })) => {
                    let (d, a, s) = prev_plan.clone().map_or_else(
                        || {
                            let s: Vec<[f64; 4]> = (1..=t_plan)
                                .map(|k| {
                                    let k = k as f64 * settings.dt;
                                    [ego[0] + k * ego[3], ego[1], ego[2], ego[3]]
                                })
                                .collect();
                            (vec![last_delta; t_plan], vec![last_accel; t_plan], s)
                        },
                        |(d, a, s)| {
                            let sh = |v: &[f64]| {
                                let mut o = v[1..].to_vec();
                                o.push(v[v.len() - 1]);
                                o
                            };
                            let mut ss = s[1..].to_vec();
                            ss.push(s[s.len() - 1]);
                            (sh(&d), sh(&a), ss)
                        },
                    );
                    planner.reset();
                    ((d, a, s), format!("QpFailed: {e}"), None)
                }
                Err(source) => {
                    return Err(SimError::Planner {
                        scene: sc.name.clone(),
                        step,
                        source,
                    });
                }
            };
        prev_plan = Some((delta.clone(), accel.clone(), planned.clone()));
        // Abort a lane change that keeps finding no safe plan before the ego is inside the
        // target lane; retry after the hold.
        let no_safe_plan = plan
            .as_ref()
            .is_none_or(|p| matches!(p.status, PlanStatus::Fallback | PlanStatus::Unsafe));
        if hold > 0 {
            hold -= 1;
        } else if cfg.abort_after > 0 && no_safe_plan && (ego[1] - y_target).abs() > inside {
            unsafe_steps += 1;
            if unsafe_steps >= cfg.abort_after {
                hold = cfg.abort_hold;
                unsafe_steps = 0;
                rec.aborts += 1;
            }
        } else {
            unsafe_steps = 0;
        }
        // Apply the first input to the nonlinear model.
        let mut next = planner.model().step(&ego, delta[0], accel[0]);
        next[3] = next[3].max(0.0);
        // Move the others.
        let mut moved: Vec<[f64; 2]> = Vec::with_capacity(n);
        moved.push([next[0], next[1]]);
        if use_world && n > 1 {
            if let Some(w) = world.as_deref_mut() {
                world_cand[0] = next[0];
                world_cand[1] = next[1];
                for k in 1..t_plan {
                    world_cand[2 * k] = planned[k][0];
                    world_cand[2 * k + 1] = planned[k][1];
                }
                w.set_scene(&history)
                    .and_then(|()| w.predict(&world_cand, &mut world_out))
                    .map_err(|source: PredictorError| SimError::Predictor {
                        scene: sc.name.clone(),
                        source,
                    })?;
                for i in 1..n {
                    let b = (i - 1) * t_plan * 2;
                    moved.push([world_out[b], world_out[b + 1]]);
                }
            }
        } else {
            for (i, h) in hist.iter().enumerate().skip(1) {
                let p = sc.future_at(i, step + 1).unwrap_or_else(|| {
                    let a = h[T_OBS - 2];
                    let b = h[T_OBS - 1];
                    [2.0 * b[0] - a[0], 2.0 * b[1] - a[1]]
                });
                moved.push(p);
            }
        }
        for (h, p) in hist.iter_mut().zip(&moved) {
            h.remove(0);
            h.push(*p);
        }
        ego = next;
        last_delta = delta[0];
        last_accel = accel[0];
        // Safety and collisions at the executed step.
        let ego_box = OrientedBox {
            x: ego[0],
            y: ego[1],
            heading: ego[2],
            length: sc.size[0][0],
            width: sc.size[0][1],
        };
        let mut collision = false;
        let mut min_b: Option<f64> = None;
        let mut nearest: Option<(usize, f64, f64)> = None;
        for i in 1..n {
            let (dx, dy) = (moved[i][0] - ego[0], moved[i][1] - ego[1]);
            if nearest.is_none_or(|(_, nx, ny)| dx.hypot(dy) < nx.hypot(ny)) {
                nearest = Some((i, dx, dy));
            }
            let other = OrientedBox {
                x: moved[i][0],
                y: moved[i][1],
                heading: heading_of(&hist[i], sc.heading[i]),
                length: sc.size[i][0],
                width: sc.size[i][1],
            };
            if ego_box.overlaps(&other) {
                collision = true;
            }
            let p = history.at(i, T_OBS - 1);
            if (p[0] - problem.ego.x).hypot(p[1] - problem.ego.y) <= settings.check_range {
                let ell = Ellipse::with_headings(
                    sc.size[0],
                    ego[2],
                    sc.size[i],
                    other.heading,
                    settings.ellipse_scale,
                    settings.margin_x,
                    settings.margin_y,
                );
                let b = ell.value([ego[0], ego[1]], moved[i]);
                min_b = Some(min_b.map_or(b, |m: f64| m.min(b)));
            }
        }
        rec.collision |= collision;
        rec.steps.push(StepRecord {
            step,
            mpc_s,
            z_updates_s: plan
                .as_ref()
                .map(|p| p.timings.z_updates_s.clone())
                .unwrap_or_default(),
            iterations: plan.as_ref().map_or(0, |p| p.iterations),
            predictor_calls: plan.as_ref().map_or(0, |p| p.predictor_calls),
            cost: plan.as_ref().map_or(f64::NAN, |p| p.cost),
            primal_residual: plan.as_ref().map_or(f64::NAN, |p| p.primal_residual),
            min_b,
            collision,
            status,
            delta: delta[0],
            accel: accel[0],
            ego: [ego[0], ego[1], ego[2], ego[3]],
            nearest,
            y_goal,
        });
        if (ego[1] - y_target).abs() <= cfg.settle_y && ego[2].abs() <= cfg.settle_psi {
            settled += 1;
        } else {
            settled = 0;
        }
        if settled >= cfg.settle_steps {
            rec.success = true;
            rec.steps_to_target = Some(step + 1);
            break;
        }
    }
    Ok(rec)
}

/// One run of a batch: which scenario (index into the slice) and which seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunSpec {
    /// Index into the scenario slice.
    pub scenario: usize,
    /// Target-lane seed.
    pub seed: u64,
}

/// A planning predictor and an optional world-model predictor for one run.
pub type PredictorPair = (Box<dyn Predictor>, Option<Box<dyn Predictor>>);

/// Runs many closed-loop simulations in parallel on the current rayon pool (each planner call
/// stays single-threaded). `make` builds a fresh (planning, world) predictor pair per run.
///
/// Results come back in the order of `specs`.
pub fn simulate_many<F>(
    scenarios: &[Scenario],
    specs: &[RunSpec],
    settings: &PlannerSettings,
    cfg: &SimConfig,
    make: F,
) -> Vec<Result<RunRecord, SimError>>
where
    F: Fn() -> Result<PredictorPair, PredictorError> + Sync,
{
    specs
        .par_iter()
        .map(|spec| {
            let sc = &scenarios[spec.scenario];
            let (mut plan_pred, mut world) = make().map_err(|source| SimError::Predictor {
                scene: sc.name.clone(),
                source,
            })?;
            simulate(
                sc,
                settings,
                cfg,
                spec.seed,
                plan_pred.as_mut(),
                world.as_deref_mut().map(|w| w as &mut dyn Predictor),
            )
        })
        .collect()
}
