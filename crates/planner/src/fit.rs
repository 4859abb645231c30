//! Whether valid planner settings fit what they are used with: the predictor's horizon, and
//! the 0.3 s step ([`nudge_predictor::DT`]) the networks were trained on and every scene is
//! sampled at. Both front ends (through the simulator's `BatchRequest`), its `simulate` and
//! the Python `Planner` call these, so the refusal reads the same everywhere.

use nudge_predictor::DT;

use crate::error::SettingsError;
use crate::settings::PlannerSettings;

/// Largest difference between `dt` and [`DT`] still taken as equal (s).
const DT_TOLERANCE: f64 = 1e-9;

fn horizon(settings: &PlannerSettings, name: &str, horizon: usize) -> Result<(), SettingsError> {
    if settings.model.horizon == horizon {
        return Ok(());
    }
    Err(SettingsError::Incompatible {
        field: "model.horizon",
        value: settings.model.horizon as f64,
        reason: format!("the {name} predicts {horizon} steps"),
    })
}

fn time_step(settings: &PlannerSettings, why: &str) -> Result<(), SettingsError> {
    if (settings.model.dt - DT).abs() <= DT_TOLERANCE {
        return Ok(());
    }
    Err(SettingsError::Incompatible {
        field: "model.dt",
        value: settings.model.dt,
        reason: format!("{why} {DT} s steps"),
    })
}

/// Checks that `settings` fit the predictor called `name` (as [`nudge_predictor::Predictor::name`])
/// that predicts `horizon` steps: the same horizon, and for the networks (`"teacher"`,
/// `"student"`) `dt` = [`DT`].
///
/// # Errors
/// [`SettingsError::Incompatible`] naming `model.horizon` or `model.dt`.
///
/// # Examples
///
/// ```
/// use nudge_planner::{PlannerSettings, fit};
///
/// let mut s = PlannerSettings::default();
/// s.model.horizon = 7;
/// let e = fit::check_predictor(&s, "student", 6).unwrap_err();
/// assert_eq!(
///     e.to_string(),
///     "planner setting `model.horizon` = 7 does not fit: the student predicts 6 steps"
/// );
/// ```
pub fn check_predictor(
    settings: &PlannerSettings,
    name: &str,
    predicts: usize,
) -> Result<(), SettingsError> {
    horizon(settings, name, predicts)?;
    if matches!(name, "teacher" | "student") {
        time_step(settings, "the teacher and student networks are trained on")?;
    }
    Ok(())
}

/// Checks that `settings` fit a closed loop on scenes with the predictors `predictors`
/// (name, horizon) (the planning predictor and, if any, the world model): `dt` = [`DT`], the
/// step every scene is sampled at (each planning step shifts the observed histories by one
/// step), and [`check_predictor`] for each.
///
/// # Errors
/// [`SettingsError::Incompatible`] naming `model.dt` or `model.horizon`.
pub fn check_closed_loop(
    settings: &PlannerSettings,
    predictors: &[(&str, usize)],
) -> Result<(), SettingsError> {
    time_step(settings, "the scenes are sampled at")?;
    for &(name, predicts) in predictors {
        check_predictor(settings, name, predicts)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn horizon_and_time_step_are_checked_by_name() {
        let s = PlannerSettings::default();
        for name in ["teacher", "student", "constant_velocity", "custom"] {
            assert_eq!(check_predictor(&s, name, 6), Ok(()));
            assert!(matches!(
                check_predictor(&s, name, 5),
                Err(SettingsError::Incompatible {
                    field: "model.horizon",
                    ..
                })
            ));
        }
        let slow = {
            let mut s = PlannerSettings::default();
            s.model.dt = 0.5;
            s
        };
        for name in ["teacher", "student"] {
            assert!(matches!(
                check_predictor(&slow, name, 6),
                Err(SettingsError::Incompatible {
                    field: "model.dt",
                    ..
                })
            ));
        }
        // Constant velocity extrapolates whatever step its history has ...
        assert_eq!(check_predictor(&slow, "constant_velocity", 6), Ok(()));
        // ... but a closed loop's histories come from scenes sampled at 0.3 s.
        let e = check_closed_loop(&slow, &[("constant_velocity", 6)]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "planner setting `model.dt` = 0.5 does not fit: the scenes are sampled at 0.3 s steps"
        );
        assert_eq!(
            check_closed_loop(&s, &[("student", 6), ("teacher", 6)]),
            Ok(())
        );
    }
}
