//! Your own predictor from Python: any object with `predict(history, candidates)` (and,
//! optionally, `set_scene(history)` and an int attribute `horizon`) becomes a [`Predictor`]
//! that `nudge.Planner` and `nudge.simulate` plan with.
//!
//! The contract is the Rust [`Predictor`] trait's, in numpy (metres in the road frame: x along
//! travel, y lateral positive left; one step = 0.3 s; agent 0 is the ego):
//!
//! * `set_scene(history)` (optional): called once per planning step, before that step's
//!   `predict` calls; `history` is `[n, 8, 2]` float64, the last [`T_OBS`] observed positions
//!   of every agent, oldest first.
//! * `predict(history, candidates)`: `history` as above (the same array object for every call
//!   of a step), `candidates` `[batch, horizon, 2]` float64, the ego's positions at steps
//!   `1..=horizon` after the last observed step (the planner asks for one candidate at a
//!   time). Returns `[batch, n - 1, horizon, 2]` (a float64 or float32 array, or anything
//!   `numpy.asarray` makes one of, e.g. a CPU torch tensor): the positions of agents `1..n`
//!   at the same steps under each candidate.
//! * `horizon` (optional, default the planner's `settings.horizon`): steps predicted.
//!
//! Both arrays handed over are read-only. The candidates are checked as for the built-in
//! predictors before the call ([`nudge_predictor::check_batch`]: finite, within the ranges of
//! [`nudge_predictor::limits`]); the prediction's type and shape are checked here, its values
//! (finite, plausible) by the planner's [`nudge_predictor::Checked`], naming candidate, agent
//! and step. The GIL is held only inside these calls: the planner runs with it released.
//! Whatever goes wrong becomes a [`PredictorError::Foreign`] carrying a [`PythonFailure`];
//! [`failure_err`] turns it back into a `nudge.PredictorError` whose cause is the exception
//! the object raised.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, PoisonError};

use nudge_planner::{PlannerSettings, fit};
use nudge_predictor::{History, Predictor, PredictorError, T_OBS, check_batch, check_horizon};
use numpy::{PyArray1, PyArrayMethods, PyUntypedArray};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyList, PyTuple};

use crate::arrays::{Dim, to_f64};
use crate::errors::{PredictorError as PyPredictorError, settings_err};
use crate::predict::PyPredictor;

/// The name of every Python predictor ([`Predictor::name`]; the `predictor` column of
/// closed-loop records).
pub const NAME: &str = "python";

/// How the settings checks ([`fit`]) name a Python predictor in their messages.
pub const LABEL: &str = "Python predictor";

/// What a Python predictor did wrong: a message naming the object's class, the method and the
/// item, and the exception the method raised (if it raised).
#[derive(Debug)]
pub struct PythonFailure {
    message: String,
    exception: Option<PyErr>,
}

impl std::fmt::Display for PythonFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for PythonFailure {}

/// A Python object as a [`Predictor`] (see the module documentation).
pub struct PythonPredictor {
    object: Arc<Py<PyAny>>,
    /// The object's class name, for messages.
    class: Arc<str>,
    horizon: usize,
    has_set_scene: bool,
    scene: Option<Scene>,
}

/// The scene of the current planning step.
struct Scene {
    /// `[n, T_OBS, 2]` read-only float64, handed to every `predict` of the step.
    history: Py<PyAny>,
    n_agents: usize,
    /// The ego's last observed position (m).
    ego_last: [f64; 2],
}

impl PythonPredictor {
    /// Wraps `object`: it must have a callable `predict`; `set_scene`, when present, must be
    /// callable; `horizon`, when present, an int in `1..=MAX_HORIZON` (default
    /// `default_horizon`). Raises `nudge.PredictorError` naming the method or attribute.
    pub fn new(object: &Bound<'_, PyAny>, default_horizon: usize) -> PyResult<Self> {
        let class = object.get_type().qualname()?.to_string();
        let method = |name: &str| -> PyResult<bool> {
            match object.getattr_opt(name)? {
                Some(m) if m.is_callable() => Ok(true),
                Some(_) => Err(PyPredictorError::new_err(format!(
                    "predictor {class}: `{name}` is not a method"
                ))),
                None => Ok(false),
            }
        };
        if !method("predict")? {
            return Err(PyPredictorError::new_err(format!(
                "predictor {class}: no method `predict`; a predictor is a nudge.Predictor or an \
                 object with predict(history [n, 8, 2], candidates [batch, horizon, 2]) -> \
                 [batch, n - 1, horizon, 2] (metres)"
            )));
        }
        let has_set_scene = method("set_scene")?;
        let horizon = match object.getattr_opt("horizon")? {
            None => default_horizon,
            Some(h) => h
                .extract::<usize>()
                .ok()
                .filter(|&h| check_horizon(h).is_ok())
                .ok_or_else(|| {
                    PyPredictorError::new_err(format!(
                        "predictor {class}: `horizon` must be an int in 1..={}, got {}",
                        nudge_predictor::MAX_HORIZON,
                        h.repr().map_or_else(|_| "?".into(), |r| r.to_string())
                    ))
                })?,
        };
        Ok(Self {
            object: Arc::new(object.clone().unbind()),
            class: class.into(),
            horizon,
            has_set_scene,
            scene: None,
        })
    }

    /// Another predictor calling the same object, with no scene set (one per closed-loop run).
    pub fn fresh(&self) -> Self {
        Self {
            object: Arc::clone(&self.object),
            class: Arc::clone(&self.class),
            horizon: self.horizon,
            has_set_scene: self.has_set_scene,
            scene: None,
        }
    }

    /// The failure `message`, with the exception raised.
    fn failure(&self, message: String, exception: Option<PyErr>) -> PredictorError {
        PredictorError::Foreign {
            predictor: NAME,
            source: Box::new(PythonFailure { message, exception }),
        }
    }

    /// `call` (e.g. `predict(history, candidates)`) raised `e`.
    fn raised(&self, py: Python<'_>, call: &str, e: PyErr) -> PredictorError {
        let kind = e
            .get_type(py)
            .name()
            .map_or_else(|_| "an exception".into(), |n| n.to_string());
        let message = format!("{}.{call} raised {kind}: {}", self.class, e.value(py));
        self.failure(message, Some(e))
    }

    /// The prediction `got` as `[batch, n - 1, horizon, 2]` values, row-major.
    fn prediction(&self, got: &Bound<'_, PyAny>, shape: [usize; 4]) -> Result<Vec<f64>, String> {
        let py = got.py();
        let array = if got.is_instance_of::<PyUntypedArray>()
            || got.is_instance_of::<PyList>()
            || got.is_instance_of::<PyTuple>()
        {
            got.clone()
        } else {
            // Anything numpy makes an array of (a CPU torch tensor, ...).
            py.import("numpy")
                .and_then(|np| np.call_method1("asarray", (got,)))
                .map_err(|e| format!("numpy.asarray could not convert it: {}", e.value(py)))?
        };
        let dims = shape.map(Dim::Exact);
        to_f64("prediction", &array, &dims)
            .map(|(values, _)| values)
            .map_err(|e| e.value(py).to_string())
    }
}

/// `values` as a read-only float64 array of `shape`.
fn read_only<'py>(py: Python<'py>, values: &[f64], shape: &[usize]) -> PyResult<Bound<'py, PyAny>> {
    let array = PyArray1::from_slice(py, values).reshape(shape)?.into_any();
    array.getattr("flags")?.setattr("writeable", false)?;
    Ok(array)
}

impl Predictor for PythonPredictor {
    fn name(&self) -> &'static str {
        NAME
    }

    fn horizon(&self) -> usize {
        self.horizon
    }

    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.scene = None;
        let n_agents = history.n_agents();
        let array = Python::attach(|py| -> nudge_predictor::Result<Py<PyAny>> {
            let array = read_only(py, history.positions(), &[n_agents, T_OBS, 2])
                .map_err(|e| self.raised(py, "set_scene(history) (handing over history)", e))?;
            if self.has_set_scene {
                self.object
                    .bind(py)
                    .call_method1("set_scene", (&array,))
                    .map_err(|e| self.raised(py, "set_scene(history)", e))?;
            }
            Ok(array.unbind())
        })?;
        self.scene = Some(Scene {
            history: array,
            n_agents,
            ego_last: history.at(0, T_OBS - 1),
        });
        Ok(())
    }

    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        let Some(scene) = &self.scene else {
            return Err(PredictorError::NoScene);
        };
        let (n, h) = (scene.n_agents, self.horizon);
        let batch = check_batch(candidates, out, h, n, scene.ego_last)?;
        let values = Python::attach(|py| -> nudge_predictor::Result<Vec<f64>> {
            let call = "predict(history, candidates)";
            let candidates =
                read_only(py, candidates, &[batch, h, 2]).map_err(|e| self.raised(py, call, e))?;
            let got = self
                .object
                .bind(py)
                .call_method1("predict", (scene.history.bind(py), candidates))
                .map_err(|e| self.raised(py, call, e))?;
            self.prediction(&got, [batch, n - 1, h, 2])
                .map_err(|reason| {
                    let message = format!(
                        "{}.{call} returned an unusable prediction (expected [batch, agents - 1, \
                     horizon, 2] float64 or float32): {reason}",
                        self.class
                    );
                    self.failure(message, None)
                })
        })?;
        out.copy_from_slice(&values);
        Ok(())
    }
}

/// The Python exception for a [`PredictorError::Foreign`] with message `msg` (the whole
/// context: planner, scene, step): `nudge.PredictorError(msg)` with the exception the
/// object raised as its cause; an exception that is not an `Exception` (`KeyboardInterrupt`,
/// `SystemExit`) passes through unchanged.
pub fn failure_err(msg: String, source: Box<dyn std::error::Error + Send + Sync>) -> PyErr {
    let exception = source
        .downcast::<PythonFailure>()
        .ok()
        .and_then(|f| f.exception);
    Python::attach(|py| match exception {
        Some(e) if !e.is_instance_of::<PyException>(py) => e,
        cause => {
            let err = PyPredictorError::new_err(msg);
            err.set_cause(py, cause);
            err
        }
    })
}

/// The predictor a `nudge.Planner` plans with: a `nudge.Predictor` or any other object with
/// `predict` ([`PythonPredictor`]).
pub enum PlanningPredictor {
    /// A built-in predictor.
    Native(Py<PyPredictor>),
    /// A Python object and its wrapper.
    Python(Py<PyAny>, Mutex<PythonPredictor>),
}

impl PlanningPredictor {
    /// `object` as the predictor of a planner with `settings`, checked to fit them
    /// ([`fit::check_predictor`]: `SettingsError` naming `horizon`, or `dt` for a teacher or
    /// student); `nudge.PredictorError` for an object without `predict`.
    pub fn new(object: &Bound<'_, PyAny>, settings: &PlannerSettings) -> PyResult<Self> {
        let (predictor, label, horizon) = match object.cast::<PyPredictor>() {
            Ok(native) => {
                let (name, horizon) = (native.get().name(), native.get().lock().horizon());
                (Self::Native(native.clone().unbind()), name, horizon)
            }
            Err(_) => {
                let p = PythonPredictor::new(object, settings.model.horizon)?;
                let horizon = p.horizon;
                let python = Self::Python(object.clone().unbind(), Mutex::new(p));
                (python, LABEL, horizon)
            }
        };
        fit::check_predictor(settings, label, horizon).map_err(settings_err)?;
        Ok(predictor)
    }

    /// The predictor's name (`"teacher"`, `"student"`, `"constant_velocity"` or [`NAME`]).
    pub fn name(&self) -> &'static str {
        match self {
            Self::Native(p) => p.get().name(),
            Self::Python(..) => NAME,
        }
    }

    /// The object given.
    pub fn object(&self, py: Python<'_>) -> Py<PyAny> {
        match self {
            Self::Native(p) => p.clone_ref(py).into_any(),
            Self::Python(o, _) => o.clone_ref(py),
        }
    }

    /// `f` on the locked predictor (call with the GIL released: a Python predictor takes it
    /// only around its own calls).
    pub fn with<R>(&self, f: impl FnOnce(&mut dyn Predictor) -> R) -> R {
        match self {
            Self::Native(p) => f(p.get().lock().as_mut()),
            Self::Python(_, p) => f(&mut *p.lock().unwrap_or_else(PoisonError::into_inner)),
        }
    }
}

/// The `predictor` argument of `simulate`: a name (`"teacher"`, `"student"`,
/// `"constant_velocity"`) or weights path (`str` or `os.PathLike`), or any other object,
/// planned with as a [`PythonPredictor`].
pub enum PredictorArg {
    /// A name or weights path.
    Path(PathBuf),
    /// A Python predictor object.
    Object(Py<PyAny>),
}

impl<'a, 'py> FromPyObject<'a, 'py> for PredictorArg {
    type Error = PyErr;

    fn extract(obj: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        match obj.extract::<PathBuf>() {
            Ok(path) => Ok(Self::Path(path)),
            Err(_) => Ok(Self::Object(obj.to_owned().unbind())),
        }
    }
}

impl PredictorArg {
    /// The [`PythonPredictor`] of an object (`None` for a name or path), predicting
    /// `default_horizon` steps unless it says otherwise.
    pub fn python(
        &self,
        py: Python<'_>,
        default_horizon: usize,
    ) -> PyResult<Option<PythonPredictor>> {
        match self {
            Self::Path(_) => Ok(None),
            Self::Object(o) => PythonPredictor::new(o.bind(py), default_horizon).map(Some),
        }
    }
}
