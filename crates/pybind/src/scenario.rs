//! `nudge._native.Scenario`: a "nudge.scenario/1" or "nudge.scenario/2" scene file, read by the
//! Rust reader.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use nudge_planner::{PlannerSettings, Scenario};
use nudge_predictor::T_OBS;
use nudge_sim::SimConfig;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::prelude::*;

use crate::args::{Int, guard};
use crate::errors::{NudgeError, scenario_err};
use crate::settings::{PySettings, PySimConfig};

/// One real scene (agent 0 = ego), road frame, metres, 0.3 s steps.
#[pyclass(name = "Scenario", module = "nudge._native", frozen)]
#[derive(Debug, Clone)]
pub struct PyScenario {
    /// The parsed scenario.
    pub inner: Arc<Scenario>,
    /// The file it was read from.
    pub path: PathBuf,
}

fn reshape_err(e: impl std::fmt::Display) -> PyErr {
    NudgeError::new_err(format!("reshape failed: {e}"))
}

#[pymethods]
impl PyScenario {
    /// Reads and validates a scenario file (raises `ScenarioError` naming the problem).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        guard(|| {
            let sc = py
                .detach(|| Scenario::from_file(&path))
                .map_err(scenario_err)?;
            Ok(Self {
                inner: Arc::new(sc),
                path,
            })
        })
    }

    /// File stem.
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }

    /// The file path.
    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// Agents n (ego included).
    #[getter]
    fn n_agents(&self) -> usize {
        self.inner.n_agents
    }

    /// Observed positions `[n, 8, 2]` (m).
    #[getter]
    fn history<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f64>>> {
        self.inner
            .history
            .clone()
            .into_pyarray(py)
            .reshape([self.inner.n_agents, T_OBS, 2])
            .map_err(reshape_err)
    }

    /// Heading at the last observed step `[n]` (rad).
    #[getter]
    fn heading<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.heading.clone().into_pyarray(py)
    }

    /// Speed at the last observed step `[n]` (m/s).
    #[getter]
    fn speed<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.speed.clone().into_pyarray(py)
    }

    /// (length, width) `[n, 2]` (m).
    #[getter]
    fn size<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let flat: Vec<f64> = self.inner.size.iter().flatten().copied().collect();
        flat.into_pyarray(py)
            .reshape([self.inner.n_agents, 2])
            .map_err(reshape_err)
    }

    /// Logged future positions `[n, F, 2]` (m); see `future_valid`.
    #[getter]
    fn future<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f64>>> {
        self.inner
            .future
            .clone()
            .into_pyarray(py)
            .reshape([self.inner.n_agents, self.inner.n_future, 2])
            .map_err(reshape_err)
    }

    /// Whether each logged future position is real data `[n, F]`.
    #[getter]
    fn future_valid<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<bool>>> {
        self.inner
            .future_valid
            .clone()
            .into_pyarray(py)
            .reshape([self.inner.n_agents, self.inner.n_future])
            .map_err(reshape_err)
    }

    /// Lane-centre y `[L]` (m), ascending.
    #[getter]
    fn lane_centres<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.lane_centres.clone().into_pyarray(py)
    }

    /// Lane-boundary y `[L + 1]` (m), ascending; first and last are the road edges.
    #[getter]
    fn lane_bounds<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.lane_bounds.clone().into_pyarray(py)
    }

    /// Where each lane begins and ends along x `[L, 2]` (m), in `lane_centres` order;
    /// `None` for a "nudge.scenario/1" file (its lanes run through the scene).
    #[getter]
    fn lane_extents<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f64>>>> {
        self.inner
            .lane_extents
            .as_ref()
            .map(|ext| {
                let flat: Vec<f64> = ext.iter().flat_map(|e| [e.begin, e.end]).collect();
                flat.into_pyarray(py)
                    .reshape([ext.len(), 2])
                    .map_err(reshape_err)
            })
            .transpose()
    }

    /// Whether each lane really begins / ends at its extent `[L, 2]` (an on-ramp joining, an
    /// acceleration or exit lane ending) rather than where the lane map stops; `None` for a
    /// "nudge.scenario/1" file.
    #[getter]
    fn lane_extent_real<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<Option<Bound<'py, PyArray2<bool>>>> {
        self.inner
            .lane_extents
            .as_ref()
            .map(|ext| {
                let flat: Vec<bool> = ext.iter().flat_map(|e| [e.begins, e.ends]).collect();
                flat.into_pyarray(py)
                    .reshape([ext.len(), 2])
                    .map_err(reshape_err)
            })
            .transpose()
    }

    /// The ego's lane index.
    #[getter]
    fn ego_lane(&self) -> usize {
        self.inner.ego_lane
    }

    /// Source vehicle ids `[n]`.
    #[getter]
    fn agent_ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        self.inner.agent_ids.clone().into_pyarray(py)
    }

    /// File metadata (schema, source, split, provenance, ...).
    #[getter]
    fn metadata(&self) -> HashMap<String, String> {
        self.inner.metadata.clone()
    }

    /// Road edges (right, left) y (m).
    #[getter]
    fn road(&self) -> (f64, f64) {
        let r = self.inner.road();
        (r[0], r[1])
    }

    /// The target lane the simulator draws for `seed` in a run under `settings` and `config`
    /// (defaults: `PlannerSettings.default()`, `SimConfig.default()`): an adjacent lane of the
    /// ego's that is open and does not really end within the run's reach
    /// (`nudge_sim::target_lane`, the one rule of every front end).
    #[pyo3(
        signature = (seed, settings = None, config = None),
        text_signature = "($self, seed, settings=None, config=None)"
    )]
    fn target_lane(
        &self,
        seed: Int,
        settings: Option<Bound<'_, PySettings>>,
        config: Option<Bound<'_, PySimConfig>>,
    ) -> PyResult<usize> {
        guard(|| {
            let seed = seed.u64("seed", u64::MAX)?;
            let settings =
                settings.map_or_else(PlannerSettings::default, |s| s.get().inner.clone());
            let config = config.map_or_else(SimConfig::default, |c| c.get().inner);
            nudge_sim::target_lane(&self.inner, seed, &settings, &config)
                .map_err(crate::errors::sim_err)
        })
    }

    /// The ego and its `keep` nearest neighbours (nearest first).
    fn nearest(&self, keep: Int) -> PyResult<Self> {
        guard(|| {
            let keep = keep.usize("keep", usize::MAX)?;
            Ok(Self {
                inner: Arc::new(self.inner.nearest(keep)),
                path: self.path.clone(),
            })
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "Scenario(name={:?}, n_agents={}, lanes={}, ego_lane={})",
            self.inner.name,
            self.inner.n_agents,
            self.inner.lane_centres.len(),
            self.inner.ego_lane
        )
    }
}
