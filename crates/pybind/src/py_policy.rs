//! Your own planner from Python in nudge's worlds and metrics: any object with
//! `plan(observation) -> plan` (and, optionally, `reset()`) drives the ego of
//! `nudge.simulate(..., planner=obj)` as a [`Policy`] (docs/python_planner.md).
//!
//! Every closed-loop step hands the object an observation dict (numpy arrays, road frame:
//! x along travel, y lateral positive left, metres, radians, m/s; agent 0 is the ego):
//!
//! * `scenario` (str), `seed` (int), `step` (int, 0-based), `dt` (0.3 s), `horizon` (T);
//! * `ego` `[4]` (x, y, ψ, v) measured now; `last_inputs` `[2]` (δ, a) applied at the
//!   previous step (0, 0 at the first);
//! * `history` `[n, 8, 2]` every agent's last 8 observed positions, oldest first;
//!   `sizes` `[n, 2]` (length, width);
//! * `lane_centres` `[L]`, `lane_bounds` `[L + 1]` (y of the lane lines, right to left),
//!   `road` `[2]` (right and left edge), `y_target` (the target lane's centre, or the own
//!   lane's while a lane-change abort holds), `y_retreat` (the lane the ego came from, or
//!   `None`), `v_ref` (the reference speed);
//! * `bounds`: `delta_max` (rad), `a_min`, `a_max` (m/s²), the inputs a plan may use.
//!
//! It returns a plan: a mapping with `delta` and `accel`, each T floats (rad, m/s²), the
//! inputs over the horizon. nudge applies the first pair. The plan is checked (finite, T
//! values, within `bounds`: no clamping) and rolled out with nudge's bicycle model; nudge's
//! own safety check judges the roll-out under the run's planning predictor (one predictor
//! call), and the step's `status` is `Converged` when it passes, `Unsafe` when it does not.
//! The MPC's own columns mean nothing for a foreign plan: `iterations` 0, `cost` and
//! `primal_residual` NaN, `decided_by` `admm`.
//!
//! The GIL is held only inside the object's calls. An exception the object raises, or a plan
//! that cannot be used, stops the run with [`PlannerError::Foreign`] naming the object's class,
//! the scene, the seed and the step; `nudge.simulate` raises it as `nudge.NudgeError` (a
//! raised exception as its cause) or `nudge.InputError` (an unusable plan).

use std::sync::Arc;

use nudge_planner::{
    Bicycle, DecidedBy, EgoState, Plan, PlanStatus, PlannerError, PlannerSettings, PlanningProblem,
    SafetyConstraint, Scenario, State,
};
use nudge_predictor::{Checked, Predictor, T_OBS};
use nudge_sim::Policy;
use numpy::PyArray1;
use numpy::PyArrayMethods;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyMapping};

use crate::errors::{InputError, NudgeError};

/// What a Python planner did wrong: the message, and the exception it raised (if it raised).
#[derive(Debug)]
pub struct PlannerFailure {
    message: String,
    exception: Option<PyErr>,
}

impl std::fmt::Display for PlannerFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for PlannerFailure {}

/// The Python planner object, checked once: shared by the runs of a batch.
#[derive(Debug, Clone)]
pub struct PythonPlanner {
    object: Arc<Py<PyAny>>,
    class: Arc<str>,
    has_reset: bool,
}

impl PythonPlanner {
    /// Wraps `object`: it must have a callable `plan`; `reset`, when present, must be
    /// callable. Raises `nudge.InputError` naming the method.
    pub fn new(object: &Bound<'_, PyAny>) -> PyResult<Self> {
        let class = object.get_type().qualname()?.to_string();
        let method = |name: &str| -> PyResult<bool> {
            match object.getattr_opt(name)? {
                Some(m) if m.is_callable() => Ok(true),
                Some(_) => Err(InputError::new_err(format!(
                    "planner {class}: `{name}` is not a method"
                ))),
                None => Ok(false),
            }
        };
        if !method("plan")? {
            return Err(InputError::new_err(format!(
                "planner {class}: no method `plan`; a planner is an object with \
                 plan(observation) -> {{\"delta\": [T], \"accel\": [T]}} (docs/python_planner.md)"
            )));
        }
        let has_reset = method("reset")?;
        Ok(Self {
            object: Arc::new(object.clone().unbind()),
            class: class.into(),
            has_reset,
        })
    }

    /// The planner's Python class (qualified name), as errors and provenance name it.
    #[must_use]
    pub fn class(&self) -> &str {
        &self.class
    }

    /// The policy of one run on `scene` with target-lane seed `seed`.
    #[must_use]
    pub fn policy(&self, scene: &Scenario, seed: u64, settings: &PlannerSettings) -> PyPolicy {
        PyPolicy {
            planner: self.clone(),
            scenario: scene.name.clone(),
            seed,
            lane_centres: scene.lane_centres.clone(),
            lane_bounds: scene.lane_bounds.clone(),
            settings: settings.clone(),
            step: 0,
            pending: None,
        }
    }
}

/// One run's [`Policy`] calling a [`PythonPlanner`].
pub struct PyPolicy {
    planner: PythonPlanner,
    scenario: String,
    seed: u64,
    lane_centres: Vec<f64>,
    lane_bounds: Vec<f64>,
    settings: PlannerSettings,
    /// The closed-loop step of the next `plan` call.
    step: usize,
    /// The failure of `reset()`, raised at the next `plan` call.
    pending: Option<PlannerError>,
}

impl PyPolicy {
    /// The error of the current step: `message`, and the exception raised.
    fn failure(&self, message: String, exception: Option<PyErr>) -> PlannerError {
        PlannerError::Foreign {
            policy: format!(
                "Python planner {} (scene {}, seed {}, step {})",
                self.planner.class, self.scenario, self.seed, self.step
            ),
            source: Box::new(PlannerFailure { message, exception }),
        }
    }

    /// `call` raised `e`.
    fn raised(&self, py: Python<'_>, call: &str, e: PyErr) -> PlannerError {
        let kind = e
            .get_type(py)
            .name()
            .map_or_else(|_| "an exception".into(), |n| n.to_string());
        let message = format!("{call} raised {kind}: {}", e.value(py));
        self.failure(message, Some(e))
    }

    /// The observation dict of `problem` (see the module documentation).
    fn observation<'py>(
        &self,
        py: Python<'py>,
        problem: &PlanningProblem<'_>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let run = RunInfo {
            scenario: &self.scenario,
            seed: self.seed,
            step: self.step,
            lane_centres: &self.lane_centres,
            lane_bounds: &self.lane_bounds,
            settings: &self.settings,
        };
        observation_dict(py, problem, &run)
    }

    /// The inputs `name` (`delta` or `accel`) of the plan `got`: T finite floats within
    /// [`lo`, `hi`].
    fn inputs(
        &self,
        got: &Bound<'_, PyAny>,
        name: &str,
        lo: f64,
        hi: f64,
    ) -> Result<Vec<f64>, String> {
        let t = self.settings.model.horizon;
        let mapping = got.cast::<PyMapping>().map_err(|_| {
            format!(
                "expected a mapping with \"delta\" and \"accel\", got {}",
                type_name(got)
            )
        })?;
        let value = mapping
            .get_item(name)
            .map_err(|_| format!("no \"{name}\""))?;
        let values: Vec<f64> = value
            .extract::<Vec<f64>>()
            .or_else(|_| {
                value
                    .call_method0("tolist")
                    .and_then(|l| l.extract::<Vec<f64>>())
            })
            .map_err(|_| format!("\"{name}\": expected {t} floats, got {}", type_name(&value)))?;
        check_inputs(&values, name, lo, hi, t)?;
        Ok(values)
    }
}

/// The type name of `v`, for messages.
fn type_name(v: &Bound<'_, PyAny>) -> String {
    v.get_type()
        .name()
        .map_or_else(|_| "?".into(), |n| n.to_string())
}

impl Policy for PyPolicy {
    fn reset(&mut self) {
        self.step = 0;
        if self.planner.has_reset {
            // An exception here surfaces at the first plan call (the trait's reset cannot
            // fail): it is kept and raised there.
            let failed = Python::attach(|py| {
                self.planner
                    .object
                    .bind(py)
                    .call_method0("reset")
                    .err()
                    .map(|e| self.raised(py, "reset()", e))
            });
            self.pending = failed;
        }
    }

    fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        if let Some(e) = self.pending.take() {
            return Err(e);
        }
        let b = self.settings.bounds.clone();
        let (delta, accel) = Python::attach(|py| -> Result<_, PlannerError> {
            let call = "plan(observation)";
            let obs = self.observation(py, problem).map_err(|e| {
                self.raised(py, "plan(observation) (handing over the observation)", e)
            })?;
            let got = self
                .planner
                .object
                .bind(py)
                .call_method1("plan", (obs,))
                .map_err(|e| self.raised(py, call, e))?;
            let unusable = |reason: String| {
                self.failure(format!("{call} returned an unusable plan: {reason}"), None)
            };
            let delta = self
                .inputs(&got, "delta", -b.delta_max, b.delta_max)
                .map_err(unusable)?;
            let accel = self
                .inputs(&got, "accel", b.a_min, b.a_max)
                .map_err(unusable)?;
            Ok((delta, accel))
        })?;
        self.step += 1;
        judged_plan(problem, &self.settings, delta, accel, predictor)
    }
}

/// The Python exception for a [`PlannerError::Foreign`] with message `msg`: an unusable plan
/// is `nudge.InputError(msg)`; a raised exception gives `nudge.NudgeError(msg)` with that
/// exception as its cause; one that is not an `Exception` (`KeyboardInterrupt`) passes
/// through unchanged.
pub fn failure_err(msg: String, source: Box<dyn std::error::Error + Send + Sync>) -> PyErr {
    let exception = source
        .downcast::<PlannerFailure>()
        .ok()
        .and_then(|f| f.exception);
    Python::attach(|py| match exception {
        Some(e) if !e.is_instance_of::<PyException>(py) => e,
        Some(cause) => {
            let err = NudgeError::new_err(msg);
            err.set_cause(py, Some(cause));
            err
        }
        None => InputError::new_err(msg),
    })
}

/// What an observation dict tells about the run besides the planning problem.
pub struct RunInfo<'a> {
    /// The scene's name.
    pub scenario: &'a str,
    /// The run's target-lane seed.
    pub seed: u64,
    /// The closed-loop step (0-based).
    pub step: usize,
    /// Lane centres `[L]` (y, m).
    pub lane_centres: &'a [f64],
    /// Lane lines `[L + 1]` (y, m).
    pub lane_bounds: &'a [f64],
    /// The planner settings (horizon, dt, bounds).
    pub settings: &'a PlannerSettings,
}

/// The observation dict of `problem` for the run `run` (the module documentation lists its
/// keys; docs/python_planner.md): what a Python planner and the Gymnasium environment see.
pub fn observation_dict<'py>(
    py: Python<'py>,
    problem: &PlanningProblem<'_>,
    run: &RunInfo<'_>,
) -> PyResult<Bound<'py, PyDict>> {
    let array = |values: &[f64], shape: &[usize]| -> PyResult<Bound<'py, PyAny>> {
        let a = PyArray1::from_slice(py, values).reshape(shape)?.into_any();
        a.getattr("flags")?.setattr("writeable", false)?;
        Ok(a)
    };
    let n = problem.history.n_agents();
    let e = &problem.ego;
    let sizes: Vec<f64> = problem.sizes.iter().flatten().copied().collect();
    let b = &run.settings.bounds;
    let bounds = PyDict::new(py);
    bounds.set_item("delta_max", b.delta_max)?;
    bounds.set_item("a_min", b.a_min)?;
    bounds.set_item("a_max", b.a_max)?;
    let d = PyDict::new(py);
    d.set_item("scenario", run.scenario)?;
    d.set_item("seed", run.seed)?;
    d.set_item("step", run.step)?;
    d.set_item("dt", run.settings.model.dt)?;
    d.set_item("horizon", run.settings.model.horizon)?;
    d.set_item("ego", array(&[e.x, e.y, e.psi, e.v], &[4])?)?;
    d.set_item(
        "last_inputs",
        array(&[problem.last_delta, problem.last_accel], &[2])?,
    )?;
    d.set_item(
        "history",
        array(problem.history.positions(), &[n, T_OBS, 2])?,
    )?;
    d.set_item("sizes", array(&sizes, &[n, 2])?)?;
    d.set_item(
        "lane_centres",
        array(run.lane_centres, &[run.lane_centres.len()])?,
    )?;
    d.set_item(
        "lane_bounds",
        array(run.lane_bounds, &[run.lane_bounds.len()])?,
    )?;
    d.set_item("road", array(&problem.road, &[2])?)?;
    d.set_item("y_target", problem.y_target)?;
    d.set_item("y_retreat", problem.y_retreat)?;
    d.set_item("v_ref", problem.v_ref)?;
    d.set_item("bounds", bounds)?;
    Ok(d)
}

/// Checks the inputs `values` named `name` (`delta` or `accel`): `t` values (the horizon),
/// each finite and within [`lo`, `hi`]; the message names the first that is not. Nothing is
/// clamped.
pub fn check_inputs(values: &[f64], name: &str, lo: f64, hi: f64, t: usize) -> Result<(), String> {
    if values.len() != t {
        return Err(format!(
            "\"{name}\": expected {t} values (the horizon), got {}",
            values.len()
        ));
    }
    for (k, &v) in values.iter().enumerate() {
        if !v.is_finite() {
            return Err(format!("\"{name}\"[{k}] is not finite ({v})"));
        }
        if v < lo || v > hi {
            return Err(format!(
                "\"{name}\"[{k}] = {v} is outside [{lo}, {hi}] (observation[\"bounds\"])"
            ));
        }
    }
    Ok(())
}

/// The plan's roll-out z_1..z_T from the measured state `ego` with the inputs `delta`,
/// `accel` under the bicycle model of `settings`.
fn rollout(
    settings: &PlannerSettings,
    ego: &EgoState,
    delta: &[f64],
    accel: &[f64],
) -> Vec<[f64; 4]> {
    let m = &settings.model;
    let model = Bicycle {
        l_f: m.l_f,
        l_r: m.l_r,
        dt: m.dt,
    };
    let mut z = State::new(ego.x, ego.y, ego.psi, ego.v);
    delta
        .iter()
        .zip(accel)
        .map(|(&d, &a)| {
            z = model.advance(&z, d, a);
            [z[0], z[1], z[2], z[3]]
        })
        .collect()
}

/// The plan of inputs `delta`, `accel` (T each, checked by [`check_inputs`]) made outside
/// nudge for `problem`: rolled out with nudge's bicycle model and judged by nudge's safety
/// check under the planning predictor `predictor` (one call): `Converged` when the check
/// passes, `Unsafe` when it does not. The MPC's own fields are empty (`iterations` 0,
/// `cost` and the residuals NaN).
///
/// # Errors
/// [`PlannerError::Predictor`] when the prediction fails.
pub fn judged_plan(
    problem: &PlanningProblem<'_>,
    settings: &PlannerSettings,
    delta: Vec<f64>,
    accel: Vec<f64>,
    predictor: &mut dyn Predictor,
) -> Result<Plan, PlannerError> {
    let states = rollout(settings, &problem.ego, &delta, &accel);
    // nudge's safety check on the roll-out under the planning predictor.
    let constraint = SafetyConstraint::new(problem, settings);
    let checked = constraint.vehicles().len();
    let (min_b, calls) = if checked == 0 {
        (None, 0)
    } else {
        let n_others = problem.history.n_agents() - 1;
        let t = states.len();
        let candidate: Vec<f64> = states.iter().flat_map(|z| [z[0], z[1]]).collect();
        let mut prediction = vec![0.0; n_others * t * 2];
        let mut p = Checked::new(predictor);
        p.set_scene(problem.history)
            .and_then(|()| p.predict(&candidate, &mut prediction))
            .map_err(PlannerError::Predictor)?;
        (constraint.binding(&states, &prediction).map(|w| w.b), 1)
    };
    let lane_violation = problem
        .lanes
        .as_ref()
        .and_then(|l| l.first_violation(&states));
    let safe = min_b.is_none_or(|b| b >= settings.safety.safety_min) && lane_violation.is_none();
    Ok(Plan {
        delta,
        accel,
        states,
        admm_states: Vec::new(),
        cost: f64::NAN,
        iterations: 0,
        predictor_calls: calls,
        refused_candidates: 0,
        qp_solves: 0,
        primal_residual: f64::NAN,
        change_residual: f64::NAN,
        min_safety: min_b,
        rollout_min_safety: min_b,
        checked,
        lane_violation,
        // Only the safety part is measured for a foreign plan (no corridor or heading bound
        // of nudge's call applies to it): the rest is NaN, "not measured".
        violation: nudge_planner::Violation {
            safety: min_b.map_or(0.0, |b| {
                if b.is_finite() {
                    (settings.safety.safety_min - b).max(0.0)
                } else {
                    f64::INFINITY
                }
            }),
            heading: f64::NAN,
            corridor: f64::NAN,
            road_edge: f64::NAN,
            lane: f64::NAN,
        },
        timings: nudge_planner::PhaseTimings::default(),
        status: if safe {
            PlanStatus::Converged
        } else {
            PlanStatus::Unsafe
        },
        decided_by: DecidedBy::External,
        budget_reached: None,
    })
}
