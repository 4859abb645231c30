//! `nudge._native.Predictor`: the teacher, the student and the constant-velocity baseline.

use std::path::PathBuf;
use std::sync::Mutex;

use nudge_predictor::{
    ConstantVelocity, History, MAX_AGENTS, MAX_BATCH, Predictor, PredictorSpec, T_OBS,
};
use numpy::{IntoPyArray, PyArray4, PyArrayMethods};
use pyo3::prelude::*;

use crate::args::{Int, guard};
use crate::arrays::{Dim, to_f64};
use crate::errors::{NudgeError, predictor_err};

/// An interactive predictor loaded from a `.safetensors` weights file (teacher or student,
/// whichever the file's config names) or the constant-velocity baseline.
#[pyclass(name = "Predictor", module = "nudge._native", frozen)]
pub struct PyPredictor {
    inner: Mutex<Box<dyn Predictor>>,
    name: &'static str,
    horizon: usize,
}

impl PyPredictor {
    /// Locks the inner predictor (a poisoned lock is recovered: predictors hold no invariant
    /// that a panic could break between calls).
    pub fn lock(&self) -> std::sync::MutexGuard<'_, Box<dyn Predictor>> {
        self.inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn wrap(inner: Box<dyn Predictor>) -> Self {
        let name = inner.name();
        let horizon = inner.horizon();
        Self {
            inner: Mutex::new(inner),
            name,
            horizon,
        }
    }
}

#[pymethods]
impl PyPredictor {
    /// Loads a teacher or student from `path` (raises `WeightsError` naming the problem).
    /// `horizon` (steps, default the file's): a teacher rolls its one-step network out that
    /// many times; a student predicts only its own horizon (`InputError` naming both
    /// otherwise).
    #[staticmethod]
    #[pyo3(signature = (path, horizon = None), text_signature = "(path, horizon=None)")]
    fn load(py: Python<'_>, path: PathBuf, horizon: Option<Int>) -> PyResult<Self> {
        guard(|| {
            let horizon = horizon
                .map(|h| h.usize("horizon", nudge_predictor::MAX_HORIZON))
                .transpose()?;
            let spec = py
                .detach(|| {
                    let spec = PredictorSpec::from_file(&path)?;
                    match horizon {
                        Some(h) => spec.with_horizon(h),
                        None => Ok(spec),
                    }
                })
                .map_err(predictor_err)?;
            Ok(Self::wrap(spec.build()))
        })
    }

    /// The constant-velocity baseline with a horizon of `horizon` steps.
    #[staticmethod]
    #[pyo3(signature = (horizon = Int::from(6)), text_signature = "(horizon=6)")]
    fn constant_velocity(horizon: Int) -> PyResult<Self> {
        guard(|| {
            let horizon = horizon.usize("horizon", nudge_predictor::MAX_HORIZON)?;
            let cv = ConstantVelocity::new(horizon).map_err(predictor_err)?;
            Ok(Self::wrap(Box::new(cv)))
        })
    }

    /// `"teacher"`, `"student"` or `"constant_velocity"`.
    #[getter]
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// Prediction horizon in 0.3 s steps.
    #[getter]
    fn horizon(&self) -> usize {
        self.horizon
    }

    /// Predicts the other agents' positions for every ego candidate.
    ///
    /// `history`: `[agents, 8, 2]` metres (agent 0 = ego); `candidates`: `[batch, horizon, 2]`
    /// metres (at most `MAX_BATCH` candidates); float64/float32 arrays or nested lists.
    /// Returns `[batch, agents - 1, horizon, 2]` float64. The GIL is released while the
    /// network runs.
    fn predict<'py>(
        &self,
        py: Python<'py>,
        history: &Bound<'py, PyAny>,
        candidates: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray4<f64>>> {
        guard(|| {
            let h_dims = [Dim::AtMost(MAX_AGENTS), Dim::Exact(T_OBS), Dim::Exact(2)];
            let (hist, hshape) = to_f64("history", history, &h_dims)?;
            let c_dims = [
                Dim::AtMost(MAX_BATCH),
                Dim::Exact(self.horizon),
                Dim::Exact(2),
            ];
            let (cand, cshape) = to_f64("candidates", candidates, &c_dims)?;
            let n = hshape[0];
            let batch = cshape[0];
            let horizon = self.horizon;
            let out = py.detach(|| -> Result<Vec<f64>, nudge_predictor::PredictorError> {
                let history = History::new(hist, n)?;
                let mut guard = self.lock();
                guard.set_scene(&history)?;
                let mut out = vec![0.0; batch * (n - 1) * horizon * 2];
                guard.predict(&cand, &mut out)?;
                Ok(out)
            });
            let out = out.map_err(predictor_err)?;
            out.into_pyarray(py)
                .reshape([batch, n - 1, horizon, 2])
                .map_err(|e| NudgeError::new_err(format!("reshape failed: {e}")))
        })
    }

    fn __repr__(&self) -> String {
        format!("Predictor(name={:?}, horizon={})", self.name, self.horizon)
    }
}
