//! [`SimConfig`]: every setting of a closed-loop run in one validated,
//! serde-(de)serialisable struct, and the [`World`] that moves the other vehicles.

use std::str::FromStr;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::SimConfigError;
use nudge_planner::settings::schema::{FieldRange, any, closed, open_min, positive};

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
    /// [`crate::idm`]).
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

/// `Ok` when nothing is out of its range, else the error naming the first field that is.
pub(crate) fn in_range(out: Option<(FieldRange, f64)>) -> Result<(), SimConfigError> {
    match out {
        Some((range, value)) => Err(SimConfigError::OutOfRange {
            field: range.field,
            value,
            range,
        }),
        None => Ok(()),
    }
}

impl nudge_planner::settings::schema::FieldValue for World {
    fn number(&self) -> Option<f64> {
        None
    }
}

/// Most steps of one run (1000 steps = 5 minutes of driving).
const MAX_STEPS: f64 = 1000.0;
/// Largest `settle_y` (m): half the narrowest lane a scenario may have
/// ([`nudge_planner::scenario::LANE_WIDTH`]).
const MAX_SETTLE_Y: f64 = 0.5 * nudge_planner::scenario::LANE_WIDTH[0];
/// Largest `settle_psi` (rad).
const MAX_SETTLE_PSI: f64 = 0.2;

nudge_planner::settings_struct! {
    /// Closed-loop settings. Units: metres, radians, 0.3 s steps.
    ///
    /// Deserialises from JSON with every field optional (missing fields take the [`Default`])
    /// and unknown fields rejected; [`SimConfig::validate`] checks every field (done by
    /// [`crate::simulate`]).
    #[derive(Copy)]
    pub struct SimConfig("") {
        /// Most planning steps per run (0.3 s each).
        max_steps: usize = 30, closed(1.0, MAX_STEPS, "steps");
        /// Settled in the target lane when |y − y_target| ≤ this for `settle_steps` steps (m);
        /// at most half the narrowest lane a scene may have (1.25 m), so a settled ego's centre
        /// is inside the target lane.
        settle_y: f64 = 0.3, open_min(0.0, MAX_SETTLE_Y, "m");
        /// Heading bound of the settling test, relative to the road (rad); at most 0.2 rad
        /// (11°), the planner's default heading bound: a steeper ego is still changing lanes.
        settle_psi: f64 = 0.03, open_min(0.0, MAX_SETTLE_PSI, "rad");
        /// Consecutive steps the settling test must hold.
        settle_steps: usize = 2, closed(1.0, MAX_STEPS, "steps");
        /// How the other vehicles move: `teacher`, `idm` or `log_replay`.
        world: World = World::Teacher, any();
        /// Abort a lane change after this many steps without a safe plan before the ego is
        /// inside the target lane (0: never).
        abort_after: usize = 4, closed(0.0, MAX_STEPS, "steps");
        /// Steps an aborted ego aims at its own lane before it tries again.
        abort_hold: usize = 3, closed(0.0, MAX_STEPS, "steps");
        /// Also abort a lane change that straddles the line and moves less than this towards
        /// the target lane on each of `abort_after` steps (m per step; 0: never).
        stall_progress: f64 = 0.0, closed(0.0, 1.0, "m");
        /// Abort from a start across a line of the own lane after this many steps without a
        /// safe plan (0: as `abort_after`).
        start_abort_after: usize = 0, closed(0.0, MAX_STEPS, "steps");
        /// Gap seeking: aim this far above or below a blocking target-lane vehicle's speed
        /// (m/s; 0: off).
        gap_speed: f64 = 0.0, closed(0.0, 10.0, "m/s");
        /// Bumper gap below which a target-lane vehicle blocks the lane change (m).
        gap_window: f64 = 6.0, closed(0.0, 100.0, "m");
        /// Crawl reference: below this fraction of the goal lane's flow the reference speed
        /// keeps up with that flow (0: off).
        crawl_fraction: f64 = 0.5, closed(0.0, 1.0, "–");
        /// At-fault rule: an ego hit from behind inside one lane is not at fault only if it
        /// braked no harder than this (m/s²).
        fault_brake_limit: f64 = 3.0, positive("m/s²");
        /// Log replay past a vehicle's log: the share of its last sideways displacement it
        /// repeats per step.
        replay_lateral_decay: f64 = 0.75, closed(0.0, 1.0, "–");
    }
}

impl SimConfig {
    /// Most steps of one run (1000 steps = 5 minutes of driving).
    pub const MAX_STEPS: usize = MAX_STEPS as usize;

    /// The value of numeric field `field` as f64 (`None` for `world` or an unknown name).
    #[must_use]
    pub fn numeric(&self, field: &str) -> Option<f64> {
        self.value(field)
    }

    /// Checks every numeric field against its range in [`SimConfig::FIELDS`] (`world` is
    /// valid by type).
    ///
    /// # Errors
    /// [`SimConfigError::OutOfRange`] naming the first field out of its range (NaN and
    /// infinity never are in range), with the range in the message.
    pub fn validate(&self) -> Result<(), SimConfigError> {
        in_range(self.out_of_range())
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
        let c: Self = serde_json::from_value(value.clone()).map_err(|e| {
            let mut err = bad(nudge_predictor::json::brief(
                &e,
                "docs/reference/settings.md",
            ));
            // serde names no field in a type error: find it by parsing each field alone.
            let failing = value.as_object().and_then(|o| {
                o.iter().find_map(|(k, v)| {
                    let alone = serde_json::json!({ k: v });
                    serde_json::from_value::<Self>(alone)
                        .is_err()
                        .then_some(k.as_str())
                })
            });
            if let (SimConfigError::Invalid { field, .. }, Some(k)) = (&mut err, failing)
                && let Some(f) = Self::FIELDS.iter().find(|f| f.field == k)
            {
                *field = f.field;
            }
            err
        })?;
        c.validate()?;
        Ok(c)
    }

    /// Reads a closed-loop settings JSON file (a regular file of at most
    /// [`nudge_planner::settings::MAX_SETTINGS_BYTES`], refused before reading otherwise) and parses it
    /// as [`Self::from_json`].
    ///
    /// # Errors
    /// [`SimConfigError::File`] naming the file when it cannot be read, otherwise as
    /// [`Self::from_json`].
    pub fn from_file(path: impl AsRef<std::path::Path>) -> Result<Self, SimConfigError> {
        let path = path.as_ref();
        let bytes =
            nudge_predictor::file::read_bounded(path, nudge_planner::settings::MAX_SETTINGS_BYTES)
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
        let bad: [(&str, f64); 22] = [
            ("max_steps", 0.0),
            ("max_steps", 1001.0),
            ("settle_y", f64::NAN),
            ("settle_y", 0.0),
            // Issue 49: 1e308 validated and reported success after one step.
            ("settle_y", 1e308),
            ("settle_y", 1.3),
            ("settle_psi", 1e308),
            ("settle_psi", 0.21),
            ("settle_psi", -0.1),
            ("settle_steps", 0.0),
            ("abort_after", 5000.0),
            ("abort_hold", 5000.0),
            ("gap_speed", -1.0),
            ("gap_speed", f64::NAN),
            ("start_abort_after", 5000.0),
            ("gap_window", 1000.0),
            ("fault_brake_limit", 0.0),
            ("fault_brake_limit", f64::INFINITY),
            ("replay_lateral_decay", 1.5),
            ("replay_lateral_decay", f64::NAN),
            ("stall_progress", 2.0),
            ("crawl_fraction", -0.5),
        ];
        for (field, v) in bad {
            let mut c = SimConfig::default();
            match field {
                "max_steps" => c.max_steps = v as usize,
                "settle_y" => c.settle_y = v,
                "settle_psi" => c.settle_psi = v,
                "settle_steps" => c.settle_steps = v as usize,
                "abort_after" => c.abort_after = v as usize,
                "abort_hold" => c.abort_hold = v as usize,
                "gap_speed" => c.gap_speed = v,
                "start_abort_after" => c.start_abort_after = v as usize,
                "gap_window" => c.gap_window = v,
                "fault_brake_limit" => c.fault_brake_limit = v,
                "replay_lateral_decay" => c.replay_lateral_decay = v,
                "stall_progress" => c.stall_progress = v,
                _ => c.crawl_fraction = v,
            }
            match c.validate() {
                Err(SimConfigError::OutOfRange { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field} = {v}: expected an error, got {other:?}"),
            }
        }
        for text in [r#"{"bogus": 1}"#, "[30]"] {
            assert!(matches!(
                SimConfig::from_json(text),
                Err(SimConfigError::Invalid {
                    field: "<json>",
                    ..
                })
            ));
        }
        // A value of the wrong type or variant names its field (it named `<json>` before).
        assert!(matches!(
            SimConfig::from_json(r#"{"world": "predictor"}"#),
            Err(SimConfigError::Invalid { field: "world", .. })
        ));
        assert!(matches!(
            "log-replay".parse::<World>(),
            Err(SimConfigError::Invalid { field: "world", .. })
        ));
    }
    /// Every way a closed-loop settings text is refused gives a message of at most 200
    /// characters naming the item: an unknown key (serde listed all the fields: 343
    /// characters), an unknown world, a wrong type (named), each field out of its range.
    #[test]
    fn every_message_is_short_and_names_its_item() {
        let mut cases = vec![
            (
                r#"{"no_such_key": 1}"#.to_string(),
                "`no_such_key`".to_string(),
            ),
            (r#"{"world": "moon"}"#.to_string(), "`moon`".to_string()),
        ];
        let defaults = serde_json::to_value(SimConfig::default()).expect("serialise");
        for key in defaults.as_object().expect("an object").keys() {
            cases.push((format!(r#"{{"{key}": -1}}"#), format!("`{key}`")));
            cases.push((format!(r#"{{"{key}": [1]}}"#), format!("`{key}`")));
        }
        for (text, item) in cases {
            let e = SimConfig::from_json(&text)
                .err()
                .unwrap_or_else(|| panic!("{text} accepted"))
                .to_string();
            assert!(e.contains(&item), "{text}: {e}");
            assert!(
                e.chars().count() <= 200,
                "{text}: {} characters: {e}",
                e.chars().count()
            );
        }
    }
}
