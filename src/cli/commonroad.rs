//! `nudge simulate --commonroad FILE (--ego ID | --planning-problem ID)`: closed-loop runs on
//! the nudge scenario built from a CommonRoad scenario file ([`crate::commonroad`]), each run's
//! executed ego trajectory written as a CommonRoad solution in the file's own coordinates.

use std::path::{Path, PathBuf};

use clap::Args;
use nudge_planner::{PlannerSettings, Scenario};
use nudge_predictor::{DT, T_OBS};
use nudge_sim::{Policy, RunOutput, SimConfig};

use crate::commonroad::scene::NEIGHBOUR_RANGE;
use crate::commonroad::{CommonRoadError, CommonRoadScene, Ego, GoalPolicy, RoadGoal, Solution};

/// The CommonRoad flags of `nudge simulate`.
#[derive(Debug, Args)]
pub struct CommonRoadArgs {
    /// A CommonRoad 2020a (or 2018b) scenario file (.xml or .xml.gz) to plan in instead of
    /// --scenes; needs --out, and --ego or --planning-problem. Writes the nudge scenario built
    /// from it and one CommonRoad solution (KS trajectory) per run into --out.
    #[arg(long, conflicts_with = "scenes", requires = "out")]
    pub commonroad: Option<PathBuf>,
    /// With --commonroad: the dynamic obstacle that becomes the ego (its logged history is
    /// the ego's).
    #[arg(long, requires = "commonroad", conflicts_with = "planning_problem")]
    pub ego: Option<i64>,
    /// With --commonroad: the planning problem whose initial state is the ego's (histories
    /// before the scene's first step are extrapolated at constant speed and heading).
    #[arg(long, requires = "commonroad")]
    pub planning_problem: Option<i64>,
    /// With --commonroad: the last observed time (s of the file's clock) [default: the ego
    /// obstacle's first time with a full 2.1 s history on the scene's 0.3 s grid; the planning
    /// problem's initial time].
    #[arg(long, requires = "commonroad")]
    pub t0: Option<f64>,
    /// With --commonroad: neighbours are the vehicles within this distance of the ego at t0 (m)
    /// [default: 60].
    #[arg(long, requires = "commonroad")]
    pub neighbour_range: Option<f64>,
}

/// A CommonRoad scene made ready to run: the scene, the ego, t0, the scenario and its file.
#[derive(Debug)]
pub struct Prepared {
    scene: CommonRoadScene,
    ego: Ego,
    t0: f64,
    scenario: Scenario,
    /// The scenario file written into the output directory.
    pub scenario_path: PathBuf,
    /// The planning problem's goal in the road frame (a planning-problem ego only).
    pub goal: Option<RoadGoal>,
}

impl CommonRoadArgs {
    /// Reads the CommonRoad file and writes the scenario of the ego into `out` (created);
    /// `None` without --commonroad.
    ///
    /// # Errors
    /// A message naming the file and the reason (unreadable, unsupported road shape, unknown
    /// ego, no history), or a missing --ego / --planning-problem.
    pub fn prepare(&self, out: Option<&Path>) -> Result<Option<Prepared>, String> {
        let Some(path) = &self.commonroad else {
            return Ok(None);
        };
        let ego = match (self.ego, self.planning_problem) {
            (Some(id), None) => Ego::Obstacle(id),
            (None, Some(id)) => Ego::PlanningProblem(id),
            _ => return Err("--commonroad needs --ego ID or --planning-problem ID".into()),
        };
        let out = out.ok_or("--commonroad needs --out")?;
        let range = self.neighbour_range.unwrap_or(NEIGHBOUR_RANGE);
        let (scene, t0, scenario, bytes) =
            CommonRoadScene::prepare(path, ego, self.t0, range).map_err(|e| e.to_string())?;
        let goal = match ego {
            Ego::PlanningProblem(id) => {
                let goal = scene
                    .road_goal(id, t0, scenario.position(0, T_OBS - 1))
                    .map_err(|e| e.to_string())?;
                let b = &scenario.lane_bounds;
                if !(b[0] <= goal.y && goal.y <= b[b.len() - 1]) {
                    return Err(CommonRoadError::Goal {
                        path: path.clone(),
                        problem: id,
                        reason: format!(
                            "its lane (road y {:.2} m) is not on the road where the ego starts \
                             (lanes {:.2}..{:.2} m): nudge plans within the lanes at the ego's x",
                            goal.y,
                            b[0],
                            b[b.len() - 1]
                        ),
                    }
                    .to_string());
                }
                Some(goal)
            }
            Ego::Obstacle(_) => None,
        };
        std::fs::create_dir_all(out).map_err(|e| format!("--out {}: {e}", out.display()))?;
        let scenario_path = out.join(format!("{}.safetensors", scenario.name));
        crate::files::write_file(&scenario_path, &bytes).map_err(|e| e.to_string())?;
        Ok(Some(Prepared {
            scene,
            ego,
            t0,
            scenario,
            scenario_path,
            goal,
        }))
    }
}

/// One output file: its name in the output directory and its bytes.
pub type NamedBytes = (String, Vec<u8>);

impl Prepared {
    /// The closed-loop settings of a run to the goal: `cfg` with as many steps as reach the
    /// end of the goal's time window and no early stop on settling (the run ends with the
    /// window, the solution where it first reaches the goal). Past the scene's logged future
    /// the others move by the log-replay world's extrapolation (the checker judges a solution
    /// only against the recorded obstacles, which end there). `cfg` itself without a goal.
    ///
    /// # Errors
    /// A message naming the planning problem when its time window ends more than
    /// [`SimConfig::MAX_STEPS`] steps after t0.
    pub fn goal_config(&self, cfg: &SimConfig) -> Result<SimConfig, String> {
        let Some(g) = &self.goal else {
            return Ok(*cfg);
        };
        let need = ((g.time_s[1] - self.t0) / DT - 1e-9).ceil().max(1.0);
        #[allow(clippy::cast_precision_loss)]
        if need > SimConfig::MAX_STEPS as f64 {
            return Err(format!(
                "{}: planning problem {}: goal: its time window ends at {:.1} s, more than {} \
                 steps of {DT} s after t0 {:.1} s",
                self.scene.raw.path.display(),
                g.problem,
                g.time_s[1],
                SimConfig::MAX_STEPS,
                self.t0
            ));
        }
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let steps = need as usize;
        Ok(SimConfig {
            max_steps: steps,
            settle_steps: steps,
            ..*cfg
        })
    }

    /// A policy driving nudge's planner (under `settings`) to `goal` from this scene's t0
    /// ([`GoalPolicy`]).
    #[must_use]
    pub fn goal_policy(&self, goal: RoadGoal, settings: &PlannerSettings) -> Box<dyn Policy> {
        Box::new(GoalPolicy::new(settings.clone(), goal, self.t0))
    }

    /// The files `solution_<scenario>_seed<seed>.xml` of every run that ran (and beside each a
    /// `.json` with the ego's size (m), l_r (m) and the deviation (m)), as (name, bytes) for
    /// the output set ([`crate::files::write_set`]), and one line per solution (name, states,
    /// largest deviation from the closed loop).
    ///
    /// # Errors
    /// A message naming the run that has no trajectory in the file's coordinates.
    pub fn solution_files(
        &self,
        outputs: &[RunOutput],
        settings: &PlannerSettings,
    ) -> Result<(Vec<NamedBytes>, Vec<String>), String> {
        let mut files = Vec::new();
        let mut lines = Vec::new();
        for o in outputs {
            let Ok(record) = &o.result else { continue };
            let goals = self.goal.and_then(|g| {
                self.scene
                    .raw
                    .planning_problems
                    .iter()
                    .find(|p| p.id == g.problem)
                    .map(|p| &p.goals[..])
            });
            let (sol, goal) = Solution::of_run_to_goal(
                &self.scene,
                (self.ego, self.t0),
                &self.scenario,
                record,
                (settings.model.l_f, settings.model.l_r),
                goals,
            )
            .map_err(|e| format!("run seed {}: {e}", o.spec.seed))?;
            let stem = format!("solution_{}_seed{}", self.scenario.name, o.spec.seed);
            let side = serde_json::json!({
                "benchmark_id": sol.benchmark_id,
                "planning_problem": sol.planning_problem,
                "ego": self.ego.to_string(),
                "ego_size_m": self.scenario.size[0],
                "l_r_m": settings.model.l_r,
                "max_dev_m": sol.max_dev_m,
                "n_states": sol.states.len(),
                "goal_reached": goal.as_ref().map(Result::is_ok),
                "goal_time_step": goal.as_ref().and_then(|g| g.as_ref().ok()).map(|&i| sol.states[i].step),
                "goal_missed": goal.as_ref().and_then(|g| g.as_ref().err()),
                "goal_lane": self.goal.map(|g| g.lane),
            });
            lines.push(format!(
                "CommonRoad solution {stem}.xml ({}, {} states, {:.3} m from the closed loop's states)",
                sol.benchmark_id,
                sol.states.len(),
                sol.max_dev_m
            ));
            match &goal {
                Some(Ok(i)) => lines.push(format!(
                    "goal of planning problem {} reached at time step {} (lane {})",
                    sol.planning_problem,
                    sol.states[*i].step,
                    self.goal.map_or(0, |g| g.lane)
                )),
                Some(Err(why)) => lines.push(format!(
                    "goal of planning problem {} NOT reached: {why}",
                    sol.planning_problem
                )),
                None => {}
            }
            files.push((format!("{stem}.xml"), sol.to_xml().into_bytes()));
            files.push((format!("{stem}.json"), side.to_string().into_bytes()));
        }
        Ok((files, lines))
    }
}
