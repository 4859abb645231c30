//! `nudge._native`: Python bindings of the nudge predictors, planner and simulator.
//!
//! The only crate of the workspace that uses pyo3. Every call that runs a network, a plan or a
//! simulation releases the GIL; every Rust error becomes a subclass of `nudge.NudgeError`.

mod arrays;
mod errors;
mod planner;
mod predict;
mod record;
mod scenario;
mod settings;
mod sim;

use pyo3::prelude::*;

/// The extension module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("NudgeError", py.get_type::<errors::NudgeError>())?;
    m.add("WeightsError", py.get_type::<errors::WeightsError>())?;
    m.add("InputError", py.get_type::<errors::InputError>())?;
    m.add("SettingsError", py.get_type::<errors::SettingsError>())?;
    m.add("ScenarioError", py.get_type::<errors::ScenarioError>())?;
    m.add("SolverError", py.get_type::<errors::SolverError>())?;
    m.add_class::<predict::PyPredictor>()?;
    m.add_class::<settings::PySettings>()?;
    m.add_class::<scenario::PyScenario>()?;
    m.add_class::<planner::PyPlanner>()?;
    m.add_function(wrap_pyfunction!(sim::simulate, m)?)?;
    m.add("T_OBS", nudge_predictor::T_OBS)?;
    m.add("MAX_AGENTS", nudge_predictor::MAX_AGENTS)?;
    m.add("DT", nudge_predictor::DT)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
