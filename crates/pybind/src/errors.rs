//! The Python exception hierarchy and the mapping of every Rust error onto it.
//!
//! ```text
//! NudgeError
//! ├── WeightsError    bad or missing weights file
//! ├── InputError      wrong shape / dtype / non-finite values / agent count
//! ├── SettingsError   invalid planner or closed-loop settings (unknown key, bad value)
//! ├── ScenarioError   bad or missing scenario file
//! ├── WorldFileError  bad or missing world file (the idm world's driver population)
//! ├── PredictorError  a predictor given from Python failed or returned an unusable prediction
//! └── SolverError     a QP solve or planning step failed
//! ```

use nudge_planner::{
    PlannerError, ScenarioError as RsScenarioError, SettingsError as RsSettingsError,
};
use nudge_predictor::PredictorError as RsPredictorError;
use nudge_sim::{SimConfigError, SimError};
use pyo3::PyErr;
use pyo3::Python;
use pyo3::create_exception;
use pyo3::exceptions::PyException;

use crate::py_predictor;

create_exception!(
    nudge,
    NudgeError,
    PyException,
    "Base class of every nudge error."
);
create_exception!(
    nudge,
    WeightsError,
    NudgeError,
    "A weights file is missing, malformed or inconsistent with its config."
);
create_exception!(
    nudge,
    InputError,
    NudgeError,
    "An input array has the wrong shape or dtype, or holds NaN/inf."
);
create_exception!(
    nudge,
    SettingsError,
    NudgeError,
    "Planner or closed-loop settings are invalid (unknown key, impossible value)."
);
create_exception!(
    nudge,
    ScenarioError,
    NudgeError,
    "A scenario file is missing or malformed."
);
create_exception!(
    nudge,
    WorldFileError,
    NudgeError,
    "A world file (the idm world's driver population, \"nudge.idm/1\") is missing or malformed."
);
create_exception!(
    nudge,
    PredictorError,
    NudgeError,
    "A predictor given from Python failed (its exception is the cause), lacks a method, or \
     returned a prediction of the wrong type or shape, non-finite or implausible."
);
create_exception!(
    nudge,
    ReentrancyError,
    NudgeError,
    "A planner was called again from inside its own planning call (its predictor called back \
     into it): refused instead of waiting for itself."
);
create_exception!(
    nudge,
    SolverError,
    NudgeError,
    "An optimisation step failed."
);

/// Maps a predictor error to the matching Python exception, keeping the Rust message.
pub fn predictor_err(err: RsPredictorError) -> PyErr {
    let msg = err.to_string();
    match err {
        RsPredictorError::AgentCount { .. }
        | RsPredictorError::InputShape { .. }
        | RsPredictorError::NonFiniteInput { .. }
        | RsPredictorError::InputOutOfRange { .. }
        | RsPredictorError::Horizon { .. }
        | RsPredictorError::FixedHorizon { .. }
        | RsPredictorError::BatchTooLarge { .. }
        | RsPredictorError::NoScene => InputError::new_err(msg),
        RsPredictorError::Foreign { source, .. } => py_predictor::failure_err(msg, source),
        RsPredictorError::NonFiniteOutput {
            predictor: py_predictor::NAME,
            ..
        }
        | RsPredictorError::ImplausibleOutput {
            predictor: py_predictor::NAME,
            ..
        } => PredictorError::new_err(msg),
        _ => WeightsError::new_err(msg),
    }
}

/// An exception of the same class and cause as `err` with message `msg` (`err` itself when it
/// is not a nudge error: a `KeyboardInterrupt` raised inside a Python predictor).
fn same_class(err: &PyErr, msg: String) -> PyErr {
    Python::attach(|py| {
        if !err.is_instance_of::<NudgeError>(py) {
            return err.clone_ref(py);
        }
        let new = PyErr::from_type(err.get_type(py), msg);
        new.set_cause(py, err.cause(py));
        new
    })
}

/// Maps a settings error.
pub fn settings_err(err: RsSettingsError) -> PyErr {
    SettingsError::new_err(err.to_string())
}

/// Maps a closed-loop settings error.
pub fn sim_config_err(err: SimConfigError) -> PyErr {
    SettingsError::new_err(err.to_string())
}

/// Maps a scenario error.
pub fn scenario_err(err: RsScenarioError) -> PyErr {
    ScenarioError::new_err(err.to_string())
}

/// Maps a planner error.
pub fn planner_err(err: PlannerError) -> PyErr {
    let msg = err.to_string();
    match err {
        PlannerError::Settings(e) => settings_err(e),
        // Keep the planner's context ("predictor failed: ...") in the message.
        PlannerError::Predictor(e) => same_class(&predictor_err(e), msg),
        PlannerError::BadProblem { .. }
        | PlannerError::BadLane { .. }
        | PlannerError::HorizonMismatch { .. } => InputError::new_err(msg),
        PlannerError::Foreign { source, .. } => crate::py_policy::failure_err(msg, source),
        PlannerError::Cancelled => NudgeError::new_err(msg),
        _ => SolverError::new_err(msg),
    }
}

/// Maps a simulation error.
pub fn sim_err(err: SimError) -> PyErr {
    let msg = err.to_string();
    match err {
        SimError::Settings(_) | SimError::Config(_) => SettingsError::new_err(msg),
        SimError::NoAdjacentLane { .. } => ScenarioError::new_err(msg),
        SimError::Predictor { source, .. } | SimError::Model { source, .. } => {
            same_class(&predictor_err(source), msg)
        }
        SimError::Planner { source, .. } => same_class(&planner_err(source), msg),
        SimError::WorldModel { .. }
        | SimError::Runs { .. }
        | SimError::Ended { .. }
        | SimError::NoPlan { .. } => InputError::new_err(msg),
        SimError::WorldFile(_) => WorldFileError::new_err(msg),
        SimError::Scenario(e) => scenario_err(e),
        SimError::Cancelled { .. } => NudgeError::new_err(msg),
        #[allow(unreachable_patterns)]
        _ => NudgeError::new_err(msg),
    }
}
