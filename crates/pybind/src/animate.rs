//! `nudge._native.animate`: a traced run (one entry of `simulate(..., trace=True)["traces"]`,
//! a dict of numpy arrays) drawn by the renderer of the `nudge` crate (the one the CLI's
//! `--animate` uses) into a GIF, and an MP4 through ffmpeg.
//!
//! The trace dict of a run with S steps, n agents, horizon T and L lanes:
//!
//! | key | shape / type | meaning |
//! |---|---|---|
//! | `title` | str | caption title (scenario, predictors, outcome) |
//! | `lane_bounds` | `[L + 1]` float | lane-boundary y, ascending (m) |
//! | `sizes` | `[n, 2]` float | (length, width) per agent (m) |
//! | `agents` | `[S + 1, n, 3]` float | (x, y, heading) per state and agent (m, m, rad) |
//! | `speed` | `[S + 1]` float | ego speed per state (m/s) |
//! | `collision` | `[S + 1]` bool | ego in collision in that state |
//! | `status` | list of S str | each step's plan status |
//! | `mpc_s` | `[S]` float | planning time (s) |
//! | `plan` | `[S, T + 1, 4]` float | plan z_0..z_T (x, y, ψ, v) |
//! | `predicted` | `[S, n − 1, T, 2]` float | predicted positions of agents 1..n given the plan (m) |
//! | `binding` | `[S]` int | binding agent, −1 when none is checked |
//! | `binding_step` | `[S]` int | plan step of its smallest b (−1 when none) |
//! | `binding_b` | `[S]` float | its smallest b (NaN when none) |
//! | `semi_axes` | `[S, T, 2]` float | its safety ellipses' semi-axes (m; NaN when none) |

use std::path::PathBuf;

use nudge::animate::{
    AnimateError, AnimationSettings, PlannedStep, Reel, Shot, animate as render,
    find_ffmpeg as find,
};
use nudge_planner::{BindingVehicle, StepStatus};
use numpy::{IntoPyArray, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::args::guard;
use crate::errors::{InputError, NudgeError, SettingsError};
use crate::settings::{Settings, with_overrides};

impl Settings for AnimationSettings {
    const WHAT: &'static str = "animation settings";
    const FIELD: &'static str = "animation setting";
    fn check(&self) -> PyResult<()> {
        self.validate().map_err(animate_err)
    }
    fn parse_json(text: &str) -> PyResult<Self> {
        let s: Self = serde_json::from_str(text)
            .map_err(|e| SettingsError::new_err(format!("animation settings: {e}")))?;
        s.check()?;
        Ok(s)
    }
}

/// Maps an animation error: malformed traces are `InputError`, settings `SettingsError`,
/// writing failures `NudgeError`.
pub fn animate_err(err: AnimateError) -> PyErr {
    let msg = err.to_string();
    match err {
        AnimateError::Invalid { .. } | AnimateError::NoTrace { .. } => InputError::new_err(msg),
        AnimateError::Setting { .. } => SettingsError::new_err(msg),
        _ => NudgeError::new_err(msg),
    }
}

/// A float array `[d0, d1, ...]` from the flat `v`.
fn array<'py>(py: Python<'py>, v: Vec<f64>, shape: &[usize]) -> PyResult<Bound<'py, PyAny>> {
    Ok(v.into_pyarray(py)
        .reshape(shape.to_vec())
        .map_err(|e| NudgeError::new_err(format!("reshape failed: {e}")))?
        .into_any())
}

/// The trace dict of `reel` (see the module docs).
pub fn reel_dict<'py>(py: Python<'py>, reel: &Reel) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let n = reel.sizes.len();
    let frames = reel.shots.len();
    let planned: Vec<&PlannedStep> = reel
        .shots
        .iter()
        .filter_map(|s| s.planned.as_ref())
        .collect();
    let s = planned.len();
    let t = planned.first().map_or(0, |p| p.plan.len() - 1);
    d.set_item("title", &reel.title)?;
    d.set_item("lane_bounds", reel.lane_bounds.clone().into_pyarray(py))?;
    d.set_item(
        "sizes",
        array(py, reel.sizes.iter().flatten().copied().collect(), &[n, 2])?,
    )?;
    let agents = reel
        .shots
        .iter()
        .flat_map(|s| s.agents.iter().flatten().copied())
        .collect();
    d.set_item("agents", array(py, agents, &[frames, n, 3])?)?;
    let speed: Vec<f64> = reel.shots.iter().map(|s| s.ego_speed).collect();
    d.set_item("speed", speed.into_pyarray(py))?;
    let collision: Vec<bool> = reel.shots.iter().map(|s| s.collision).collect();
    d.set_item("collision", collision.into_pyarray(py))?;
    let status: Vec<&str> = planned.iter().map(|p| p.status.as_str()).collect();
    d.set_item("status", status)?;
    let mpc_s: Vec<f64> = planned.iter().map(|p| p.mpc_s).collect();
    d.set_item("mpc_s", mpc_s.into_pyarray(py))?;
    let plan = planned
        .iter()
        .flat_map(|p| p.plan.iter().flatten().copied())
        .collect();
    d.set_item("plan", array(py, plan, &[s, t + 1, 4])?)?;
    let predicted = planned
        .iter()
        .flat_map(|p| p.predicted.iter().flatten().flatten().copied())
        .collect();
    d.set_item(
        "predicted",
        array(py, predicted, &[s, n.saturating_sub(1), t, 2])?,
    )?;
    let binding = |f: &dyn Fn(&BindingVehicle) -> i64| -> Vec<i64> {
        planned
            .iter()
            .map(|p| p.binding.as_ref().map_or(-1, f))
            .collect()
    };
    let index = |v: usize| i64::try_from(v).unwrap_or(i64::MAX);
    d.set_item("binding", binding(&|b| index(b.agent)).into_pyarray(py))?;
    d.set_item("binding_step", binding(&|b| index(b.step)).into_pyarray(py))?;
    let b: Vec<f64> = planned
        .iter()
        .map(|p| p.binding.as_ref().map_or(f64::NAN, |b| b.b))
        .collect();
    d.set_item("binding_b", b.into_pyarray(py))?;
    let axes = planned
        .iter()
        .flat_map(|p| match &p.binding {
            Some(b) => b.semi_axes.iter().flatten().copied().collect::<Vec<_>>(),
            None => vec![f64::NAN; t * 2],
        })
        .collect();
    d.set_item("semi_axes", array(py, axes, &[s, t, 2])?)?;
    Ok(d)
}

/// The trace dict `d`, read back with every key's presence, type and shape checked.
struct TraceDict<'a, 'py> {
    d: &'a Bound<'py, PyDict>,
}

impl TraceDict<'_, '_> {
    fn bad(key: &str, what: String) -> PyErr {
        InputError::new_err(format!("trace `{key}`: {what}"))
    }

    fn item(&self, key: &str) -> PyResult<Bound<'_, PyAny>> {
        self.d.get_item(key)?.ok_or_else(|| {
            Self::bad(
                key,
                "missing (pass an entry of simulate(..., trace=True)[\"traces\"])".into(),
            )
        })
    }

    /// A numpy array of `T` with `shape` (`None` = any extent), flat.
    fn array<T: numpy::Element + Copy>(
        &self,
        key: &str,
        shape: &[Option<usize>],
        dtype: &str,
    ) -> PyResult<(Vec<usize>, Vec<T>)> {
        let obj = self.item(key)?;
        let a: PyReadonlyArrayDyn<'_, T> = obj.extract().map_err(|_| {
            Self::bad(
                key,
                format!("expected a numpy {dtype} array, got {}", type_name(&obj)),
            )
        })?;
        let got = a.shape().to_vec();
        let fits = got.len() == shape.len()
            && got
                .iter()
                .zip(shape)
                .all(|(g, w)| w.is_none_or(|w| w == *g));
        if !fits {
            let want: Vec<String> = shape
                .iter()
                .map(|w| w.map_or("*".into(), |w| w.to_string()))
                .collect();
            return Err(Self::bad(
                key,
                format!("expected shape [{}], got {got:?}", want.join(", ")),
            ));
        }
        let flat = a.as_array().iter().copied().collect();
        Ok((got, flat))
    }
}

/// The Python type name of `obj`.
fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map_or_else(|_| "?".into(), |n| n.to_string())
}

/// Pairs / triples of a flat array.
fn tuples<const K: usize>(v: &[f64]) -> Vec<[f64; K]> {
    v.chunks_exact(K)
        .map(|c| std::array::from_fn(|i| c[i]))
        .collect()
}

/// The reel of the trace dict `obj` (checked: keys, types, shapes, then [`Reel::validate`]).
fn reel_from_dict(obj: &Bound<'_, PyAny>) -> PyResult<Reel> {
    let d = obj.cast::<PyDict>().map_err(|_| {
        InputError::new_err(format!(
            "trace: expected a dict (an entry of simulate(..., trace=True)[\"traces\"]), got {}",
            type_name(obj)
        ))
    })?;
    let td = TraceDict { d };
    let title: String = td
        .item("title")?
        .extract()
        .map_err(|_| TraceDict::bad("title", "expected a str".into()))?;
    let (_, lane_bounds) = td.array::<f64>("lane_bounds", &[None], "float64")?;
    let (sh, sizes) = td.array::<f64>("sizes", &[None, Some(2)], "float64")?;
    let n = sh[0];
    let (sh, agents) = td.array::<f64>("agents", &[None, Some(n), Some(3)], "float64")?;
    let frames = sh[0];
    if frames == 0 {
        return Err(TraceDict::bad("agents", "no state".into()));
    }
    let s = frames - 1;
    let (_, speed) = td.array::<f64>("speed", &[Some(frames)], "float64")?;
    let (_, collision) = td.array::<bool>("collision", &[Some(frames)], "bool")?;
    let (sh, plan) = td.array::<f64>("plan", &[Some(s), None, Some(4)], "float64")?;
    if s > 0 && sh[1] < 2 {
        return Err(TraceDict::bad(
            "plan",
            format!("expected T + 1 ≥ 2 states per step, got {}", sh[1]),
        ));
    }
    let t = sh[1].saturating_sub(1);
    let planned = planned_steps(&td, s, n, t, &plan)?;
    let per = n * 3;
    let mut shots: Vec<Shot> = (0..frames)
        .map(|k| Shot {
            agents: tuples::<3>(&agents[k * per..(k + 1) * per]),
            ego_speed: speed[k],
            collision: collision[k],
            planned: None,
        })
        .collect();
    for (shot, p) in shots.iter_mut().zip(planned) {
        shot.planned = Some(p);
    }
    let reel = Reel {
        title,
        lane_bounds,
        sizes: tuples::<2>(&sizes),
        shots,
    };
    reel.validate().map_err(animate_err)?;
    Ok(reel)
}

/// The S planned steps of a trace dict with n agents and horizon T (`plan` read already).
fn planned_steps(
    td: &TraceDict<'_, '_>,
    s: usize,
    n: usize,
    t: usize,
    plan: &[f64],
) -> PyResult<Vec<PlannedStep>> {
    let status: Vec<String> = td
        .item("status")?
        .extract()
        .map_err(|_| TraceDict::bad("status", "expected a list of str".into()))?;
    if status.len() != s {
        return Err(TraceDict::bad(
            "status",
            format!("expected {s} entries, got {}", status.len()),
        ));
    }
    let (_, mpc_s) = td.array::<f64>("mpc_s", &[Some(s)], "float64")?;
    let (_, predicted) = td.array::<f64>(
        "predicted",
        &[Some(s), Some(n.saturating_sub(1)), Some(t), Some(2)],
        "float64",
    )?;
    let (_, binding) = td.array::<i64>("binding", &[Some(s)], "int64")?;
    let (_, binding_step) = td.array::<i64>("binding_step", &[Some(s)], "int64")?;
    let (_, binding_b) = td.array::<f64>("binding_b", &[Some(s)], "float64")?;
    let (_, semi_axes) = td.array::<f64>("semi_axes", &[Some(s), Some(t), Some(2)], "float64")?;
    let per_pred = n.saturating_sub(1) * t * 2;
    (0..s)
        .map(|k| {
            let status = StepStatus::ALL
                .into_iter()
                .find(|st| st.as_str() == status[k])
                .ok_or_else(|| {
                    TraceDict::bad(
                        "status",
                        format!("step {k}: unknown status {:?}", status[k]),
                    )
                })?;
            let binding = match (
                usize::try_from(binding[k]),
                usize::try_from(binding_step[k]),
            ) {
                (Ok(agent), Ok(step)) => Some(BindingVehicle {
                    agent,
                    step,
                    b: binding_b[k],
                    semi_axes: tuples::<2>(&semi_axes[k * t * 2..(k + 1) * t * 2]),
                }),
                (Err(_), Err(_)) if binding[k] == -1 && binding_step[k] == -1 => None,
                _ => {
                    return Err(TraceDict::bad(
                        "binding",
                        format!(
                            "step {k}: agent {} and step {} must both be ≥ 0, or both −1",
                            binding[k], binding_step[k]
                        ),
                    ));
                }
            };
            let pred = &predicted[k * per_pred..(k + 1) * per_pred];
            Ok(PlannedStep {
                status,
                mpc_s: mpc_s[k],
                plan: tuples::<4>(&plan[k * (t + 1) * 4..(k + 1) * (t + 1) * 4]),
                predicted: pred.chunks_exact(t * 2).map(tuples::<2>).collect(),
                binding,
            })
        })
        .collect()
}

/// Draws the traced run `trace` (an entry of `simulate(..., trace=True)["traces"]`) into the
/// GIF `gif` and, when `mp4` is given, into that MP4 through `ffmpeg` (default: the one on
/// `PATH`). `**settings`: `AnimationSettings` fields (`px_per_m`, `behind_m`, `ahead_m`,
/// `margin_m` in m; `frame_s` in s). Returns `{"gif": path, "mp4": path or None,
/// "frames": S + 1, "width": px, "height": px}`.
///
/// Raises `InputError` for a malformed trace (naming the key), `SettingsError` for a bad
/// setting, `NudgeError` when writing fails or an MP4 is asked for without ffmpeg.
#[pyfunction]
#[pyo3(signature = (trace, gif, *, mp4 = None, ffmpeg = None, **settings))]
pub fn animate<'py>(
    py: Python<'py>,
    trace: &Bound<'py, PyAny>,
    gif: PathBuf,
    mp4: Option<PathBuf>,
    ffmpeg: Option<PathBuf>,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    guard(|| {
        let reel = reel_from_dict(trace)?;
        let settings = match settings {
            Some(s) => with_overrides(&AnimationSettings::default(), s.as_any())?,
            None => AnimationSettings::default(),
        };
        let ffmpeg = match (&mp4, ffmpeg) {
            (Some(_), Some(f)) => Some(f),
            (Some(_), None) => Some(find().ok_or_else(|| {
                NudgeError::new_err(
                    "mp4: ffmpeg not found on PATH (install it, or leave mp4 out for the GIF only)",
                )
            })?),
            (None, _) => None,
        };
        let video = mp4.as_deref().zip(ffmpeg.as_deref());
        let w = py
            .detach(|| render(&reel, &settings, &gif, video))
            .map_err(animate_err)?;
        let out = PyDict::new(py);
        out.set_item("gif", w.gif)?;
        out.set_item("mp4", w.mp4)?;
        out.set_item("frames", w.frames)?;
        out.set_item("width", w.size.0)?;
        out.set_item("height", w.size.1)?;
        Ok(out)
    })
}

/// The `ffmpeg` program on `PATH` (the one the CLI's `--animate` uses), or None.
#[pyfunction]
pub fn find_ffmpeg() -> Option<PathBuf> {
    find()
}
