//! [`SimConfig`]: every setting of a closed-loop run in one validated,
//! serde-(de)serialisable struct, and the [`World`] that moves the other vehicles.

use std::str::FromStr;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::SimConfigError;
use crate::settings::{FieldRange, closed};

/// The range (0, ∞) of a positive, finite setting.
const fn positive(field: &'static str, unit: &'static str) -> FieldRange {
    FieldRange {
        field,
        min: 0.0,
        min_open: true,
        max: f64::INFINITY,
        max_open: true,
        unit,
    }
}

/// How the other vehicles move.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum World {
    /// The teacher's one-step interactive prediction, given the ego's executed motion and the
    /// rest of its plan, moves them (a learned world that reacts to the ego).
    Teacher,
    /// The logged future moves them; once a vehicle's log ends it keeps its last speed along
    /// the road and its lateral motion fades by [`SimConfig::replay_lateral_decay`] per step
    /// (real traffic that never reacts).
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
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Most planning steps per run (0.3 s each).
    pub max_steps: usize,
    /// A run has settled in the target lane when |y − y_target| ≤ settle_y (m) and
    /// |ψ| ≤ `settle_psi` for `settle_steps` consecutive steps.
    pub settle_y: f64,
    /// Heading bound of the settling test (rad, relative to the road; see `settle_y`).
    pub settle_psi: f64,
    /// Consecutive steps the settling test must hold (see `settle_y`).
    pub settle_steps: usize,
    /// How the other vehicles move: `teacher` (the teacher's interactive prediction reacts to
    /// the ego's plan), `idm` (lane keeping with fitted Intelligent Driver Model drivers) or
    /// `log_replay` (the logged future, never reacting).
    pub world: World,
    /// Lane-change abort: after this many consecutive planning steps without a safe
    /// lane-change plan (status `Fallback`, `Unsafe` or `SolverFailed`) while the ego is not
    /// yet wholly inside the target lane, the ego aims back at its own lane's centre instead
    /// of idling across the lane boundary. 0 disables aborts.
    pub abort_after: usize,
    /// Steps an aborted ego keeps aiming at its own lane before it tries the lane change
    /// again.
    pub abort_hold: usize,
    /// Stalled lane-change abort (m per step): a lane change whose ego centre moved less than
    /// this towards the target lane on each of `abort_after` consecutive steps while the ego's
    /// box straddles the line between the lanes, its centre not yet across, is aborted like
    /// one without a safe plan (an ego that finds admissible plans that edge over the line
    /// and stop there would otherwise idle across it). 0 disables it.
    pub stall_progress: f64,
    /// Abort from a straddling start: an ego whose box starts across a line of its own lane
    /// (its centre in its own lane) aborts after this many consecutive steps without a safe
    /// plan, before its first safe plan, instead of `abort_after`; with 1 the first step
    /// without one turns the goal to the own lane's centre at once
    /// ([`crate::lane::LaneChange::with_start_abort`]; one such abort per run). 0 disables it,
    /// the default: at 1 on validation (300 scenes × 3 seeds, teacher planner on 100, paired
    /// with it off) success moved by −0.7 to +1.0 points per world and planner (15 runs lost,
    /// 14 gained over the six arms), and one at-fault run was added in the idm world (a 6.1 m
    /// truck rear-ended while it straddled the line, teacher planner). An ego's centre always
    /// starts in its own lane, so the fallbacks are offered the own lane from the first step
    /// without it ([`crate::lane::LaneChange::retreat`]).
    pub start_abort_after: usize,
    /// Gap seeking (m/s): while a lane change has not yet brought the ego wholly inside the
    /// target lane, a target-lane vehicle alongside it (bumper gap along the road below
    /// `gap_window`) sets the planner's reference speed this much above its speed when, at
    /// their current speeds, the ego would be ahead of it after the planning horizon, else
    /// this much below (then never above the run's starting speed nor more than this below it,
    /// never below 0; never above the planner's `v_max`; [`crate::lane::LaneChange::v_ref`]). Without it the reference
    /// stays the ego's starting speed and the ego can ride beside a target-lane vehicle of
    /// about its speed, half across the line, until the step budget runs out. 0 (the
    /// default) disables it: on validation it gained 1.3 pp of success for the student planner
    /// in the teacher world but cost the teacher planner 17 of 300 log-replay runs
    /// (`crate::lane`).
    pub gap_speed: f64,
    /// Bumper gap along the road (m) below which a target-lane vehicle blocks a lane change
    /// (see `gap_speed`).
    pub gap_window: f64,
    /// Crawl reference (a fraction; 0 disables it): the first planning step at which the
    /// run's reference speed (the ego's starting speed) is below this fraction of the goal
    /// lane's flow (the median speed of the vehicles, as last observed, in the lane the ego is
    /// aiming for within [`crate::lane::FLOW_RANGE_M`] along the road, or the last such median
    /// seen) makes the ego *crawling*, and from then on its reference speed is at least that
    /// flow ([`crate::lane::LaneChange::v_ref`]). Without it an ego that starts at a crawl
    /// (queued behind a slow vehicle) keeps planning that crawl beside traffic at 6–12 m/s
    /// after its path has cleared. 0.5 was chosen on validation scenes and on the train
    /// split's crawling starts (the validation split has none), `docs/results/crawl_reference.md`.
    pub crawl_fraction: f64,
    /// Braking limit of the at-fault rule (m/s²): an ego hit from behind while wholly
    /// inside one lane is not at fault only if its applied acceleration at that step was
    /// ≥ −`fault_brake_limit` ([`crate::sim::metrics::classify_collision`]).
    pub fault_brake_limit: f64,
    /// Log replay once a vehicle's log ends (a fraction per 0.3 s step, in [0, 1]): each
    /// extrapolated step repeats the vehicle's last displacement along the road and this
    /// fraction of its last displacement across it, so a vehicle last seen moving sideways by
    /// Δy per step drifts Δy·ρ(1 − ρᵏ)/(1 − ρ) in k steps (ρ = this factor) and at most
    /// Δy·ρ/(1 − ρ) in all ([`crate::sim::world::logged_position`]). 1 is constant velocity
    /// (a driver wobbling in its lane at the log's end then crosses the road for the rest of
    /// the run); 0 holds the lateral position. 0.75 (a time constant of 1.04 s) is the least
    /// squares fit to where real NGSIM vehicles were 1–24 steps after a last observed step, on
    /// the training scenes' tracks; on the validation scenes' its lateral RMSE is 0.36 m,
    /// against 0.74 m at 1 and 0.39 m at 0 (`nudge-train replay-extrapolation`,
    /// `docs/results/replay_extrapolation.md`).
    pub replay_lateral_decay: f64,
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
        stall_progress: 0.0,
        start_abort_after: 0,
        gap_speed: 0.0,
        gap_window: 6.0,
        crawl_fraction: 0.5,
        fault_brake_limit: 3.0,
        replay_lateral_decay: 0.75,
    };

    /// Most steps of one run (1000 steps = 5 minutes of driving).
    pub const MAX_STEPS: usize = 1000;

    /// Every numeric field's admissible range, in field order (step counts up to
    /// [`SimConfig::MAX_STEPS`]; tolerances and the braking limit positive and finite).
    pub const RANGES: &[FieldRange] = &[
        closed("max_steps", 1.0, Self::MAX_STEPS as f64, "steps"),
        positive("settle_y", "m"),
        positive("settle_psi", "rad"),
        closed("settle_steps", 1.0, Self::MAX_STEPS as f64, "steps"),
        closed("abort_after", 0.0, Self::MAX_STEPS as f64, "steps"),
        closed("abort_hold", 0.0, Self::MAX_STEPS as f64, "steps"),
        closed("stall_progress", 0.0, 1.0, "m"),
        closed("start_abort_after", 0.0, Self::MAX_STEPS as f64, "steps"),
        closed("gap_speed", 0.0, 10.0, "m/s"),
        closed("gap_window", 0.0, 100.0, "m"),
        closed("crawl_fraction", 0.0, 1.0, "–"),
        positive("fault_brake_limit", "m/s²"),
        closed("replay_lateral_decay", 0.0, 1.0, "–"),
    ];

    /// The value of numeric field `field` as f64 (`None` for `world` or an unknown name).
    #[must_use]
    pub fn numeric(&self, field: &str) -> Option<f64> {
        Some(match field {
            "max_steps" => self.max_steps as f64,
            "settle_y" => self.settle_y,
            "settle_psi" => self.settle_psi,
            "settle_steps" => self.settle_steps as f64,
            "abort_after" => self.abort_after as f64,
            "abort_hold" => self.abort_hold as f64,
            "stall_progress" => self.stall_progress,
            "start_abort_after" => self.start_abort_after as f64,
            "gap_speed" => self.gap_speed,
            "gap_window" => self.gap_window,
            "crawl_fraction" => self.crawl_fraction,
            "fault_brake_limit" => self.fault_brake_limit,
            "replay_lateral_decay" => self.replay_lateral_decay,
            _ => return None,
        })
    }

    /// Checks every numeric field against [`SimConfig::RANGES`] (`world` is valid by type).
    ///
    /// # Errors
    /// [`SimConfigError::OutOfRange`] naming the first field out of its range (NaN and
    /// infinity never are in range), with the range in the message.
    pub fn validate(&self) -> Result<(), SimConfigError> {
        for r in Self::RANGES {
            let value = self.numeric(r.field).unwrap_or(f64::NAN);
            if !r.contains(value) {
                return Err(SimConfigError::OutOfRange {
                    field: r.field,
                    value,
                    range: *r,
                });
            }
        }
        Ok(())
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
                "gap_speed",
                SimConfig {
                    gap_speed: -1.0,
                    ..SimConfig::default()
                },
            ),
            (
                "gap_speed",
                SimConfig {
                    gap_speed: f64::NAN,
                    ..SimConfig::default()
                },
            ),
            (
                "start_abort_after",
                SimConfig {
                    start_abort_after: 5000,
                    ..SimConfig::default()
                },
            ),
            (
                "gap_window",
                SimConfig {
                    gap_window: 1000.0,
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
            (
                "replay_lateral_decay",
                SimConfig {
                    replay_lateral_decay: 1.5,
                    ..SimConfig::default()
                },
            ),
            (
                "replay_lateral_decay",
                SimConfig {
                    replay_lateral_decay: f64::NAN,
                    ..SimConfig::default()
                },
            ),
        ];
        for (field, c) in bad {
            match c.validate() {
                Err(SimConfigError::OutOfRange { field: f, .. }) => assert_eq!(f, field),
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
