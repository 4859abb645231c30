//! `nudge._native`: Python bindings of the nudge predictors, planner and simulator.
//!
//! The only crate of the workspace that uses pyo3. Every call that runs a network, a plan or a
//! simulation releases the GIL; every Rust error becomes a subclass of `nudge.NudgeError`.

mod animate;
mod args;
mod arrays;
mod cli;
mod commonroad;
mod env;
mod errors;
mod interrupt;
mod planner;
mod predict;
mod py_policy;
mod py_predictor;
mod scenario;
mod settings;
mod sim;

use std::path::PathBuf;

use nudge_predictor::PredictorKind;
use pyo3::prelude::*;

/// The shipped weights of `name` (`"teacher"` or `"student"`) under the assets directory
/// `assets`: the path the Rust resolver loads for that name.
#[pyfunction]
fn model_path(assets: PathBuf, name: &str) -> PyResult<PathBuf> {
    args::guard(|| {
        match name
            .parse::<PredictorKind>()
            .ok()
            .and_then(PredictorKind::model)
        {
            Some(kind) => Ok(nudge_predictor::model_path(&assets, kind)),
            None => Err(errors::InputError::new_err(format!(
                "model_path: expected \"teacher\" or \"student\", got {name:?}"
            ))),
        }
    })
}

/// The assets directory of the package whose shipped assets are at `shipped`:
/// `$NUDGE_ASSETS` when set and not empty, else `shipped` (`nudge_predictor::assets_dir`, the
/// rule of every front end).
#[pyfunction]
fn assets_dir(shipped: PathBuf) -> PathBuf {
    nudge_predictor::assets_dir(shipped)
}

/// The shipped scenes under the assets directory `assets`: `<assets>/scenes`.
#[pyfunction]
fn scenes_dir(assets: PathBuf) -> PathBuf {
    nudge_predictor::scenes_dir(&assets)
}

/// The extension module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    // Load numpy's C API now: loaded lazily on the first array instead, an import interrupted
    // by a pending Ctrl-C would make rust-numpy panic.
    numpy::PyArray1::<f64>::zeros(py, [0], false);
    m.add("NudgeError", py.get_type::<errors::NudgeError>())?;
    m.add("WeightsError", py.get_type::<errors::WeightsError>())?;
    m.add("InputError", py.get_type::<errors::InputError>())?;
    m.add("SettingsError", py.get_type::<errors::SettingsError>())?;
    m.add("ScenarioError", py.get_type::<errors::ScenarioError>())?;
    m.add("SolverError", py.get_type::<errors::SolverError>())?;
    m.add("PredictorError", py.get_type::<errors::PredictorError>())?;
    m.add("WorldFileError", py.get_type::<errors::WorldFileError>())?;
    m.add("ReentrancyError", py.get_type::<errors::ReentrancyError>())?;
    m.add_class::<predict::PyPredictor>()?;
    m.add_class::<settings::PySettings>()?;
    m.add_class::<settings::PySimConfig>()?;
    settings::document_fields(m)?;
    m.add_class::<scenario::PyScenario>()?;
    m.add_class::<planner::PyPlanner>()?;
    m.add_class::<env::PySession>()?;
    m.add_function(wrap_pyfunction!(sim::simulate, m)?)?;
    m.add_function(wrap_pyfunction!(model_path, m)?)?;
    m.add_function(wrap_pyfunction!(assets_dir, m)?)?;
    m.add_function(wrap_pyfunction!(scenes_dir, m)?)?;
    m.add_function(wrap_pyfunction!(cli::cli_main, m)?)?;
    m.add_function(wrap_pyfunction!(commonroad::commonroad_scenario, m)?)?;
    m.add_function(wrap_pyfunction!(commonroad::commonroad_solution, m)?)?;
    m.add_function(wrap_pyfunction!(commonroad::commonroad_tracks, m)?)?;
    m.add_function(wrap_pyfunction!(animate::animate, m)?)?;
    m.add_function(wrap_pyfunction!(animate::find_ffmpeg, m)?)?;
    m.add("DEFAULTS", sim::defaults_dict(py)?)?;
    m.add("T_OBS", nudge_predictor::T_OBS)?;
    m.add("MAX_AGENTS", nudge_predictor::MAX_AGENTS)?;
    m.add("DT", nudge_predictor::DT)?;
    m.add("SLOW_FRACTION", nudge_sim::metrics::SLOW_FRACTION)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("GIT_SHA", nudge::GIT_SHA)?;
    Ok(())
}
