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
use crate::arrays::{Dim, check_shape, to_f64};
use crate::errors::{InputError, NudgeError, scenario_err};
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

    /// A scene from your own data, validated exactly as a scenario file is (the arrays are
    /// written to a scenario file image in memory and read back by the file reader: every
    /// check of `Scenario.load`, naming the array, agent and field). Road frame: x along
    /// travel, y lateral positive left (m); 0.3 s steps; agent 0 is the ego.
    ///
    /// `history` `[n, 8, 2]` observed positions, oldest first; `size` `[n, 2]` (length,
    /// width); `lane_bounds` `[L + 1]` lane lines, ascending (the first and last are the road
    /// edges); `ego_lane` the ego's lane index. Optional: `heading`, `speed` `[n]` at the last
    /// observed step (default: from the last two observed positions); `future` `[n, F, 2]`
    /// (F ≥ 6) with `future_valid` `[n, F]` bool, the logged futures where known (default: 6
    /// steps at constant velocity, none valid: no log); `lane_centres` `[L]` (default: midway
    /// between the lines); `agent_ids` `[n]` int (default 0..n); `lane_extents` `[L, 2]`
    /// (begin, end x) with `lane_extent_real` `[L, 2]` bool (a "nudge.scenario/2" scene);
    /// `name`; `metadata` (str → str). Raises `InputError` for an array of the wrong type or
    /// shape, `ScenarioError` for what the file reader refuses.
    #[staticmethod]
    #[pyo3(signature = (
        history, size, lane_bounds, ego_lane, *, heading = None, speed = None, future = None,
        future_valid = None, lane_centres = None, agent_ids = None, lane_extents = None,
        lane_extent_real = None, name = "scene", metadata = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn from_arrays(
        history: &Bound<'_, PyAny>,
        size: &Bound<'_, PyAny>,
        lane_bounds: &Bound<'_, PyAny>,
        ego_lane: Int,
        heading: Option<Bound<'_, PyAny>>,
        speed: Option<Bound<'_, PyAny>>,
        future: Option<Bound<'_, PyAny>>,
        future_valid: Option<Bound<'_, PyAny>>,
        lane_centres: Option<Bound<'_, PyAny>>,
        agent_ids: Option<Bound<'_, PyAny>>,
        lane_extents: Option<Bound<'_, PyAny>>,
        lane_extent_real: Option<Bound<'_, PyAny>>,
        name: &str,
        metadata: Option<HashMap<String, String>>,
    ) -> PyResult<Self> {
        guard(|| {
            const ANY: Dim = Dim::AtMost(1 << 20);
            let (history, shape) =
                to_f64("history", history, &[ANY, Dim::Exact(T_OBS), Dim::Exact(2)])?;
            let n = shape[0];
            let (size, _) = to_f64("size", size, &[Dim::Exact(n), Dim::Exact(2)])?;
            let (lane_bounds, lshape) = to_f64("lane_bounds", lane_bounds, &[ANY])?;
            let nl = lshape[0].saturating_sub(1);
            let ego_lane = ego_lane.usize("ego_lane", usize::MAX)?;
            let last = |a: usize, back: usize| {
                let i = (a * T_OBS + T_OBS - 1 - back) * 2;
                [history[i], history[i + 1]]
            };
            let motion = |a: usize| {
                let (p, q) = (last(a, 0), last(a, 1));
                [p[0] - q[0], p[1] - q[1]]
            };
            let per_agent =
                |what: &str, v: Option<Bound<'_, PyAny>>, default: &dyn Fn(usize) -> f64| {
                    v.map_or_else(
                        || Ok((0..n).map(default).collect()),
                        |v| to_f64(what, &v, &[Dim::Exact(n)]).map(|(v, _)| v),
                    )
                };
            let heading = per_agent("heading", heading, &|a| {
                let d = motion(a);
                if d[0] == 0.0 && d[1] == 0.0 {
                    0.0
                } else {
                    d[1].atan2(d[0])
                }
            })?;
            let speed = per_agent("speed", speed, &|a| {
                let d = motion(a);
                d[0].hypot(d[1]) / nudge_predictor::DT
            })?;
            let (n_future, future, future_valid) = match (future, future_valid) {
                (Some(f), Some(v)) => {
                    let (f, fshape) = to_f64("future", &f, &[Dim::Exact(n), ANY, Dim::Exact(2)])?;
                    let valid = bools("future_valid", &v, &[n, fshape[1]])?;
                    (fshape[1], f, valid)
                }
                (None, None) => {
                    const STEPS: usize = 6;
                    let f = (0..n)
                        .flat_map(|a| {
                            let (p, d) = (last(a, 0), motion(a));
                            (1..=STEPS)
                                .flat_map(move |k| [p[0] + d[0] * k as f64, p[1] + d[1] * k as f64])
                        })
                        .collect();
                    (STEPS, f, vec![false; n * STEPS])
                }
                _ => {
                    return Err(InputError::new_err(
                        "future and future_valid: give both or neither",
                    ));
                }
            };
            let lane_centres = match lane_centres {
                Some(c) => to_f64("lane_centres", &c, &[Dim::Exact(nl)])?.0,
                None => lane_bounds
                    .windows(2)
                    .map(|w| 0.5 * (w[0] + w[1]))
                    .collect(),
            };
            let agent_ids = match agent_ids {
                Some(ids) => ints("agent_ids", &ids, n)?,
                None => (0..n)
                    .map(|a| i64::try_from(a).unwrap_or(i64::MAX))
                    .collect(),
            };
            let lane_extents = match (lane_extents, lane_extent_real) {
                (Some(e), Some(r)) => {
                    let (e, _) = to_f64("lane_extents", &e, &[Dim::Exact(nl), Dim::Exact(2)])?;
                    let r = bools("lane_extent_real", &r, &[nl, 2])?;
                    Some(
                        (0..nl)
                            .map(|k| nudge_planner::LaneExtent {
                                begin: e[2 * k],
                                end: e[2 * k + 1],
                                begins: r[2 * k],
                                ends: r[2 * k + 1],
                            })
                            .collect(),
                    )
                }
                (None, None) => None,
                _ => {
                    return Err(InputError::new_err(
                        "lane_extents and lane_extent_real: give both or neither",
                    ));
                }
            };
            let mut meta = metadata.unwrap_or_default();
            meta.entry("source".into())
                .or_insert_with(|| "Scenario.from_arrays".into());
            let draft = Scenario {
                name: name.to_string(),
                n_agents: n,
                history,
                heading,
                speed,
                size: size.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
                n_future,
                future,
                future_valid,
                lane_centres,
                lane_bounds,
                ego_lane,
                agent_ids,
                lane_extents,
                metadata: meta,
            };
            let path = PathBuf::from(format!("{name}.safetensors"));
            let sc = draft
                .to_bytes()
                .and_then(|bytes| Scenario::from_bytes(&bytes, &path))
                .map_err(scenario_err)?;
            Ok(Self {
                inner: Arc::new(sc),
                path,
            })
        })
    }

    /// Writes this scene as a scenario file at `path` (the image `Scenario.load` reads back
    /// equal; "nudge.scenario/2" when it has lane extents), e.g. to run it with
    /// `nudge.simulate([path])` or `nudge simulate --scenes DIR`.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        guard(|| {
            let bytes = self.inner.to_bytes().map_err(scenario_err)?;
            py.detach(|| std::fs::write(&path, bytes))
                .map_err(|e| NudgeError::new_err(format!("{}: {e}", path.display())))
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

/// `obj` as a bool array of `shape` (numpy bool dtype or a nested list of bools), row-major;
/// `InputError` naming `what` otherwise.
fn bools(what: &str, obj: &Bound<'_, PyAny>, shape: &[usize]) -> PyResult<Vec<bool>> {
    let py = obj.py();
    let a = py.import("numpy")?.call_method1("asarray", (obj,))?;
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    if kind != "b" {
        return Err(InputError::new_err(format!(
            "{what}: expected a bool array, got dtype {}",
            a.getattr("dtype")?.str()?
        )));
    }
    let got: Vec<usize> = a.getattr("shape")?.extract()?;
    let dims: Vec<Dim> = shape.iter().map(|&n| Dim::Exact(n)).collect();
    check_shape(what, &got, &dims)?;
    a.call_method0("ravel")?.call_method0("tolist")?.extract()
}

/// `obj` as an int64 array `[n]` (numpy integer dtype or a list of ints); `InputError`
/// naming `what` otherwise.
fn ints(what: &str, obj: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<i64>> {
    let py = obj.py();
    let a = py.import("numpy")?.call_method1("asarray", (obj,))?;
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    if kind != "i" && kind != "u" {
        return Err(InputError::new_err(format!(
            "{what}: expected an integer array, got dtype {}",
            a.getattr("dtype")?.str()?
        )));
    }
    let got: Vec<usize> = a.getattr("shape")?.extract()?;
    check_shape(what, &got, &[Dim::Exact(n)])?;
    a.call_method0("tolist")?
        .extract()
        .map_err(|_| InputError::new_err(format!("{what}: values beyond int64")))
}
