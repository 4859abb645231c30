//! `nudge._native.Planner`: one ADMM MPC call at a time, on a scenario or on raw arrays.

use std::sync::{Mutex, MutexGuard, PoisonError};
use std::thread::ThreadId;

use nudge_planner::scenario::{LaneExtent, MAX_LANES};
use nudge_planner::{
    BudgetLimit, Cancel, EgoState, LaneViolationKind, Lanes, Plan, PlanStatus, Planner,
    PlannerSettings, PlanningProblem,
};
use nudge_predictor::{History, MAX_AGENTS, T_OBS};
use nudge_sim::SimConfig;
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::args::{Int, guard};
use crate::arrays::{Dim, to_f64};
use crate::errors::{InputError, NudgeError, ReentrancyError, planner_err, predictor_err, sim_err};
use crate::interrupt::interruptibly;
use crate::py_predictor::PlanningPredictor;
use crate::scenario::PyScenario;
use crate::settings::{PySettings, PySimConfig};

/// The interaction-aware MPC planner bound to one predictor (built in, or a Python object:
/// `crate::py_predictor`). Keeps its previous solution as the warm start of the next call
/// (`reset()` forgets it).
#[pyclass(name = "Planner", module = "nudge._native", frozen)]
pub struct PyPlanner {
    planner: Mutex<Planner>,
    predictor: PlanningPredictor,
    /// The thread planning now (holding `planner` inside [`PyPlanner::run`]), if any: a call
    /// from that thread while it plans comes from inside the predictor (re-entrant) and would
    /// wait for itself forever, so it is refused ([`PyPlanner::lock`]).
    planning_on: Mutex<Option<ThreadId>>,
}

/// Clears [`PyPlanner::planning_on`] when the planning call ends (returns or unwinds).
struct Planning<'a>(&'a Mutex<Option<ThreadId>>);

impl Drop for Planning<'_> {
    fn drop(&mut self) {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner) = None;
    }
}

/// A finite float or `InputError` naming it.
fn finite(what: &str, v: f64) -> PyResult<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(InputError::new_err(format!("{what}: non-finite value {v}")))
    }
}

/// The plan as a dict of numpy arrays and scalars.
pub fn plan_to_dict<'py>(py: Python<'py>, plan: &Plan) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let t = plan.delta.len();
    let states: Vec<f64> = plan.states.iter().flatten().copied().collect();
    d.set_item("delta", plan.delta.clone().into_pyarray(py))?;
    d.set_item("accel", plan.accel.clone().into_pyarray(py))?;
    d.set_item(
        "states",
        states
            .into_pyarray(py)
            .reshape([t, 4])
            .map_err(|e| NudgeError::new_err(format!("reshape failed: {e}")))?,
    )?;
    let admm: Vec<f64> = plan.admm_states.iter().flatten().copied().collect();
    let admm_rows = plan.admm_states.len();
    d.set_item(
        "admm_states",
        admm.into_pyarray(py)
            .reshape([admm_rows, 4])
            .map_err(|e| NudgeError::new_err(format!("reshape failed: {e}")))?,
    )?;
    d.set_item("cost", plan.cost)?;
    d.set_item("iterations", plan.iterations)?;
    d.set_item("predictor_calls", plan.predictor_calls)?;
    d.set_item("refused_candidates", plan.refused_candidates)?;
    d.set_item("qp_solves", plan.qp_solves)?;
    d.set_item("primal_residual", plan.primal_residual)?;
    d.set_item("change_residual", plan.change_residual)?;
    d.set_item("min_safety", plan.min_safety)?;
    d.set_item("checked", plan.checked)?;
    d.set_item("rollout_min_safety", plan.rollout_min_safety)?;
    d.set_item("status", plan.status.name())?;
    d.set_item("decided_by", plan.decided_by.label())?;
    d.set_item(
        "budget_reached",
        plan.budget_reached.map(BudgetLimit::as_str),
    )?;
    let violation = plan
        .lane_violation
        .map(|v| -> PyResult<Bound<'py, PyDict>> {
            let e = PyDict::new(py);
            e.set_item("step", v.step)?;
            e.set_item("lane", v.lane)?;
            e.set_item(
                "kind",
                match v.kind {
                    LaneViolationKind::Ended => "Ended",
                    LaneViolationKind::NotBegun => "NotBegun",
                },
            )?;
            e.set_item("x", v.x)?;
            Ok(e)
        })
        .transpose()?;
    d.set_item("lane_violation", violation)?;
    // Which QP failed and Clarabel's status, for status "SolverFailed".
    let failure = match plan.status {
        PlanStatus::SolverFailed { qp, status } => Some((
            qp.as_str(),
            serde_json::to_value(status)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default(),
        )),
        _ => None,
    };
    d.set_item("solver_failure", failure)?;
    let tm = PyDict::new(py);
    tm.set_item("delta_s", plan.timings.delta_s)?;
    tm.set_item("alpha_s", plan.timings.alpha_s)?;
    tm.set_item("z_s", plan.timings.z_s)?;
    tm.set_item("total_s", plan.timings.total_s)?;
    tm.set_item(
        "z_updates_s",
        plan.timings.z_updates_s.clone().into_pyarray(py),
    )?;
    d.set_item("timings", tm)?;
    Ok(d)
}

impl PyPlanner {
    /// `ReentrancyError` when the calling thread is inside this planner's own planning call
    /// (the call comes from its predictor, directly or through other planners).
    fn refuse_reentry(&self, method: &str) -> PyResult<()> {
        let me = std::thread::current().id();
        if *self
            .planning_on
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            == Some(me)
        {
            return Err(ReentrancyError::new_err(format!(
                "re-entrant call: Planner.{method} was called while this planner is planning, \
                 from inside its own predictor (a predictor may not call back into the planner \
                 it serves; use another Planner)"
            )));
        }
        Ok(())
    }

    /// The planner, locked; `ReentrancyError` for a re-entrant call ([`Self::refuse_reentry`]).
    /// Another thread's call waits for the planning call to end.
    fn lock(&self, method: &str) -> PyResult<MutexGuard<'_, Planner>> {
        self.refuse_reentry(method)?;
        Ok(self.planner.lock().unwrap_or_else(PoisonError::into_inner))
    }

    /// Plans `problem` with the GIL released; the plan as a dict. `method` names the Python
    /// method in a re-entrancy error.
    ///
    /// The call runs on a worker thread while this (the calling) thread polls Python's signal
    /// handlers every [`crate::interrupt::SIGNAL_POLL`] ([`interruptibly`]): on Ctrl-C the planner's cancel flag is set, the call
    /// ends within one predictor call ([`nudge_planner::PlannerError::Cancelled`]) and the
    /// `KeyboardInterrupt` (or whatever the handler raised) is returned; the warm start is
    /// kept.
    fn run<'py>(
        &self,
        py: Python<'py>,
        problem: &PlanningProblem<'_>,
        method: &str,
    ) -> PyResult<Bound<'py, PyDict>> {
        self.refuse_reentry(method)?;
        let cancel = Cancel::new();
        let plan = interruptibly(
            py,
            &cancel,
            "planning",
            || {
                let mut planner = self.planner.lock().unwrap_or_else(PoisonError::into_inner);
                *self
                    .planning_on
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner) = Some(std::thread::current().id());
                let _planning = Planning(&self.planning_on);
                planner.set_cancel(Some(cancel.clone()));
                let plan = self.predictor.with(|p| planner.plan(problem, p));
                planner.set_cancel(None);
                plan
            },
            |_| Ok(()),
        )?
        .map_err(planner_err)?;
        plan_to_dict(py, &plan)
    }
}

#[pymethods]
impl PyPlanner {
    /// A planner with `settings` (default: `PlannerSettings.default()`) predicting with
    /// `predictor`: a `Predictor`, or any object with `predict(history, candidates)`
    /// (`crate::py_predictor`). Its horizon must equal `settings.horizon`, and a teacher or
    /// student needs `settings.dt` = 0.3 s (`SettingsError` otherwise, `nudge_planner::fit`).
    #[new]
    #[pyo3(signature = (settings, predictor))]
    fn new(
        settings: Option<Bound<'_, PySettings>>,
        predictor: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        guard(|| {
            let settings =
                settings.map_or_else(PlannerSettings::default, |s| s.get().inner.clone());
            let predictor = PlanningPredictor::new(predictor, &settings)?;
            let planner = Planner::new(settings).map_err(planner_err)?;
            Ok(Self {
                planner: Mutex::new(planner),
                predictor,
                planning_on: Mutex::new(None),
            })
        })
    }

    /// The settings in use.
    #[getter]
    fn settings(&self) -> PyResult<PySettings> {
        let p = self.lock("settings")?;
        Ok(PySettings {
            inner: p.settings().clone(),
        })
    }

    /// The predictor in use (the object given).
    #[getter]
    fn predictor(&self, py: Python<'_>) -> Py<PyAny> {
        self.predictor.object(py)
    }

    /// Forgets the warm start.
    fn reset(&self) -> PyResult<()> {
        self.lock("reset")?.reset();
        Ok(())
    }

    /// One MPC call on raw arrays.
    ///
    /// `history` `[n, 8, 2]` (m, agent 0 = ego), `sizes` `[n, 2]` (length, width, m),
    /// `ego` `[4]` = (x, y, ψ, v) (m, m, rad, m/s), `y_target` (m), `v_ref` (m/s),
    /// `road` = (right, left) edge y (m), previous inputs `last_delta` (rad), `last_accel`
    /// (m/s²), `y_retreat` (m or None: the lane centre the fallbacks may steer back to,
    /// `PlanningProblem::y_retreat`). Returns a dict: `delta` `[T]`, `accel` `[T]`, `states` `[T, 4]`, `cost`,
    /// `iterations`, `predictor_calls`, `refused_candidates`, `qp_solves`, `primal_residual`, `change_residual`,
    /// `min_safety` and `rollout_min_safety` (float or None), `checked`, `status` (a
    /// `PlanStatus` name), `solver_failure` (`(qp, clarabel_status)` for `"SolverFailed"`,
    /// else None), `timings` (dict, seconds), `lane_violation` (None, or a dict `step`,
    /// `lane`, `kind` (`"Ended"` / `"NotBegun"`), `x`: the first planned state in a lane
    /// outside its extent).
    ///
    /// Lanes that begin and end (`PlanningProblem::lanes`, as `Scenario.lane_bounds`,
    /// `Scenario.lane_extents`, `Scenario.lane_extent_real` give them): `lane_bounds` `[L + 1]`
    /// (m), `lane_extents` `[L, 2]` (begin, end x, m), `lane_extent_real` `[L, 2]` (bool or
    /// 0/1; default all true). Both `lane_bounds` and `lane_extents` or neither.
    #[pyo3(signature = (history, sizes, ego, y_target, v_ref, road, last_delta = 0.0, last_accel = 0.0, y_retreat = None, lane_bounds = None, lane_extents = None, lane_extent_real = None))]
    #[allow(clippy::too_many_arguments)]
    fn plan<'py>(
        &self,
        py: Python<'py>,
        history: &Bound<'py, PyAny>,
        sizes: &Bound<'py, PyAny>,
        ego: &Bound<'py, PyAny>,
        y_target: f64,
        v_ref: f64,
        road: (f64, f64),
        last_delta: f64,
        last_accel: f64,
        y_retreat: Option<f64>,
        lane_bounds: Option<&Bound<'py, PyAny>>,
        lane_extents: Option<&Bound<'py, PyAny>>,
        lane_extent_real: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        guard(|| {
            let h_dims = [Dim::AtMost(MAX_AGENTS), Dim::Exact(T_OBS), Dim::Exact(2)];
            let (hist, hshape) = to_f64("history", history, &h_dims)?;
            let n = hshape[0];
            let (sz, _) = to_f64("sizes", sizes, &[Dim::Exact(n), Dim::Exact(2)])?;
            if let Some(bad) = sz.iter().find(|v| !v.is_finite() || **v <= 0.0) {
                return Err(InputError::new_err(format!(
                    "sizes: every length and width must be finite and positive, got {bad}"
                )));
            }
            let (e, _) = to_f64("ego", ego, &[Dim::Exact(4)])?;
            for (what, v) in [
                ("ego[x]", e[0]),
                ("ego[y]", e[1]),
                ("ego[psi]", e[2]),
                ("ego[v]", e[3]),
            ] {
                finite(what, v)?;
            }
            finite("y_target", y_target)?;
            finite("v_ref", v_ref)?;
            finite("road[0]", road.0)?;
            finite("road[1]", road.1)?;
            finite("last_delta", last_delta)?;
            finite("last_accel", last_accel)?;
            if let Some(y) = y_retreat {
                finite("y_retreat", y)?;
            }
            let history = History::new(hist, n).map_err(predictor_err)?;
            let sizes: Vec<[f64; 2]> = sz.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
            let layout = lane_layout(lane_bounds, lane_extents, lane_extent_real)?;
            let problem = PlanningProblem {
                ego: EgoState {
                    x: e[0],
                    y: e[1],
                    psi: e[2],
                    v: e[3],
                },
                last_delta,
                last_accel,
                history: &history,
                sizes: &sizes,
                y_target,
                v_ref,
                road: [road.0, road.1],
                y_retreat,
                lanes: layout
                    .as_ref()
                    .map(|(bounds, extents)| Lanes { bounds, extents }),
            };
            self.run(py, &problem, "plan")
        })
    }

    /// One MPC call at a scenario's start, as the simulator's first step: ego state from the
    /// last observed step, `v_ref` = its speed, target = the centre of `target_lane` (default:
    /// the lane the simulator draws for `seed` in a run with this planner's settings under
    /// `config`, default `SimConfig.default()`).
    #[pyo3(
        signature = (scenario, target_lane = None, seed = Int::from(0), config = None),
        text_signature = "($self, scenario, target_lane=None, seed=0, config=None)"
    )]
    fn plan_scenario<'py>(
        &self,
        py: Python<'py>,
        scenario: &PyScenario,
        target_lane: Option<Int>,
        seed: Int,
        config: Option<Bound<'_, PySimConfig>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        guard(|| {
            self.refuse_reentry("plan_scenario")?;
            let seed = seed.u64("seed", u64::MAX)?;
            let target_lane = target_lane
                .map(|l| l.usize("target_lane", usize::MAX))
                .transpose()?;
            let sc = &scenario.inner;
            let lane = match target_lane {
                Some(l) if l < sc.lane_centres.len() => l,
                Some(l) => {
                    return Err(InputError::new_err(format!(
                        "target_lane {l} out of range: the scenario has {} lanes",
                        sc.lane_centres.len()
                    )));
                }
                None => {
                    let settings = self.settings()?.inner;
                    let config = config.map_or_else(SimConfig::default, |c| c.get().inner);
                    nudge_sim::target_lane(sc, seed, &settings, &config).map_err(sim_err)?
                }
            };
            let history = History::new(sc.history.clone(), sc.n_agents).map_err(predictor_err)?;
            let problem = PlanningProblem::at_scenario_start(sc, &history, sc.lane_centres[lane]);
            let d = self.run(py, &problem, "plan_scenario")?;
            d.set_item("target_lane", lane)?;
            d.set_item("y_target", sc.lane_centres[lane])?;
            Ok(d)
        })
    }

    fn __repr__(&self) -> String {
        format!("Planner(predictor={:?})", self.predictor.name())
    }
}

/// The lane layout of `Planner.plan` (`lane_bounds` `[L + 1]`, `lane_extents` `[L, 2]`,
/// `lane_extent_real` `[L, 2]` of bools or 0/1, default all true); `None` without one. Values
/// are checked by `PlanningProblem::check` (a `BadLane` error naming the lane and field).
fn lane_layout(
    bounds: Option<&Bound<'_, PyAny>>,
    extents: Option<&Bound<'_, PyAny>>,
    real: Option<&Bound<'_, PyAny>>,
) -> PyResult<Option<(Vec<f64>, Vec<LaneExtent>)>> {
    let (bounds, extents) = match (bounds, extents) {
        (None, None) => {
            return if real.is_some() {
                Err(InputError::new_err(
                    "lane_extent_real: given without lane_bounds and lane_extents",
                ))
            } else {
                Ok(None)
            };
        }
        (Some(b), Some(e)) => (b, e),
        _ => {
            return Err(InputError::new_err(
                "lane_bounds, lane_extents: give both or neither",
            ));
        }
    };
    let (ext, eshape) = to_f64(
        "lane_extents",
        extents,
        &[Dim::AtMost(MAX_LANES), Dim::Exact(2)],
    )?;
    let nl = eshape[0];
    let (b, _) = to_f64("lane_bounds", bounds, &[Dim::Exact(nl + 1)])?;
    let flags: Vec<bool> = match real {
        None => vec![true; 2 * nl],
        Some(r) => {
            // A bool or integer array is read as numbers; every value must be exactly 0 or 1.
            let np = r.py().import("numpy")?;
            let arr = np.call_method1("asarray", (r,))?;
            let kind: String = arr.getattr("dtype")?.getattr("kind")?.extract()?;
            let arr = if matches!(kind.as_str(), "b" | "i" | "u") {
                arr.call_method1("astype", ("float64",))?
            } else {
                r.clone()
            };
            let (v, _) = to_f64("lane_extent_real", &arr, &[Dim::Exact(nl), Dim::Exact(2)])?;
            if let Some(i) = v.iter().position(|&f| f != 0.0 && f != 1.0) {
                return Err(InputError::new_err(format!(
                    "lane_extent_real: lane {} has flag {} (0 or 1, or a bool, expected)",
                    i / 2,
                    v[i]
                )));
            }
            v.iter().map(|&f| f == 1.0).collect()
        }
    };
    let extents = (0..nl)
        .map(|k| LaneExtent {
            begin: ext[2 * k],
            end: ext[2 * k + 1],
            begins: flags[2 * k],
            ends: flags[2 * k + 1],
        })
        .collect();
    Ok(Some((b, extents)))
}
