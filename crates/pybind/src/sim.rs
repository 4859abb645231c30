//! `nudge._native.simulate`: closed-loop lane changes over scenario files, in parallel on a
//! rayon pool of `threads` threads, returning per-run and per-step records as numpy columns
//! (and, with `record=True`, every candidate the planning predictor evaluated).

use std::path::PathBuf;

use nudge_planner::{
    PlannerSettings, RunRecord, Scenario, SimConfig, SimError, WorldMode, simulate as rs_simulate,
};
use nudge_predictor::{Predictor, T_OBS};
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;

use crate::errors::{InputError, NudgeError, predictor_err, scenario_err, sim_err};
use crate::record::{Recording, Records, Spec};
use crate::settings::PySettings;

/// Most closed-loop steps per run accepted (1000 steps = 5 minutes of driving).
pub const MAX_STEPS: usize = 1000;
/// Most rayon threads accepted.
pub const MAX_THREADS: usize = 256;

/// One finished run: its record (or error) and what the recorder saw.
type RunOut = (Result<RunRecord, SimError>, Option<Records>);

fn reshape_err(e: impl std::fmt::Display) -> PyErr {
    NudgeError::new_err(format!("reshape failed: {e}"))
}

/// Runs one closed-loop simulation with fresh predictors.
fn run_one(
    sc: &Scenario,
    settings: &PlannerSettings,
    cfg: &SimConfig,
    seed: u64,
    plan_spec: &Spec,
    world_spec: Option<&Spec>,
    record: bool,
) -> RunOut {
    let mut world: Option<Box<dyn Predictor>> = world_spec.map(Spec::build);
    let world_ref = world.as_deref_mut().map(|w| w as &mut dyn Predictor);
    if record {
        let mut rec = Recording::new(plan_spec.build());
        let r = rs_simulate(sc, settings, cfg, seed, &mut rec, world_ref);
        (r, Some(rec.records))
    } else {
        let mut p = plan_spec.build();
        (
            rs_simulate(sc, settings, cfg, seed, p.as_mut(), world_ref),
            None,
        )
    }
}

/// Appends a usize column as int64.
fn i64s(v: impl IntoIterator<Item = usize>) -> Vec<i64> {
    v.into_iter()
        .map(|x| i64::try_from(x).unwrap_or(i64::MAX))
        .collect()
}

/// Closed-loop simulation of every scenario in `scene_paths`, `runs` times each with target-lane
/// seeds `s, s + 1, ...` where `s` is `scene_seeds[i]` (one per scene) or else `seed`, on `threads` rayon threads (default: all cores; each planner
/// call stays single-threaded).
///
/// `predictor`: `"constant_velocity"` or a teacher/student `.safetensors` path (the Python
/// wrapper `nudge.simulate` also accepts `"teacher"` / `"student"`). `world`: `"log_replay"`
/// (others follow the logged future) or `"predictor"` (others follow `world_predictor`,
/// default: the planning predictor). `abort_after` / `abort_hold`: lane-change aborts (see
/// `SimConfig`; `abort_after = 0` disables them). `on_error`: `"raise"` (first failing run raises) or
/// `"skip"` (the run's `error` column holds the message).
///
/// Returns `{"runs": {...}, "steps": {...}}` of numpy columns (plus `"examples"` when
/// `record`): see the `.pyi` stub for every column.
#[pyfunction]
#[pyo3(signature = (scene_paths, predictor, *, world = "log_replay", world_predictor = None, seed = 0, scene_seeds = None, runs = 1, threads = None, settings = None, max_steps = 30, abort_after = 4, abort_hold = 3, record = false, on_error = "raise"))]
#[allow(clippy::too_many_arguments)]
pub fn simulate<'py>(
    py: Python<'py>,
    scene_paths: Vec<PathBuf>,
    predictor: &str,
    world: &str,
    world_predictor: Option<&str>,
    seed: u64,
    scene_seeds: Option<Vec<u64>>,
    runs: usize,
    threads: Option<usize>,
    settings: Option<Bound<'_, PySettings>>,
    max_steps: usize,
    abort_after: usize,
    abort_hold: usize,
    record: bool,
    on_error: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let settings = settings.map_or_else(PlannerSettings::default, |s| s.get().inner.clone());
    let world_mode = match world {
        "log_replay" => WorldMode::LogReplay,
        "predictor" => WorldMode::Predictor,
        other => {
            return Err(InputError::new_err(format!(
                "world: expected \"log_replay\" or \"predictor\", got {other:?}"
            )));
        }
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
    if runs == 0 {
        return Err(InputError::new_err("runs: must be at least 1"));
    }
    if max_steps == 0 || max_steps > MAX_STEPS {
        return Err(InputError::new_err(format!(
            "max_steps: must be in 1..={MAX_STEPS}, got {max_steps}"
        )));
    }
    if abort_after > MAX_STEPS || abort_hold > MAX_STEPS {
        return Err(InputError::new_err(format!(
            "abort_after / abort_hold: must be at most {MAX_STEPS}, got {abort_after} / {abort_hold}"
        )));
    }
    if let Some(t) = threads
        && (t == 0 || t > MAX_THREADS)
    {
        return Err(InputError::new_err(format!(
            "threads: must be in 1..={MAX_THREADS} (or None for all cores), got {t}"
        )));
    }
    let cfg = SimConfig {
        max_steps,
        world: world_mode,
        abort_after,
        abort_hold,
        ..SimConfig::default()
    };
    let horizon = settings.horizon;
    let plan_spec = py
        .detach(|| Spec::parse(predictor, horizon))
        .map_err(predictor_err)?;
    let world_spec = match (world_mode, world_predictor) {
        (WorldMode::LogReplay, _) => None,
        (WorldMode::Predictor, None) => Some(plan_spec.clone()),
        (WorldMode::Predictor, Some(w)) => Some(
            py.detach(|| Spec::parse(w, horizon))
                .map_err(predictor_err)?,
        ),
    };
    let scenes: Vec<Scenario> = py
        .detach(|| {
            scene_paths
                .iter()
                .map(Scenario::from_file)
                .collect::<Result<Vec<_>, _>>()
        })
        .map_err(scenario_err)?;
    if let Some(ss) = &scene_seeds
        && ss.len() != scene_paths.len()
    {
        return Err(InputError::new_err(format!(
            "scene_seeds: expected one seed per scene ({}), got {}",
            scene_paths.len(),
            ss.len()
        )));
    }
    let base: Vec<u64> = scene_seeds.unwrap_or_else(|| vec![seed; scene_paths.len()]);
    let specs: Vec<(usize, u64)> = (0..scenes.len())
        .flat_map(|i| {
            let b = base[i];
            (0..runs).map(move |r| (i, b.wrapping_add(r as u64)))
        })
        .collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()
        .map_err(|e| NudgeError::new_err(format!("cannot start {threads:?} threads: {e}")))?;
    let mut outs: Vec<RunOut> = py.detach(|| {
        pool.install(|| {
            specs
                .par_iter()
                .map(|&(i, s)| {
                    run_one(
                        &scenes[i],
                        &settings,
                        &cfg,
                        s,
                        &plan_spec,
                        world_spec.as_ref(),
                        record,
                    )
                })
                .collect()
        })
    });
    if !skip && let Some(pos) = outs.iter().position(|(r, _)| r.is_err()) {
        let (r, _) = outs.swap_remove(pos);
        if let Err(e) = r {
            return Err(sim_err(e));
        }
    }
    build_output(py, &scenes, &specs, outs, record)
}

#[allow(clippy::too_many_lines)]
fn build_output<'py>(
    py: Python<'py>,
    scenes: &[Scenario],
    specs: &[(usize, u64)],
    outs: Vec<RunOut>,
    record: bool,
) -> PyResult<Bound<'py, PyDict>> {
    // Runs.
    let n_runs = outs.len();
    let mut scenario = Vec::with_capacity(n_runs);
    let mut scene_index = Vec::with_capacity(n_runs);
    let mut seeds = Vec::with_capacity(n_runs);
    let mut predictor = Vec::with_capacity(n_runs);
    let mut world = Vec::with_capacity(n_runs);
    let mut n_agents = Vec::with_capacity(n_runs);
    let mut target_lane = Vec::with_capacity(n_runs);
    let mut y_target = Vec::with_capacity(n_runs);
    let mut success = Vec::with_capacity(n_runs);
    let mut steps_to_target = Vec::with_capacity(n_runs);
    let mut collision = Vec::with_capacity(n_runs);
    let mut n_steps = Vec::with_capacity(n_runs);
    let mut error: Vec<Option<String>> = Vec::with_capacity(n_runs);
    // Steps.
    let mut s_run = Vec::new();
    let mut s_step = Vec::new();
    let mut s_mpc = Vec::new();
    let mut s_iter = Vec::new();
    let mut s_calls = Vec::new();
    let mut s_cost = Vec::new();
    let mut s_res = Vec::new();
    let mut s_minb = Vec::new();
    let mut s_coll = Vec::new();
    let mut s_status: Vec<String> = Vec::new();
    let mut s_delta = Vec::new();
    let mut s_accel = Vec::new();
    let mut s_ego: Vec<f64> = Vec::new();
    let mut s_nz = Vec::new();
    let mut s_zs = Vec::new();
    let mut s_goal = Vec::new();
    let mut aborts = Vec::new();
    // Examples.
    let mut ex = Records::default();
    let mut ctx_run: Vec<usize> = Vec::new();
    for (run, ((r, recs), &(i, seed))) in outs.into_iter().zip(specs).enumerate() {
        scenario.push(scenes[i].name.clone());
        scene_index.push(i);
        seeds.push(seed);
        match r {
            Ok(rec) => {
                predictor.push(rec.predictor.clone());
                world.push(rec.world.clone());
                n_agents.push(rec.n_agents);
                target_lane.push(i64::try_from(rec.target_lane).unwrap_or(-1));
                y_target.push(rec.y_target);
                success.push(rec.success);
                steps_to_target.push(
                    rec.steps_to_target
                        .map_or(-1, |v| i64::try_from(v).unwrap_or(-1)),
                );
                collision.push(rec.collision);
                aborts.push(rec.aborts);
                n_steps.push(rec.steps.len());
                error.push(None);
                for st in &rec.steps {
                    s_run.push(run);
                    s_step.push(st.step);
                    s_mpc.push(st.mpc_s);
                    s_iter.push(st.iterations);
                    s_calls.push(st.predictor_calls);
                    s_cost.push(st.cost);
                    s_res.push(st.primal_residual);
                    s_minb.push(st.min_b.unwrap_or(f64::NAN));
                    s_coll.push(st.collision);
                    s_status.push(st.status.clone());
                    s_delta.push(st.delta);
                    s_accel.push(st.accel);
                    s_ego.extend_from_slice(&st.ego);
                    s_nz.push(st.z_updates_s.len());
                    s_zs.push(st.z_updates_s.iter().sum::<f64>());
                    s_goal.push(st.y_goal);
                }
                if let Some(mut recs) = recs {
                    let base = ex.context_agents.len();
                    ctx_run.extend(std::iter::repeat_n(run, recs.context_agents.len()));
                    ex.history.append(&mut recs.history);
                    ex.context_agents.append(&mut recs.context_agents);
                    ex.example_context
                        .extend(recs.example_context.iter().map(|c| c + base));
                    ex.candidate.append(&mut recs.candidate);
                    ex.prediction.append(&mut recs.prediction);
                    ex.duplicates += recs.duplicates;
                }
            }
            Err(e) => {
                predictor.push(String::new());
                world.push(String::new());
                n_agents.push(scenes[i].n_agents);
                target_lane.push(-1);
                y_target.push(f64::NAN);
                success.push(false);
                steps_to_target.push(-1);
                collision.push(false);
                aborts.push(0);
                n_steps.push(0);
                error.push(Some(e.to_string()));
            }
        }
    }
    let runs = PyDict::new(py);
    runs.set_item("scenario", scenario)?;
    runs.set_item("scene_index", i64s(scene_index).into_pyarray(py))?;
    runs.set_item("seed", seeds.into_pyarray(py))?;
    runs.set_item("predictor", predictor)?;
    runs.set_item("world", world)?;
    runs.set_item("n_agents", i64s(n_agents).into_pyarray(py))?;
    runs.set_item("target_lane", target_lane.into_pyarray(py))?;
    runs.set_item("y_target", y_target.into_pyarray(py))?;
    runs.set_item("success", success.into_pyarray(py))?;
    runs.set_item("steps_to_target", steps_to_target.into_pyarray(py))?;
    runs.set_item("collision", collision.into_pyarray(py))?;
    runs.set_item("aborts", i64s(aborts).into_pyarray(py))?;
    runs.set_item("n_steps", i64s(n_steps).into_pyarray(py))?;
    runs.set_item("error", error)?;
    let steps = PyDict::new(py);
    let ns = s_run.len();
    steps.set_item("run", i64s(s_run).into_pyarray(py))?;
    steps.set_item("step", i64s(s_step).into_pyarray(py))?;
    steps.set_item("mpc_s", s_mpc.into_pyarray(py))?;
    steps.set_item("iterations", i64s(s_iter).into_pyarray(py))?;
    steps.set_item("predictor_calls", i64s(s_calls).into_pyarray(py))?;
    steps.set_item("cost", s_cost.into_pyarray(py))?;
    steps.set_item("primal_residual", s_res.into_pyarray(py))?;
    steps.set_item("min_b", s_minb.into_pyarray(py))?;
    steps.set_item("collision", s_coll.into_pyarray(py))?;
    steps.set_item("status", s_status)?;
    steps.set_item("delta", s_delta.into_pyarray(py))?;
    steps.set_item("accel", s_accel.into_pyarray(py))?;
    steps.set_item(
        "ego",
        s_ego
            .into_pyarray(py)
            .reshape([ns, 4])
            .map_err(reshape_err)?,
    )?;
    steps.set_item("z_updates", i64s(s_nz).into_pyarray(py))?;
    steps.set_item("z_s", s_zs.into_pyarray(py))?;
    steps.set_item("y_goal", s_goal.into_pyarray(py))?;
    let out = PyDict::new(py);
    out.set_item("runs", runs)?;
    out.set_item("steps", steps)?;
    if record {
        out.set_item("examples", examples_dict(py, ex, ctx_run)?)?;
    }
    Ok(out)
}

/// The recorded examples as numpy columns (see `Records`).
fn examples_dict<'py>(
    py: Python<'py>,
    ex: Records,
    ctx_run: Vec<usize>,
) -> PyResult<Bound<'py, PyDict>> {
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
    d.set_item(
        "history",
        ex.history
            .into_pyarray(py)
            .reshape([h_rows, T_OBS, 2])
            .map_err(reshape_err)?,
    )?;
    d.set_item("context_offsets", i64s(ctx_off).into_pyarray(py))?;
    d.set_item("context_run", i64s(ctx_run).into_pyarray(py))?;
    d.set_item("example_context", i64s(ex.example_context).into_pyarray(py))?;
    d.set_item(
        "candidate",
        ex.candidate
            .into_pyarray(py)
            .reshape([n_ex, horizon, 2])
            .map_err(reshape_err)?,
    )?;
    d.set_item(
        "prediction",
        ex.prediction
            .into_pyarray(py)
            .reshape([p_rows, horizon, 2])
            .map_err(reshape_err)?,
    )?;
    d.set_item("prediction_offsets", i64s(pred_off).into_pyarray(py))?;
    d.set_item("duplicates", ex.duplicates)?;
    Ok(d)
}
