//! One closed-loop lane change ([`simulate`]): at every step, plan; apply the first input to
//! the vehicle; move the other vehicles with the [`World`]; shift the histories; record the
//! step's safety (the planner's own constraint, [`SafetyConstraint::executed_min_b`]) and
//! collisions; stop when the ego has settled in the target lane.

use std::time::Instant;

use nudge_predictor::{History, Predictor, T_OBS};

use crate::admm::{EgoState, Plan, Planner, PlanningProblem, SafetyConstraint};
use crate::error::{PlannerError, SimError};
use crate::model::State;
use crate::safety::{OrientedBox, motion_heading};
use crate::scenario::Scenario;
use crate::settings::PlannerSettings;

use super::batch::Cancel;
use super::config::{SimConfig, World};
use super::records::{RunRecord, StepRecord, StepStatus};

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

/// The lane change's goal and its aborts: after `abort_after` consecutive steps without a
/// safe plan while the ego is not wholly inside the target lane, aim at the own lane's centre
/// for `abort_hold` steps, then retry.
struct LaneChange {
    y_target: f64,
    y_own: f64,
    /// |y − y_target| below which the ego is wholly inside the target lane (m).
    inside: f64,
    abort_after: usize,
    abort_hold: usize,
    unsafe_steps: usize,
    hold: usize,
    aborts: usize,
}

impl LaneChange {
    fn new(sc: &Scenario, cfg: &SimConfig, y_target: f64) -> Self {
        let y_own = sc.lane_centres[sc.ego_lane];
        Self {
            y_target,
            y_own,
            inside: (0.5 * (y_target - y_own).abs() - 0.5 * sc.size[0][1]).max(cfg.settle_y),
            abort_after: cfg.abort_after,
            abort_hold: cfg.abort_hold,
            unsafe_steps: 0,
            hold: 0,
            aborts: 0,
        }
    }

    /// Where the planner aims this step (m).
    fn goal(&self) -> f64 {
        if self.hold > 0 {
            self.y_own
        } else {
            self.y_target
        }
    }

    /// Counts a planning step of the ego at lateral position `y` (m) that ended in `status`.
    fn after_plan(&mut self, status: StepStatus, y: f64) {
        if self.hold > 0 {
            self.hold -= 1;
        } else if self.abort_after > 0
            && status.is_unsafe_plan()
            && (y - self.y_target).abs() > self.inside
        {
            self.unsafe_steps += 1;
            if self.unsafe_steps >= self.abort_after {
                self.hold = self.abort_hold;
                self.unsafe_steps = 0;
                self.aborts += 1;
            }
        } else {
            self.unsafe_steps = 0;
        }
    }
}

/// What moves the other vehicles.
enum Mover<'p> {
    /// The teacher's interactive prediction, with its buffers.
    Teacher {
        predictor: &'p mut dyn Predictor,
        candidate: Vec<f64>,
        prediction: Vec<f64>,
    },
    /// The logged future.
    LogReplay,
}

impl<'p> Mover<'p> {
    /// The mover of `cfg.world`, checked against the model given.
    fn new(
        cfg: &SimConfig,
        model: Option<&'p mut dyn Predictor>,
        n_agents: usize,
        horizon: usize,
    ) -> Result<Self, SimError> {
        match (cfg.world, model) {
            (World::Teacher, Some(predictor)) => {
                if predictor.name() != "teacher" {
                    return Err(SimError::WorldModel {
                        world: World::Teacher.as_str(),
                        reason: format!(
                            "the world model must be a teacher, got a {}",
                            predictor.name()
                        ),
                    });
                }
                Ok(Self::Teacher {
                    predictor,
                    candidate: vec![0.0; horizon * 2],
                    prediction: vec![0.0; (n_agents.max(2) - 1) * horizon * 2],
                })
            }
            (World::Teacher, None) => Err(SimError::WorldModel {
                world: World::Teacher.as_str(),
                reason: "no teacher given to move the other vehicles".into(),
            }),
            (World::LogReplay, None) => Ok(Self::LogReplay),
            (World::LogReplay, Some(p)) => Err(SimError::WorldModel {
                world: World::LogReplay.as_str(),
                reason: format!(
                    "the logged future moves the others; a {} world model would be ignored",
                    p.name()
                ),
            }),
        }
    }

    /// The others' positions after `step` (index = agent, agent 0 = the ego at `ego`): the
    /// teacher predicts them given the ego's executed position and the rest of its `plan`;
    /// log replay reads the log (constant velocity from the last two observations once it ends).
    fn advance(
        &mut self,
        sc: &Scenario,
        history: &History,
        observed: &[Vec<[f64; 2]>],
        step: usize,
        ego: [f64; 2],
        plan: &[[f64; 4]],
    ) -> Result<Vec<[f64; 2]>, SimError> {
        let n = sc.n_agents;
        let mut moved: Vec<[f64; 2]> = Vec::with_capacity(n);
        moved.push(ego);
        match self {
            Self::Teacher { .. } if n < 2 => {}
            Self::Teacher {
                predictor,
                candidate,
                prediction,
            } => {
                let horizon = candidate.len() / 2;
                candidate[0] = ego[0];
                candidate[1] = ego[1];
                for k in 1..horizon {
                    candidate[2 * k] = plan[k][0];
                    candidate[2 * k + 1] = plan[k][1];
                }
                predictor
                    .set_scene(history)
                    .and_then(|()| predictor.predict(candidate, prediction))
                    .map_err(|source| SimError::Predictor {
                        scene: sc.name.clone(),
                        source,
                    })?;
                for i in 1..n {
                    let b = (i - 1) * horizon * 2;
                    moved.push([prediction[b], prediction[b + 1]]);
                }
            }
            Self::LogReplay => {
                for (i, h) in observed.iter().enumerate().skip(1) {
                    let p = sc.future_at(i, step + 1).unwrap_or_else(|| {
                        let a = h[T_OBS - 2];
                        let b = h[T_OBS - 1];
                        [2.0 * b[0] - a[0], 2.0 * b[1] - a[1]]
                    });
                    moved.push(p);
                }
            }
        }
        Ok(moved)
    }
}

/// Collision and nearest vehicle of the ego state `ego` against the others at `moved`, each
/// box at the heading of its last displacement in `observed` (clamped to ±0.5 rad; the
/// scenario's start heading when it barely moved).
fn collisions(
    sc: &Scenario,
    ego: &State,
    moved: &[[f64; 2]],
    observed: &[Vec<[f64; 2]>],
) -> (bool, Option<(usize, f64, f64)>) {
    let ego_box = OrientedBox {
        x: ego[0],
        y: ego[1],
        heading: ego[2],
        length: sc.size[0][0],
        width: sc.size[0][1],
    };
    let mut collision = false;
    let mut nearest: Option<(usize, f64, f64)> = None;
    for i in 1..sc.n_agents {
        let (dx, dy) = (moved[i][0] - ego[0], moved[i][1] - ego[1]);
        if nearest.is_none_or(|(_, nx, ny)| dx.hypot(dy) < nx.hypot(ny)) {
            nearest = Some((i, dx, dy));
        }
        let h = &observed[i];
        let other = OrientedBox {
            x: moved[i][0],
            y: moved[i][1],
            heading: motion_heading(h[T_OBS - 2], h[T_OBS - 1], sc.heading[i]),
            length: sc.size[i][0],
            width: sc.size[i][1],
        };
        collision |= ego_box.overlaps(&other);
    }
    (collision, nearest)
}

/// The state of one run between steps.
struct ClosedLoop<'a> {
    sc: &'a Scenario,
    settings: &'a PlannerSettings,
    planner: Planner,
    /// Observed positions per agent, `[n][T_OBS]` (m).
    observed: Vec<Vec<[f64; 2]>>,
    ego: State,
    v_ref: f64,
    last_inputs: (f64, f64),
    lane: LaneChange,
}

impl ClosedLoop<'_> {
    /// The observed history as the predictors take it.
    fn history(&self) -> Result<History, SimError> {
        let flat: Vec<f64> = self
            .observed
            .iter()
            .flat_map(|h| h.iter().flat_map(|p| [p[0], p[1]]))
            .collect();
        History::new(flat, self.sc.n_agents).map_err(|source| SimError::Predictor {
            scene: self.sc.name.clone(),
            source,
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
        let history = self.history()?;
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
            sizes: &sc.size,
            y_target: self.lane.goal(),
            v_ref: self.v_ref,
            road: sc.road(),
        };
        let t0 = Instant::now();
        let plan: Plan =
            self.planner
                .plan(&problem, planner_pred)
                .map_err(|source: PlannerError| SimError::Planner {
                    scene: self.sc.name.clone(),
                    step,
                    source,
                })?;
        let mpc_s = t0.elapsed().as_secs_f64();
        let status = StepStatus::from(plan.status);
        let y_goal = problem.y_target;
        let constraint = SafetyConstraint::new(&problem, self.settings);
        self.lane.after_plan(status, self.ego[1]);
        let next = self
            .planner
            .model()
            .advance(&self.ego, plan.delta[0], plan.accel[0]);
        let moved = mover.advance(
            sc,
            &history,
            &self.observed,
            step,
            [next[0], next[1]],
            &plan.states,
        )?;
        for (h, p) in self.observed.iter_mut().zip(&moved) {
            h.remove(0);
            h.push(*p);
        }
        self.ego = next;
        self.last_inputs = (plan.delta[0], plan.accel[0]);
        let (collision, nearest) = collisions(sc, &self.ego, &moved, &self.observed);
        Ok(StepRecord {
            step,
            mpc_s,
            z_updates_s: plan.timings.z_updates_s,
            iterations: plan.iterations,
            predictor_calls: plan.predictor_calls,
            cost: plan.cost,
            primal_residual: plan.primal_residual,
            min_b: constraint.executed_min_b([next[0], next[1], next[2]], &moved),
            collision,
            status,
            delta: plan.delta[0],
            accel: plan.accel[0],
            ego: [next[0], next[1], next[2], next[3]],
            nearest,
            y_goal,
        })
    }
}

/// Runs one closed-loop lane change of scenario `sc` towards the lane drawn from `seed`.
///
/// `planner_pred` predicts inside the MPC; `world` is the teacher that moves the other
/// vehicles in a [`World::Teacher`] world (and must be `None` for [`World::LogReplay`]).
///
/// # Errors
/// [`SimError::Settings`] / [`SimError::Config`] for invalid settings or settings that do not
/// fit the predictors and scenes ([`crate::fit::check_closed_loop`]),
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
/// use nudge_planner::{PlannerSettings, Scenario, SimConfig, World, simulate};
/// use nudge_predictor::ConstantVelocity;
///
/// let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
///     .join("../../assets/scenes/us101-11_1-t02.1-ego144.safetensors");
/// let sc = Scenario::from_file(&scene)?;
/// let cfg = SimConfig { world: World::LogReplay, ..SimConfig::default() };
/// let mut cv = ConstantVelocity::new(6)?;
/// let run = simulate(&sc, &PlannerSettings::default(), &cfg, 0, &mut cv, None)?;
/// assert!(run.success && !run.collision);
/// assert_eq!(run.steps.len(), run.steps_to_target.unwrap_or(0));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn simulate(
    sc: &Scenario,
    settings: &PlannerSettings,
    cfg: &SimConfig,
    seed: u64,
    planner_pred: &mut dyn Predictor,
    world: Option<&mut dyn Predictor>,
) -> Result<RunRecord, SimError> {
    let never = Cancel::new();
    simulate_cancellable(sc, settings, cfg, seed, planner_pred, world, &never)
}

/// [`simulate`], checking `cancel` before every closed-loop step.
///
/// # Errors
/// As [`simulate`]; [`SimError::Cancelled`] once `cancel` is set.
pub fn simulate_cancellable(
    sc: &Scenario,
    settings: &PlannerSettings,
    cfg: &SimConfig,
    seed: u64,
    planner_pred: &mut dyn Predictor,
    world: Option<&mut dyn Predictor>,
    cancel: &Cancel,
) -> Result<RunRecord, SimError> {
    cfg.validate()?;
    let planner = Planner::new(settings.clone()).map_err(|e| match e {
        PlannerError::Settings(s) => SimError::Settings(s),
        other => SimError::Planner {
            scene: sc.name.clone(),
            step: 0,
            source: other,
        },
    })?;
    let mut fit = vec![(planner_pred.name(), planner_pred.horizon())];
    fit.extend(world.as_ref().map(|w| (w.name(), w.horizon())));
    crate::fit::check_closed_loop(settings, &fit)?;
    let mut mover = Mover::new(cfg, world, sc.n_agents, settings.horizon)?;
    let lane = target_lane(sc, seed)?;
    let y_target = sc.lane_centres[lane];
    let p0 = sc.position(0, T_OBS - 1);
    let mut run = ClosedLoop {
        sc,
        settings,
        planner,
        observed: (0..sc.n_agents)
            .map(|i| (0..T_OBS).map(|t| sc.position(i, t)).collect())
            .collect(),
        ego: State::new(p0[0], p0[1], sc.heading[0], sc.speed[0]),
        v_ref: sc.speed[0],
        last_inputs: (0.0, 0.0),
        lane: LaneChange::new(sc, cfg, y_target),
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
        aborts: 0,
        steps: Vec::new(),
    };
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
    rec.aborts = run.lane.aborts;
    Ok(rec)
}
