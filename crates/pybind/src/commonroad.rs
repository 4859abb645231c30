//! CommonRoad in and out from Python: `commonroad_scenario` (the nudge scenario of an ego in a
//! CommonRoad file), `commonroad_solution` (inputs → a CommonRoad KS solution file) and
//! `commonroad_tracks` (the file in the road frame, for checks against the data pipeline).
//! Every error is a `ScenarioError` naming the file and the element or reason.

use std::path::PathBuf;
use std::sync::Arc;

use nudge::commonroad::scene::NEIGHBOUR_RANGE;
use nudge::commonroad::{CommonRoadError, CommonRoadScene, Ego, Solution};
use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::args::guard;
use crate::errors::{InputError, ScenarioError};
use crate::scenario::PyScenario;
use crate::settings::PySettings;

fn cr_err(e: &CommonRoadError) -> PyErr {
    ScenarioError::new_err(e.to_string())
}

fn ego_of(ego: Option<i64>, planning_problem: Option<i64>) -> PyResult<Ego> {
    match (ego, planning_problem) {
        (Some(id), None) => Ok(Ego::Obstacle(id)),
        (None, Some(id)) => Ok(Ego::PlanningProblem(id)),
        _ => Err(InputError::new_err(
            "give exactly one of ego (an obstacle id) and planning_problem (a planning problem id)",
        )),
    }
}

/// The scene, ego, t0 (s) and scenario with its file bytes.
fn build(
    path: &PathBuf,
    ego: Ego,
    t0: Option<f64>,
    range: Option<f64>,
) -> Result<(CommonRoadScene, f64, nudge::planner::Scenario), CommonRoadError> {
    let (scene, t0, sc, _) =
        CommonRoadScene::prepare(path, ego, t0, range.unwrap_or(NEIGHBOUR_RANGE))?;
    Ok((scene, t0, sc))
}

/// The nudge scenario of `ego` (a dynamic obstacle id) or `planning_problem` (an id) in the
/// CommonRoad file `path` (.xml or .xml.gz), last observed at `t0` s (default: the first time
/// with a full 2.1 s history; a planning problem's initial time), neighbours within
/// `neighbour_range` m (default 60).
#[pyfunction]
#[pyo3(signature = (path, *, ego=None, planning_problem=None, t0=None, neighbour_range=None))]
pub fn commonroad_scenario(
    py: Python<'_>,
    path: PathBuf,
    ego: Option<i64>,
    planning_problem: Option<i64>,
    t0: Option<f64>,
    neighbour_range: Option<f64>,
) -> PyResult<PyScenario> {
    guard(|| {
        let ego = ego_of(ego, planning_problem)?;
        let (_, _, sc) = py
            .detach(|| build(&path, ego, t0, neighbour_range))
            .map_err(|e| cr_err(&e))?;
        Ok(PyScenario {
            inner: Arc::new(sc),
            path,
        })
    })
}

/// Writes to `out` the CommonRoad KS solution of the inputs `delta` `[steps]` (rad) and
/// `accel` `[steps]` (m/s²), each held 0.3 s from the ego's state in the scenario that
/// `commonroad_scenario` builds with the same arguments; axle distances from `settings`
/// (default `PlannerSettings()`). Returns a dict: benchmark_id, planning_problem, n_states.
#[pyfunction]
#[pyo3(signature = (path, out, delta, accel, *, ego=None, planning_problem=None, t0=None, neighbour_range=None, settings=None))]
#[allow(clippy::too_many_arguments)]
pub fn commonroad_solution<'py>(
    py: Python<'py>,
    path: PathBuf,
    out: PathBuf,
    delta: PyReadonlyArray1<'py, f64>,
    accel: PyReadonlyArray1<'py, f64>,
    ego: Option<i64>,
    planning_problem: Option<i64>,
    t0: Option<f64>,
    neighbour_range: Option<f64>,
    settings: Option<Bound<'py, PySettings>>,
) -> PyResult<Bound<'py, PyDict>> {
    guard(|| {
        let ego = ego_of(ego, planning_problem)?;
        let (d, a) = (delta.as_slice()?, accel.as_slice()?);
        if d.len() != a.len() {
            return Err(InputError::new_err(format!(
                "delta has {} steps, accel {}",
                d.len(),
                a.len()
            )));
        }
        let inputs: Vec<[f64; 2]> = d.iter().zip(a).map(|(&d, &a)| [d, a]).collect();
        let s = settings.map(|s| s.get().inner.clone()).unwrap_or_default();
        let sol = py
            .detach(|| {
                let (scene, t0, sc) = build(&path, ego, t0, neighbour_range)?;
                let sol = Solution::of_inputs(
                    &scene,
                    (ego, t0),
                    &sc,
                    (&inputs, None),
                    (s.model.l_f, s.model.l_r),
                )?;
                sol.write(&out)?;
                Ok::<_, CommonRoadError>(sol)
            })
            .map_err(|e| cr_err(&e))?;
        let dict = PyDict::new(py);
        dict.set_item("benchmark_id", &sol.benchmark_id)?;
        dict.set_item("planning_problem", sol.planning_problem)?;
        dict.set_item("n_states", sol.states.len())?;
        Ok(dict)
    })
}

/// The CommonRoad file `path` in the road frame: per state `vehicle`, `step` (I64), `x`, `y`
/// (m), `heading` (rad), `speed` (m/s) arrays `[N]`, and `pieces`, a list of (x0 m, x1 m,
/// ascending lane boundaries `[L + 1]` m). With `curvilinear`, in the curvilinear (Frenet)
/// frame the planner uses on curved roads (x = arc length along the reference path, y = the
/// signed offset from it) instead of the straightened one.
#[pyfunction]
#[pyo3(signature = (path, *, curvilinear=false))]
pub fn commonroad_tracks(
    py: Python<'_>,
    path: PathBuf,
    curvilinear: bool,
) -> PyResult<Bound<'_, PyDict>> {
    guard(|| {
        let scene = py
            .detach(|| {
                let s = CommonRoadScene::read(&path)?;
                if curvilinear { s.curvilinear() } else { Ok(s) }
            })
            .map_err(|e| cr_err(&e))?;
        let states = || {
            scene
                .tracks
                .iter()
                .flat_map(|t| t.states.iter().map(move |s| (t.id, s)))
        };
        let dict = PyDict::new(py);
        dict.set_item(
            "vehicle",
            states()
                .map(|(id, _)| id)
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        dict.set_item(
            "step",
            states()
                .map(|(_, s)| s.step)
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        dict.set_item(
            "x",
            states()
                .map(|(_, s)| s.pos[0])
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        dict.set_item(
            "y",
            states()
                .map(|(_, s)| s.pos[1])
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        dict.set_item(
            "heading",
            states()
                .map(|(_, s)| s.heading)
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        dict.set_item(
            "speed",
            states()
                .map(|(_, s)| s.speed)
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        let pieces: Vec<(f64, f64, Vec<f64>)> = scene.lanes.pieces.clone();
        dict.set_item("pieces", pieces)?;
        Ok(dict)
    })
}
