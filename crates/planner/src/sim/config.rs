//! [`SimConfig`]: every setting of a closed-loop run in one validated,
//! serde-(de)serialisable struct, and the [`World`] that moves the other vehicles.

use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::SimConfigError;

/// How the other vehicles move.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum World {
    /// The teacher's one-step interactive prediction, given the ego's executed motion and the
    /// rest of its plan, moves them (a learned world that reacts to the ego).
    Teacher,
    /// The logged future moves them; constant velocity once the log ends (real traffic that
    /// never reacts).
    LogReplay,
    /// Every other vehicle keeps its lane and lateral position and follows the Intelligent
    /// Driver Model longitudinally, with a driver drawn per vehicle from the population fitted
    /// to real NGSIM car-following (`assets/worlds/idm.json`), reacting to an intruding ego by
    /// the fitted intrusion rule (reactive traffic with a known model; see
    /// [`crate::sim::idm`]).
    Idm,
}

impl World {
    /// Every world.
    pub const ALL: [Self; 3] = [Self::Teacher, Self::Idm, Self::LogReplay];

    /// `"teacher"`, `"idm"` or `"log_replay"`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Teacher => "teacher",
            Self::LogReplay => "log_replay",
            Self::Idm => "idm",
        }
    }
}

impl std::fmt::Display for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for World {
    type Err = SimConfigError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|w| w.as_str() == s)
            .ok_or_else(|| SimConfigError::Invalid {
                field: "world",
                value: format!("{s:?}"),
                reason: "must be \"teacher\", \"idm\" or \"log_replay\"",
            })
    }
}

/// Closed-loop settings. Units: metres, radians, 0.3 s steps.
///
/// Deserialises from JSON with every field optional (missing fields take the [`Default`]) and
/// unknown fields rejected; [`SimConfig::validate`] checks every field (done by
/// [`crate::simulate`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Most planning steps per run (1..=[`SimConfig::MAX_STEPS`]).
    pub max_steps: usize,
    /// Settled when |y − y_target| ≤ this (m, > 0) ...
    pub settle_y: f64,
    /// ... and |ψ| ≤ this (rad, > 0) ...
    pub settle_psi: f64,
    /// ... for this many consecutive steps (1..=[`SimConfig::MAX_STEPS`]).
    pub settle_steps: usize,
    /// How the others move.
    pub world: World,
    /// Lane-change abort: after this many consecutive planning steps without a safe
    /// lane-change plan (status `Fallback`, `Unsafe` or `SolverFailed`) while the ego is not
    /// yet wholly inside the target lane, the ego aims back at its own lane's centre instead
    /// of idling across the lane boundary. 0 disables aborts (at most
    /// [`SimConfig::MAX_STEPS`]).
    pub abort_after: usize,
    /// Steps an aborted ego keeps aiming at its own lane before it tries the lane change again
    /// (at most [`SimConfig::MAX_STEPS`]).
    pub abort_hold: usize,
    /// Braking limit of the at-fault rule (m/s², > 0): an ego hit from behind while wholly
    /// inside one lane is not at fault only if its applied acceleration at that step was
    /// ≥ −`fault_brake_limit` ([`crate::sim::metrics::classify_collision`]).
    pub fault_brake_limit: f64,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl SimConfig {
    /// The defaults (the values every front end uses unless told otherwise).
    pub const DEFAULT: Self = Self {
        max_steps: 30,
        settle_y: 0.3,
        settle_psi: 0.03,
        settle_steps: 2,
        world: World::Teacher,
        abort_after: 4,
        abort_hold: 3,
        fault_brake_limit: 3.0,
    };

    /// Most steps of one run (1000 steps = 5 minutes of driving).
    pub const MAX_STEPS: usize = 1000;

    /// Checks every field.
    ///
    /// # Errors
    /// [`SimConfigError::Invalid`] naming the first bad field.
    pub fn validate(&self) -> Result<(), SimConfigError> {
        let steps = |field: &'static str, v: usize, min: usize| {
            if v < min || v > Self::MAX_STEPS {
                Err(SimConfigError::Invalid {
                    field,
                    value: v.to_string(),
                    reason: if min == 0 {
                        "must be at most 1000"
                    } else {
                        "must be in 1..=1000"
                    },
                })
            } else {
                Ok(())
            }
        };
        let positive = |field: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(SimConfigError::Invalid {
                    field,
                    value: v.to_string(),
                    reason: "must be finite and > 0",
                })
            }
        };
        steps("max_steps", self.max_steps, 1)?;
        positive("settle_y", self.settle_y)?;
        positive("settle_psi", self.settle_psi)?;
        steps("settle_steps", self.settle_steps, 1)?;
        steps("abort_after", self.abort_after, 0)?;
        steps("abort_hold", self.abort_hold, 0)?;
        positive("fault_brake_limit", self.fault_brake_limit)
    }

    /// Parses JSON (missing fields default, unknown fields rejected) and validates.
    ///
    /// # Errors
    /// [`SimConfigError::Invalid`] with field `"<json>"` when the text is not a JSON object
    /// of known fields with values of the right types, otherwise as
    /// [`Self::validate`].
    pub fn from_json(text: &str) -> Result<Self, SimConfigError> {
        let bad = |value: String| SimConfigError::Invalid {
            field: "<json>",
            value,
            reason: "not a JSON object of closed-loop settings",
        };
        // A repeated key is an error naming it (serde_json would keep the last one).
        let value = nudge_predictor::json::parse(text).map_err(|e| bad(e.to_string()))?;
        if !value.is_object() {
            return Err(bad(value.to_string()));
        }
        let c: Self = serde_json::from_value(value).map_err(|e| bad(e.to_string()))?;
        c.validate()?;
        Ok(c)
    }

    /// Reads a closed-loop settings JSON file (a regular file of at most
    /// [`crate::settings::MAX_SETTINGS_BYTES`], refused before reading otherwise) and parses it
    /// as [`Self::from_json`].
    ///
    /// # Errors
    /// [`SimConfigError::File`] naming the file when it cannot be read, otherwise as
    /// [`Self::from_json`].
    pub fn from_file(path: impl AsRef<std::path::Path>) -> Result<Self, SimConfigError> {
        let path = path.as_ref();
        let bytes = nudge_predictor::file::read_bounded(path, crate::settings::MAX_SETTINGS_BYTES)
            .map_err(|e| SimConfigError::File(e.to_string()))?;
        let text = String::from_utf8(bytes).map_err(|e| {
            SimConfigError::File(format!("{}: not UTF-8 text: {e}", path.display()))
        })?;
        Self::from_json(&text)
    }

    /// The settings as JSON text (every field).
    #[must_use]
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_round_trip() {
        let c = SimConfig::default();
        c.validate().expect("defaults are valid");
        assert_eq!(SimConfig::from_json(&c.to_json()).expect("round trip"), c);
        assert_eq!(SimConfig::from_json("{}").expect("empty"), c);
        let w = SimConfig::from_json(r#"{"world": "log_replay", "settle_steps": 3}"#).expect("ok");
        assert_eq!((w.world, w.settle_steps), (World::LogReplay, 3));
        assert_eq!("teacher".parse::<World>().expect("name"), World::Teacher);
        assert_eq!("idm".parse::<World>().expect("name"), World::Idm);
        for w in World::ALL {
            assert_eq!(w.as_str().parse::<World>().expect("round trip"), w);
            assert_eq!(
                serde_json::to_string(&w).expect("serialise"),
                format!("\"{}\"", w.as_str())
            );
        }
    }

    #[test]
    fn every_field_is_validated_by_name() {
        let bad = [
            (
                "max_steps",
                SimConfig {
                    max_steps: 0,
                    ..SimConfig::default()
                },
            ),
            (
                "max_steps",
                SimConfig {
                    max_steps: 1001,
                    ..SimConfig::default()
                },
            ),
            (
                "settle_y",
                SimConfig {
                    settle_y: f64::NAN,
                    ..SimConfig::default()
                },
            ),
            (
                "settle_y",
                SimConfig {
                    settle_y: 0.0,
                    ..SimConfig::default()
                },
            ),
            (
                "settle_psi",
                SimConfig {
                    settle_psi: -0.1,
                    ..SimConfig::default()
                },
            ),
            (
                "settle_steps",
                SimConfig {
                    settle_steps: 0,
                    ..SimConfig::default()
                },
            ),
            (
                "abort_after",
                SimConfig {
                    abort_after: 5000,
                    ..SimConfig::default()
                },
            ),
            (
                "abort_hold",
                SimConfig {
                    abort_hold: 5000,
                    ..SimConfig::default()
                },
            ),
            (
                "fault_brake_limit",
                SimConfig {
                    fault_brake_limit: 0.0,
                    ..SimConfig::default()
                },
            ),
            (
                "fault_brake_limit",
                SimConfig {
                    fault_brake_limit: f64::INFINITY,
                    ..SimConfig::default()
                },
            ),
        ];
        for (field, c) in bad {
            match c.validate() {
                Err(SimConfigError::Invalid { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: expected an error, got {other:?}"),
            }
        }
        for text in [r#"{"bogus": 1}"#, r#"{"world": "predictor"}"#, "[30]"] {
            assert!(matches!(
                SimConfig::from_json(text),
                Err(SimConfigError::Invalid {
                    field: "<json>",
                    ..
                })
            ));
        }
        assert!(matches!(
            "log-replay".parse::<World>(),
            Err(SimConfigError::Invalid { field: "world", .. })
        ));
    }
}
