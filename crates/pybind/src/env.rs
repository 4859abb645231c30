//! `nudge._native.Session`: the closed loop one step at a time from Python ([`Session`]), the
//! core of the Gymnasium environment `nudge.env` (docs/env.md).
//!
//! The session is built like a `nudge.simulate` batch (the same validation,
//! `nudge_sim::BatchRequest::prepare`: scenes, planning predictor, world, settings); each
//! `reset(scene, seed)` starts the run of one scene towards the lane drawn from `seed`, exactly
//! as the run of `simulate` with that scene and seed. Every step is either nudge's own plan
//! (`nudge_plan()`, applied when `step` gets its inputs unchanged) or a plan of inputs made
//! outside nudge, checked (T finite values within the settings' bounds, nothing clamped),
//! rolled out with nudge's bicycle model and judged by nudge's safety check, as a Python
//! planner's (`crate::py_policy`). Planning and stepping run without the GIL.

// SimError carries the planner's and predictor's errors by value; they are rare, cold paths.
#![allow(clippy::result_large_err)]

use std::borrow::Cow;
use std::path::PathBuf;
use std::sync::{Mutex, PoisonError};

use nudge_planner::{Plan, Planner, PlannerError, PlannerSettings, PlanningProblem, Scenario};
use nudge_predictor::{Predictor, default_assets_dir};
use nudge_sim::{
    BatchRequest, Column, Policy, Predictors, RunOutput, RunRecord, RunSpec, Session, SimConfig,
    SimError, Table, WorldModel, WorldSpec, collision_table, defaults, run_table, step_table,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::args::{Int, guard};
use crate::errors::{InputError, NudgeError, sim_err};
use crate::py_policy::{RunInfo, check_inputs, judged_plan, observation_dict};
use crate::settings::{PySettings, PySimConfig, with_overrides};
use crate::sim::table_dict;

/// A plan of inputs made outside nudge, as a [`Policy`] of one step ([`judged_plan`]).
struct Inputs<'s> {
    delta: Vec<f64>,
    accel: Vec<f64>,
    settings: &'s PlannerSettings,
}

impl Policy for Inputs<'_> {
    fn reset(&mut self) {}

    fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        judged_plan(
            problem,
            self.settings,
            std::mem::take(&mut self.delta),
            std::mem::take(&mut self.accel),
            predictor,
        )
    }
}

/// One run in progress.
struct Episode {
    /// Index of the scene in the session's scenes.
    scene: usize,
    /// The target-lane seed.
    seed: u64,
    session: Session<'static>,
    /// The run's planning predictor.
    planning: Box<dyn Predictor>,
    /// The teacher of a `teacher` world.
    teacher: Option<Box<dyn Predictor>>,
    /// nudge's planner, built at the first `nudge_plan()` of the run.
    planner: Option<Planner>,
    /// The pending plan is nudge's own (`nudge_plan()`).
    nudge_pending: bool,
}

/// The closed loop of nudge one step at a time, over the scenes given (module
/// documentation; docs/env.md).
#[pyclass(name = "Session", module = "nudge._native")]
pub struct PySession {
    scenes: Vec<Scenario>,
    predictors: Predictors,
    settings: PlannerSettings,
    config: SimConfig,
    /// The run in progress (a `Mutex` only to make the class `Sync`: every method holds
    /// `&mut self`, so it is never contended).
    episode: Mutex<Option<Episode>>,
}

/// A row of a one-row table as a dict of Python scalars, leaving out `skip`.
fn row_dict<'py>(py: Python<'py>, table: &Table, skip: &[&str]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (name, column) in table.columns() {
        if skip.contains(name) {
            continue;
        }
        let missing = || NudgeError::new_err(format!("column {name} has no row"));
        match column {
            Column::Float(v) => d.set_item(name, *v.first().ok_or_else(missing)?)?,
            Column::Int(v) => d.set_item(name, *v.first().ok_or_else(missing)?)?,
            Column::UInt(v) => d.set_item(name, *v.first().ok_or_else(missing)?)?,
            Column::Bool(v) => d.set_item(name, *v.first().ok_or_else(missing)?)?,
            Column::Text(v) => d.set_item(name, v.first().ok_or_else(missing)?)?,
            Column::OptText(v) => d.set_item(name, v.first().ok_or_else(missing)?)?,
        }
    }
    Ok(d)
}

impl PySession {
    /// The run in progress, or `InputError` before the first `reset`.
    fn episode(&mut self) -> PyResult<&mut Episode> {
        self.episode
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner)
            .as_mut()
            .ok_or_else(|| InputError::new_err("no run in progress: call reset(scene, seed) first"))
    }

    /// The observation dict of the run's current step (`crate::py_policy::observation_dict`).
    fn observation_of<'py>(
        py: Python<'py>,
        ep: &mut Episode,
        settings: &PlannerSettings,
    ) -> PyResult<Bound<'py, PyDict>> {
        let seed = ep.seed;
        let step = ep.session.step_index();
        let sc_name = ep.session.scenario().name.clone();
        let lane_centres = ep.session.scenario().lane_centres.clone();
        let lane_bounds = ep.session.scenario().lane_bounds.clone();
        let problem = ep.session.problem().map_err(sim_err)?;
        let run = RunInfo {
            scenario: &sc_name,
            seed,
            step,
            lane_centres: &lane_centres,
            lane_bounds: &lane_bounds,
            settings,
        };
        observation_dict(py, &problem, &run)
    }
}

#[pymethods]
impl PySession {
    /// A session over the scenes `scene_paths` (in this order) with the planning predictor
    /// `predictor` (`"student"`, `"teacher"`, `"constant_velocity"` or a weights path), the
    /// world of `config` with `**config_overrides` (e.g. `world="idm"`), its world model
    /// (`world_predictor`, `idm`) and the planner `settings`; named models under `assets`.
    /// Checked as `nudge.simulate` checks its batch (the same messages).
    #[new]
    #[pyo3(signature = (
        scene_paths,
        predictor = PathBuf::from(defaults::PREDICTOR.as_str()),
        *,
        world_predictor = None,
        idm = None,
        settings = None,
        config = None,
        assets = None,
        **config_overrides
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        scene_paths: Vec<PathBuf>,
        predictor: PathBuf,
        world_predictor: Option<PathBuf>,
        idm: Option<PathBuf>,
        settings: Option<Bound<'_, PySettings>>,
        config: Option<Bound<'_, PySimConfig>>,
        assets: Option<PathBuf>,
        config_overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        guard(|| {
            let settings =
                settings.map_or_else(PlannerSettings::default, |s| s.get().inner.clone());
            let base = config.map_or_else(SimConfig::default, |c| c.get().inner);
            let cfg = match config_overrides {
                Some(o) => with_overrides(&base, o.as_any())?,
                None => base,
            };
            let assets = assets.unwrap_or_else(default_assets_dir);
            let request = BatchRequest {
                scene_paths: &scene_paths,
                predictor: &predictor,
                world_predictor: world_predictor.as_deref(),
                idm: idm.as_deref(),
                assets: &assets,
                seed: defaults::SEED,
                runs_per_scene: 1,
                scene_seeds: None,
                threads: Some(1),
                settings: &settings,
                config: &cfg,
            };
            let batch = py.detach(|| request.prepare()).map_err(sim_err)?;
            Ok(Self {
                scenes: batch.scenes.clone(),
                predictors: batch.predictors.clone(),
                settings: batch.settings.clone(),
                config: batch.config,
                episode: Mutex::new(None),
            })
        })
    }

    /// The scenes' names, in order.
    #[getter]
    fn scene_names(&self) -> Vec<String> {
        self.scenes.iter().map(|s| s.name.clone()).collect()
    }

    /// The number of lanes of each scene, in order.
    #[getter]
    fn lane_counts(&self) -> Vec<usize> {
        self.scenes.iter().map(|s| s.lane_centres.len()).collect()
    }

    /// The planner settings (horizon, dt, input bounds).
    #[getter]
    fn settings(&self) -> PySettings {
        PySettings {
            inner: self.settings.clone(),
        }
    }

    /// The closed-loop settings (world, `max_steps`, the stopping rule).
    #[getter]
    fn config(&self) -> PySimConfig {
        PySimConfig { inner: self.config }
    }

    /// The planning predictor's name.
    #[getter]
    fn predictor(&self) -> &'static str {
        self.predictors.planning.kind().as_str()
    }

    /// Starts the run of scene `scene` (index into the scenes) towards the lane drawn from
    /// `seed` (`nudge_sim::target_lane`), the run `nudge.simulate` makes of that scene with
    /// that seed; forgets any run in progress. Returns the first step's observation (the
    /// dict a Python planner gets, docs/python_planner.md).
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        scene: Int,
        seed: Int,
    ) -> PyResult<Bound<'py, PyDict>> {
        guard(|| {
            let n = self.scenes.len();
            let index = scene.usize("scene", n.saturating_sub(1))?;
            if index >= n {
                return Err(InputError::new_err(format!(
                    "invalid argument `scene`: {index} is not a scene index (0..{n})"
                )));
            }
            let seed = seed.u64("seed", u64::MAX)?;
            *self
                .episode
                .get_mut()
                .unwrap_or_else(PoisonError::into_inner) = None;
            let planning = self.predictors.planning.build();
            let mut teacher = match &self.predictors.world {
                WorldSpec::Teacher(t) => Some(t.build()),
                _ => None,
            };
            let world = match (&self.predictors.world, teacher.as_deref_mut()) {
                (WorldSpec::Teacher(_), Some(t)) => WorldModel::Teacher(t),
                (WorldSpec::Idm(p), _) => WorldModel::Idm(p),
                _ => WorldModel::LogReplay,
            };
            let session = Session::new(
                Cow::Owned(self.scenes[index].clone()),
                Cow::Owned(self.settings.clone()),
                &self.config,
                seed,
                planning.as_ref(),
                &world,
                false,
            )
            .map_err(sim_err)?;
            if let Some(end) = session.ended() {
                return Err(NudgeError::new_err(format!(
                    "scene {}: the run ends before its first step ({end})",
                    self.scenes[index].name
                )));
            }
            let mut ep = Episode {
                scene: index,
                seed,
                session,
                planning,
                teacher,
                planner: None,
                nudge_pending: false,
            };
            let obs = Self::observation_of(py, &mut ep, &self.settings)?;
            *self
                .episode
                .get_mut()
                .unwrap_or_else(PoisonError::into_inner) = Some(ep);
            Ok(obs)
        })
    }

    /// The current step's observation (the same dict as `reset` returned for the first).
    fn observation<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        guard(|| {
            let settings = self.settings.clone();
            let ep = self.episode()?;
            Self::observation_of(py, ep, &settings)
        })
    }

    /// The target lane of the run in progress (index, and its centre y in m).
    fn target(&mut self) -> PyResult<(usize, f64)> {
        let ep = self.episode()?;
        let r = ep.session.record();
        Ok((r.target_lane, r.y_target))
    }

    /// nudge's own plan for the current step (its planner, reset at the run's start, planning
    /// with the run's planning predictor; the GIL released): `{"delta": [T], "accel": [T]}`
    /// (rad, m/s²). The plan stays pending: `step` with these inputs unchanged applies it
    /// (and records it as nudge's). A second call in the same step plans again.
    fn nudge_plan<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        guard(|| {
            let settings = self.settings.clone();
            let ep = self.episode()?;
            let (delta, accel) = py
                .detach(|| -> Result<_, SimError> {
                    let planner = match &mut ep.planner {
                        Some(p) => p,
                        None => {
                            let mut p = Planner::new(settings).map_err(|e| match e {
                                PlannerError::Settings(s) => SimError::Settings(s),
                                other => SimError::Planner {
                                    scene: ep.session.scenario().name.clone(),
                                    step: 0,
                                    source: other,
                                },
                            })?;
                            Policy::reset(&mut p);
                            ep.planner.insert(p)
                        }
                    };
                    let plan = ep.session.plan(planner, ep.planning.as_mut())?;
                    Ok((plan.delta.clone(), plan.accel.clone()))
                })
                .map_err(|e| {
                    ep.nudge_pending = false;
                    sim_err(e)
                })?;
            ep.nudge_pending = true;
            let d = PyDict::new(py);
            d.set_item("delta", numpy::IntoPyArray::into_pyarray(delta, py))?;
            d.set_item("accel", numpy::IntoPyArray::into_pyarray(accel, py))?;
            Ok(d)
        })
    }

    /// Applies the inputs `delta`, `accel` (T floats each: steering in rad, acceleration in
    /// m/s²; the first pair moves the ego for one step of 0.3 s) and moves the world (the GIL
    /// released). Inputs equal, bit for bit, to those of the pending `nudge_plan()` apply
    /// nudge's plan; any others are a plan made outside nudge, checked (T finite values
    /// within the settings' bounds: `InputError` naming the first that is not, nothing
    /// clamped), rolled out and judged by nudge's safety check.
    ///
    /// Returns `(step, end, run, collisions)`: the step's row of `steps.csv` as a dict (every
    /// column but `run`), why the run ended (`"settled"`, `"lane_ended"`, `"lane_not_begun"`,
    /// `"turned_across"`, `"max_steps"`) or `None`, and once ended the run's row of `runs.csv`
    /// and its collisions (columns), else `None`.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        delta: Vec<f64>,
        accel: Vec<f64>,
    ) -> PyResult<(
        Bound<'py, PyDict>,
        Option<&'static str>,
        Option<Bound<'py, PyDict>>,
        Option<Bound<'py, PyDict>>,
    )> {
        guard(|| {
            let settings = self.settings.clone();
            let t = settings.model.horizon;
            let b = &settings.bounds;
            check_inputs(&delta, "delta", -b.delta_max, b.delta_max, t)
                .and_then(|()| check_inputs(&accel, "accel", b.a_min, b.a_max, t))
                .map_err(|e| InputError::new_err(format!("unusable inputs: {e}")))?;
            let world_spec = &self.predictors.world;
            let slot = self
                .episode
                .get_mut()
                .unwrap_or_else(PoisonError::into_inner);
            let Some(ep) = slot.as_mut() else {
                return Err(InputError::new_err(
                    "no run in progress: call reset(scene, seed) first",
                ));
            };
            let nudge = ep.nudge_pending
                && ep.session.pending().is_some_and(|p| {
                    p.delta
                        .iter()
                        .map(|v| v.to_bits())
                        .eq(delta.iter().map(|v| v.to_bits()))
                        && p.accel
                            .iter()
                            .map(|v| v.to_bits())
                            .eq(accel.iter().map(|v| v.to_bits()))
                });
            ep.nudge_pending = false;
            let result = py.detach(|| -> Result<RunRecord, SimError> {
                if !nudge {
                    let mut inputs = Inputs {
                        delta,
                        accel,
                        settings: &settings,
                    };
                    ep.session.plan(&mut inputs, ep.planning.as_mut())?;
                }
                let mut world = match (world_spec, ep.teacher.as_deref_mut()) {
                    (WorldSpec::Teacher(_), Some(t)) => WorldModel::Teacher(t),
                    (WorldSpec::Idm(p), _) => WorldModel::Idm(p),
                    _ => WorldModel::LogReplay,
                };
                let record = ep
                    .session
                    .advance(ep.planning.as_mut(), &mut world)?
                    .clone();
                let r = ep.session.record();
                let head = RunRecord {
                    scenario: r.scenario.clone(),
                    seed: r.seed,
                    predictor: r.predictor.clone(),
                    world: r.world,
                    n_agents: r.n_agents,
                    target_lane: r.target_lane,
                    y_target: r.y_target,
                    success: false,
                    steps_to_target: None,
                    collision: record.collision,
                    collisions: Vec::new(),
                    metrics: nudge_sim::RunMetrics::default(),
                    aborts: 0,
                    outcome: nudge_sim::RunOutcome::Unfinished,
                    steps: vec![record],
                };
                Ok(head)
            });
            let head = match result {
                Ok(r) => r,
                Err(e) => {
                    // A run that failed mid-step cannot go on.
                    *slot = None;
                    return Err(sim_err(e));
                }
            };
            let out = [RunOutput {
                spec: RunSpec {
                    scene: ep.scene,
                    seed: ep.seed,
                },
                result: Ok(head),
                examples: None,
            }];
            let info = row_dict(py, &step_table(&out), &["run"])?;
            let end = ep.session.ended();
            let (run, collisions) = match end {
                Some(_) => {
                    let rec = ep.session.result();
                    let out = [RunOutput {
                        spec: RunSpec {
                            scene: ep.scene,
                            seed: ep.seed,
                        },
                        result: Ok(rec),
                        examples: None,
                    }];
                    (
                        Some(row_dict(py, &run_table(&self.scenes, &out), &[])?),
                        Some(table_dict(py, collision_table(&self.scenes, &out))?),
                    )
                }
                None => (None, None),
            };
            Ok((info, end.map(nudge_sim::EndReason::as_str), run, collisions))
        })
    }
}
