//! `nudge._native.simulate`: closed-loop lane changes over scenario files, in parallel on a
//! rayon pool, returning the run and step columns of `nudge_sim::columns` as numpy
//! arrays (and, with `record=True`, every candidate the planning predictor evaluated).

// SimError carries the planner's and predictor's errors by value; they are rare, cold paths.
#![allow(clippy::result_large_err)]

use std::path::PathBuf;

use nudge_planner::PlannerSettings;
use nudge_predictor::{Predictor, Records, T_OBS, default_assets_dir};
use nudge_sim::defaults;
use nudge_sim::{Batch, BatchRequest, Cancel, Keep, Progress, RunOutput, SimConfig};
use nudge_sim::{Column, Table, collision_table, run_table, step_table};
use nudge_sim::{PlanningFactory, PolicyFactory};
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use nudge::provenance::{Inputs, ModelRef, Provenance};

use crate::args::{Int, guard};
use crate::errors::{InputError, NudgeError, sim_err};
use crate::interrupt::interruptibly;
use crate::py_policy::PythonPlanner;
use crate::py_predictor::{LABEL, NAME as PYTHON, PredictorArg};
use crate::settings::{PySettings, PySimConfig, with_overrides};

fn reshape_err(e: impl std::fmt::Display) -> PyErr {
    NudgeError::new_err(format!("reshape failed: {e}"))
}

/// A usize column as int64.
fn i64s(v: impl IntoIterator<Item = usize>) -> Vec<i64> {
    v.into_iter()
        .map(|x| i64::try_from(x).unwrap_or(i64::MAX))
        .collect()
}

/// The front ends' defaults, from Rust (`nudge_sim::defaults`): the Python wrapper's
/// signature reads them.
pub fn defaults_dict(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("predictor", defaults::PREDICTOR.as_str())?;
    d.set_item("world_predictor", defaults::WORLD_PREDICTOR.as_str())?;
    d.set_item("seed", defaults::SEED)?;
    d.set_item("runs", defaults::RUNS_PER_SCENE)?;
    Ok(d)
}

/// Runs `batch` on a worker thread with the GIL released while this (the calling) thread
/// polls Python's signal handlers every [`crate::interrupt::SIGNAL_POLL`] ([`interruptibly`]): on Ctrl-C the batch is cancelled
/// (every run stops before its next closed-loop step) and the `KeyboardInterrupt` is
/// returned. `planning` builds each run's planning predictor when the batch was prepared for
/// one from Python ([`BatchRequest::prepare_foreign`]). `progress`, a Python callable, is
/// called as `progress(done, total)` (runs finished, runs in all) from this thread whenever
/// the count of finished runs grows, and once at the end; an exception it raises cancels the
/// batch and is returned.
fn run_interruptibly(
    py: Python<'_>,
    batch: &Batch,
    keep: Keep,
    planning: Option<&PlanningFactory<'_>>,
    policy: Option<&PolicyFactory<'_>>,
    progress: Option<&Py<PyAny>>,
) -> PyResult<Vec<RunOutput>> {
    let cancel = Cancel::new();
    let count = Progress::new();
    let total = batch.specs.len();
    let mut shown: Option<usize> = None;
    let mut report = |done: usize| -> PyResult<()> {
        match progress {
            Some(cb) if shown != Some(done) => {
                shown = Some(done);
                Python::attach(|py| cb.call1(py, (done, total)).map(drop))
            }
            _ => Ok(()),
        }
    };
    interruptibly(
        py,
        &cancel,
        "simulation",
        || batch.run_counted(keep, &cancel, planning, policy, &count),
        |_| report(count.done()),
    )
}

/// Closed-loop simulation of every scenario in `scene_paths` (in the given order), `runs`
/// runs each; run r of scene i draws its target lane from seed `scene_seeds[i] + r` when
/// `scene_seeds` is given, else `seed + i * runs + r` (`nudge_sim::run_specs`). Runs go
/// in parallel on `threads` rayon threads (default: all cores; each planner call stays
/// single-threaded).
///
/// `predictor` / `world_predictor`: `"teacher"`, `"student"`, `"constant_velocity"` (named
/// models under `assets`, default `$NUDGE_ASSETS` or `./assets`) or a weights path; `predictor`
/// may also be a Python object with `predict(history, candidates)` (`crate::py_predictor`;
/// its runs go one after another on one thread, as they share the object); the world
/// model of a `"teacher"` world defaults to the shipped teacher and must be a teacher. `idm`:
/// the driver population of an `"idm"` world ("nudge.idm/1" JSON, default
/// `<assets>/worlds/idm.json`).
/// `config` (default `SimConfig.default()`) with `**config_overrides` (any `SimConfig` field,
/// e.g. `world="log_replay"`, `max_steps=4`) sets the closed loop. `on_error`: `"raise"` (the
/// first failing run raises) or `"skip"` (its `error` column holds the message).
///
/// Every argument is checked by `nudge_sim::BatchRequest::prepare` (the CLI's validation
/// too) before any run starts. Ctrl-C raises `KeyboardInterrupt` within about a second.
///
/// `trace`: keep every step's plan and the planning predictor's predicted reaction to it;
/// the result then holds `"traces"`, one dict per run (`None` for a run that could not run)
/// with `plan` `[steps, T + 1, 4]`, `predicted` `[steps, n − 1, T, 2]`, the binding vehicle
/// and its ellipses, the agents `[steps + 1, n, 3]`, ... (`nudge._native.animate` draws it).
/// Off by default: the other outputs are the same either way.
///
/// `planner`: your own planner, any object with `plan(observation) -> {"delta": [T],
/// "accel": [T]}` (and optionally `reset()`), driving the ego instead of nudge's planner
/// (`crate::py_policy`, docs/python_planner.md); its runs go one after another on one thread.
///
/// `progress`: a callable called as `progress(done, total)` (runs finished, runs in all) about
/// every 50 ms while the count grows and once at the end, from the calling thread; an
/// exception it raises stops the batch and is raised.
///
/// `out`: a folder to write the record set into, as `nudge simulate --out` does
/// (`nudge::records::write_records`: `steps.csv`, `runs.csv`, `collisions.csv`,
/// `records.json` and `provenance.json`, one atomic set with its manifest `outputs.sha256`;
/// docs/records.md). It is created before any run (a path that cannot be a folder raises
/// `NudgeError` first); provenance's `command` is `command` (the Python wrapper passes the
/// process's `sys.executable` and `sys.argv`), its `settings_file` and `config_file` are null
/// (settings come as objects), a Python predictor is `{"name": "python", "file": null}` and a
/// Python planner `"planner": "python:<class>"`.
///
/// Returns `{"runs": {...}, "steps": {...}, "collisions": {...}}` of numpy columns (plus
/// `"examples"` when `record`, `"traces"` when `trace`): see the `.pyi` stub for every column.
#[pyfunction]
#[pyo3(signature = (
    scene_paths,
    predictor = PredictorArg::Path(PathBuf::from(defaults::PREDICTOR.as_str())),
    *,
    world_predictor = None,
    idm = None,
    seed = Int::from(defaults::SEED),
    scene_seeds = None,
    runs = Int::from(defaults::RUNS_PER_SCENE as u64),
    threads = None,
    settings = None,
    config = None,
    record = false,
    trace = false,
    on_error = "raise",
    assets = None,
    progress = None,
    planner = None,
    out = None,
    command = None,
    **config_overrides
))]
#[allow(clippy::too_many_arguments)]
pub fn simulate<'py>(
    py: Python<'py>,
    scene_paths: Vec<PathBuf>,
    predictor: PredictorArg,
    world_predictor: Option<PathBuf>,
    idm: Option<PathBuf>,
    seed: Int,
    scene_seeds: Option<Vec<Int>>,
    runs: Int,
    threads: Option<Int>,
    settings: Option<Bound<'_, PySettings>>,
    config: Option<Bound<'_, PySimConfig>>,
    record: bool,
    trace: bool,
    on_error: &str,
    assets: Option<PathBuf>,
    progress: Option<Bound<'_, PyAny>>,
    planner: Option<Bound<'_, PyAny>>,
    out: Option<PathBuf>,
    command: Option<Vec<String>>,
    config_overrides: Option<&Bound<'_, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    guard(|| {
        if let Some(p) = &progress
            && !p.is_callable()
        {
            return Err(InputError::new_err(format!(
                "invalid argument `progress`: expected a callable progress(done, total) or None, \
                 got {}",
                p.get_type().name()?
            )));
        }
        let progress = progress.map(Bound::unbind);
        let seed = seed.u64("seed", u64::MAX)?;
        let runs = runs.usize("runs", nudge_sim::MAX_RUNS)?;
        let threads = threads
            .map(|t| t.usize("threads", nudge_sim::MAX_THREADS))
            .transpose()?;
        let scene_seeds: Option<Vec<u64>> = scene_seeds
            .map(|v| {
                v.into_iter()
                    .map(|s| s.u64("scene_seeds", u64::MAX))
                    .collect()
            })
            .transpose()?;
        let settings = settings.map_or_else(PlannerSettings::default, |s| s.get().inner.clone());
        let base = config.map_or_else(SimConfig::default, |c| c.get().inner);
        let cfg = match config_overrides {
            Some(o) => with_overrides(&base, o.as_any())?,
            None => base,
        };
        let skip = match on_error {
            "raise" => false,
            "skip" => true,
            other => {
                return Err(InputError::new_err(format!(
                    "on_error: expected \"raise\" or \"skip\", got {other:?}"
                )));
            }
        };
        let assets = assets.unwrap_or_else(default_assets_dir);
        let python = predictor.python(py, settings.model.horizon)?;
        if python.is_some() && threads.is_some_and(|t| t != 1) {
            return Err(InputError::new_err(format!(
                "invalid argument `threads`: a Python predictor plans on one thread (its runs \
                 share the object), got {}",
                threads.unwrap_or(1)
            )));
        }
        let own_planner = planner
            .as_ref()
            .filter(|p| !p.is_none())
            .map(PythonPlanner::new)
            .transpose()?;
        if own_planner.is_some() && threads.is_some_and(|t| t != 1) {
            return Err(InputError::new_err(format!(
                "invalid argument `threads`: a Python planner plans on one thread (its runs \
                 share the object), got {}",
                threads.unwrap_or(1)
            )));
        }
        let one_thread = python.is_some() || own_planner.is_some();
        let request = BatchRequest {
            scene_paths: &scene_paths,
            predictor: match &predictor {
                PredictorArg::Path(p) => p,
                PredictorArg::Object(_) => std::path::Path::new(PYTHON),
            },
            world_predictor: world_predictor.as_deref(),
            idm: idm.as_deref(),
            assets: &assets,
            seed,
            runs_per_scene: runs,
            scene_seeds: scene_seeds.as_deref(),
            threads: if one_thread { Some(1) } else { threads },
            settings: &settings,
            config: &cfg,
        };
        let batch = py
            .detach(|| match &python {
                Some(p) => request.prepare_foreign(LABEL, p.horizon()),
                None => request.prepare(),
            })
            .map_err(sim_err)?;
        if let Some(dir) = &out {
            nudge::records::prepare_dir(dir, "out").map_err(NudgeError::new_err)?;
        }
        let fresh = python
            .as_ref()
            .map(|p| move || Box::new(p.fresh()) as Box<dyn Predictor>);
        let planning = fresh.as_ref().map(|f| f as &PlanningFactory<'_>);
        let keep = Keep {
            examples: record,
            traces: trace,
        };
        let make_policy = own_planner.as_ref().map(|p| {
            let settings = &settings;
            move |sc: &nudge_planner::Scenario, seed: u64| {
                Box::new(p.policy(sc, seed, settings)) as Box<dyn nudge_sim::Policy>
            }
        });
        let policy = make_policy.as_ref().map(|f| f as &PolicyFactory<'_>);
        let mut outputs = run_interruptibly(py, &batch, keep, planning, policy, progress.as_ref())?;
        if !skip
            && let Some(pos) = outputs.iter().position(|o| o.result.is_err())
            && let Err(e) = outputs.swap_remove(pos).result
        {
            return Err(sim_err(e));
        }
        if let Some(dir) = &out {
            let inputs = Inputs {
                settings: (&settings, None),
                config: (&cfg, None),
                assets: &assets,
                // A Python predictor has no file: recorded by name below.
                predictor: match &predictor {
                    PredictorArg::Path(p) => p,
                    PredictorArg::Object(_) => std::path::Path::new("constant_velocity"),
                },
                world_predictor: world_predictor.as_deref(),
                idm: idm.as_deref(),
                scene_paths: &scene_paths,
                specs: &batch.specs,
                seed: (seed, runs),
                threads: batch.threads(),
            };
            let write = || -> Result<(), String> {
                let mut p = Provenance::new(&inputs, command.clone().unwrap_or_default())?;
                if let PredictorArg::Object(_) = &predictor {
                    p.predictor = ModelRef {
                        name: PYTHON.to_string(),
                        file: None,
                    };
                }
                p.planner = own_planner
                    .as_ref()
                    .map(|pl| format!("{PYTHON}:{}", pl.class()));
                nudge::records::write_records(dir, &batch.scenes, &outputs, &[p.file()?])
            };
            py.detach(write).map_err(NudgeError::new_err)?;
        }
        let out = PyDict::new(py);
        out.set_item("runs", table_dict(py, run_table(&batch.scenes, &outputs))?)?;
        let steps = table_dict(py, step_table(&outputs))?;
        add_ego(&steps)?;
        out.set_item("steps", steps)?;
        out.set_item(
            "collisions",
            table_dict(py, collision_table(&batch.scenes, &outputs))?,
        )?;
        if trace {
            out.set_item("traces", traces_list(py, &batch, &outputs)?)?;
        }
        if record {
            out.set_item("examples", examples_dict(py, outputs)?)?;
        }
        Ok(out)
    })
}

/// One trace dict per run (`crate::animate::reel_dict`; `None` for a run that could not
/// run), in run order.
fn traces_list<'py>(
    py: Python<'py>,
    batch: &Batch,
    outputs: &[RunOutput],
) -> PyResult<Vec<Option<Bound<'py, PyDict>>>> {
    outputs
        .iter()
        .map(|o| {
            let Ok(rec) = &o.result else {
                return Ok(None);
            };
            let reel = nudge::animate::Reel::from_run(&batch.scenes[o.spec.scene], rec)
                .map_err(crate::animate::animate_err)?;
            crate::animate::reel_dict(py, &reel).map(Some)
        })
        .collect()
}

/// A table's columns as a dict of numpy arrays (text columns as lists of str / None).
pub fn table_dict(py: Python<'_>, table: Table) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    for (name, column) in table.into_columns() {
        match column {
            Column::Float(v) => d.set_item(name, v.into_pyarray(py))?,
            Column::Int(v) => d.set_item(name, v.into_pyarray(py))?,
            Column::UInt(v) => d.set_item(name, v.into_pyarray(py))?,
            Column::Bool(v) => d.set_item(name, v.into_pyarray(py))?,
            Column::Text(v) => d.set_item(name, v)?,
            Column::OptText(v) => d.set_item(name, v)?,
        }
    }
    Ok(d)
}

/// `ego` `[S, 4]` = the columns (x, y, psi, v) side by side.
fn add_ego(steps: &Bound<'_, PyDict>) -> PyResult<()> {
    let py = steps.py();
    let parts: Vec<Vec<f64>> = ["x", "y", "psi", "v"]
        .iter()
        .map(|k| -> PyResult<Vec<f64>> {
            let col = steps
                .get_item(k)?
                .ok_or_else(|| NudgeError::new_err(format!("step column {k} missing")))?;
            col.extract()
        })
        .collect::<PyResult<_>>()?;
    let n = parts[0].len();
    let flat: Vec<f64> = (0..n)
        .flat_map(|i| parts.iter().map(move |p| p[i]))
        .collect();
    steps.set_item(
        "ego",
        flat.into_pyarray(py).reshape([n, 4]).map_err(reshape_err)?,
    )
}

/// The recorded examples of every run as numpy columns (see `nudge_predictor::Records`),
/// with `context_run` naming each context's run.
fn examples_dict(py: Python<'_>, outputs: Vec<RunOutput>) -> PyResult<Bound<'_, PyDict>> {
    let mut ex = Records::default();
    let mut ctx_run: Vec<usize> = Vec::new();
    for (run, o) in outputs.into_iter().enumerate() {
        if let (Ok(_), Some(recs)) = (o.result, o.examples) {
            ctx_run.extend(std::iter::repeat_n(run, recs.context_agents.len()));
            ex.append(recs);
        }
    }
    let n_ctx = ex.context_agents.len();
    let n_ex = ex.example_context.len();
    let h_rows: usize = ex.context_agents.iter().sum();
    let horizon = ex.candidate.len().checked_div(n_ex * 2).unwrap_or(0);
    let mut ctx_off = Vec::with_capacity(n_ctx + 1);
    ctx_off.push(0usize);
    for a in &ex.context_agents {
        ctx_off.push(ctx_off[ctx_off.len() - 1] + a);
    }
    let mut pred_off = Vec::with_capacity(n_ex + 1);
    pred_off.push(0usize);
    for &c in &ex.example_context {
        pred_off.push(pred_off[pred_off.len() - 1] + ex.context_agents[c] - 1);
    }
    let p_rows = pred_off[n_ex];
    let d = PyDict::new(py);
    let history = ex.history.into_pyarray(py);
    d.set_item(
        "history",
        history.reshape([h_rows, T_OBS, 2]).map_err(reshape_err)?,
    )?;
    d.set_item("context_offsets", i64s(ctx_off).into_pyarray(py))?;
    d.set_item("context_run", i64s(ctx_run).into_pyarray(py))?;
    d.set_item("example_context", i64s(ex.example_context).into_pyarray(py))?;
    let candidate = ex.candidate.into_pyarray(py);
    d.set_item(
        "candidate",
        candidate.reshape([n_ex, horizon, 2]).map_err(reshape_err)?,
    )?;
    let prediction = ex.prediction.into_pyarray(py);
    d.set_item(
        "prediction",
        prediction
            .reshape([p_rows, horizon, 2])
            .map_err(reshape_err)?,
    )?;
    d.set_item("prediction_offsets", i64s(pred_off).into_pyarray(py))?;
    d.set_item("duplicates", ex.duplicates)?;
    Ok(d)
}
