//! The `idm` world: reactive traffic with a known model, fitted to real car-following.
//!
//! Every other vehicle keeps its lane and its lateral position (its last observed y), except
//! where its lane really ends (scenes with lane extents, [`LaneEndMerge`]), and moves along
//! the road by the Intelligent Driver Model (Treiber, Hennecke & Helbing 2000) with δ from the
//! file (4):
//!
//! ```text
//! a = a_max · (1 − (v / v0)^δ − (s* / s)²),   s* = max(0, s0 + v·T + v·(v − v_lead) / (2·√(a_max·b)))
//! ```
//!
//! s is the bumper-to-bumper gap to its leader (m, floored at the file's `gap_floor_m` in the
//! interaction term), free road drops the interaction term, and the acceleration is floored at
//! −`max_decel_mps2` (9 m/s²). Integration: three ballistic sub-steps of 0.1 s per 0.3 s
//! closed-loop step, v' = max(v + a·dt, 0), x' = x + (v + v')/2·dt, every vehicle's
//! acceleration computed from the states at the start of the sub-step. This is the model the
//! parameters were fitted with (`python/train/nudge_train/idm/model.py`).
//!
//! **Drivers** ([`IdmPopulation`], `assets/worlds/idm.json`, schema "nudge.idm/1"): each
//! vehicle draws one row (T, s0, a_max, b, v0_ratio) of the fitted population, with
//! replacement, seeded by the run's seed and the vehicle's index; only rows of the scene's
//! source are drawn (the US-101 rows for a scene whose `source`/`scene` metadata names US-101,
//! the I-80 rows for I-80, every row otherwise), as the file's `sampling` text says. Desired
//! speed v0 = v0_ratio · v_ref, v_ref = the vehicle's highest logged speed (the last observed
//! speed, and every displacement of its history and of its logged future over 0.3 s), taken
//! as at least [`V_REF_MIN`] (a vehicle the log shows standing still wants to move off at
//! walking pace rather than divide by zero).
//!
//! **Leaders.** A follower's leader is the nearest vehicle ahead (centre ahead of its centre)
//! among the others in its lane (lane of the centre, fixed for the run; or whose box overlaps
//! its own across the road) and the ego when the ego counts as being in its lane. At the start
//! the ego counts in the lane of its centre, like every other vehicle. Afterwards it enters a
//! follower's lane by the file's **intrusion rule** ([`IntrusionRule`], fitted to real US-101
//! cut-ins): each follower draws once per run whether it yields (probability `p_yield`, seeded
//! by the run's seed and its index); a yielding follower counts the ego once the ego's nearest
//! edge is more than `threshold_m` inside the follower's lane (lateral overlap of the ego's box
//! with the lane > threshold), a non-yielding one only once the ego is entirely inside the
//! lane. The ego keeps counting while any part of it is in the lane (a follower does not
//! ignore a car that is leaving its lane) and stops once it is wholly out. The gap to the ego
//! is measured to the rear of the ego's rotated box, its speed along the road is v·cos ψ, and
//! within a 0.3 s step the ego moves linearly from its state before the step to its state
//! after it.
//!
//! **Lanes that end** ([`LaneEndMerge`], the file's optional `lane_end` section): a vehicle
//! whose lane really ends ahead of it changes into the adjacent lane that outlasts it once it
//! is within `zone_m` of the end and the gap is acceptable by a MOBIL-style safety criterion
//! (Kesting, Treiber & Helbing 2007): the new follower's IDM acceleration behind it after the
//! change is at least −`b_safe_mps2`, and so is its own behind the new leader, with
//! bumper-to-bumper gaps of at least `min_gap_m` to both (the ego counts as a leader or
//! follower in the lane of its centre; as a follower it is judged with the merging vehicle's
//! own driver). The change moves its centre to the new lane's centre at `lateral_speed_mps`,
//! and it counts in the new lane from the decision on. Until it changes, its lane's end leads
//! it as a standing vehicle `stop_margin_m` before the end, so without an acceptable gap it
//! stops there and waits. Decisions are taken every sub-step, in vehicle order, from the
//! states at its start.
//!
//! Deterministic: the same scene, population and seed give the same traffic, bit for bit.

use std::path::{Path, PathBuf};

use nudge_predictor::{DT, T_OBS};

use serde_json::Value;

use crate::error::{SimConfigError, WorldFileError};
use nudge_planner::State;
use nudge_planner::scenario::{LaneExtent, Scenario};
use nudge_planner::settings::schema::{closed, open_min};

/// The schema string of the world file.
pub const IDM_SCHEMA: &str = "nudge.idm/1";
/// Largest world file read (bytes): 8 MiB, 250 times the shipped `idm.json` (32 kB).
pub const MAX_WORLD_BYTES: u64 = 8 << 20;
/// Ballistic sub-steps per closed-loop step of [`DT`] = 0.3 s.
pub const SUBSTEPS: usize = 3;
/// The sub-step (s): the fit's 0.1 s ([`SUBSTEPS`] · `SUB_DT` = [`DT`]).
pub const SUB_DT: f64 = 0.1;
/// Smallest reference speed v_ref (m/s) of a driver's desired speed.
pub const V_REF_MIN: f64 = 1.0;
/// The fitted parameters in the order of every driver row.
pub const PARAMETER_NAMES: [&str; 5] = ["T", "s0", "a_max", "b", "v0_ratio"];
/// Physically plausible ranges `[lo, hi]` of the driver parameters, in [`PARAMETER_NAMES`]
/// order, checked in code (a file's own `bounds` must lie inside them, and so must every
/// driver). Units: T s, s0 m, a_max m/s², b m/s², v0_ratio 1. Reasons:
/// - T (time gap): 0.1–5 s. The IDM's published highway values are 1.0–1.6 s (Treiber,
///   Hennecke & Helbing 2000: 1.6 s; Treiber & Kesting, *Traffic Flow Dynamics*, 2013: 1.0 s);
///   NGSIM followers keep gaps as short as 0.3 s (the fit's box), and beyond ~5 s a vehicle
///   is in free flow rather than following.
/// - s0 (jam distance): 0.1–10 m; published values are 2 m (both sources above); a stopped
///   queue holds 1–5 m between bumpers.
/// - a_max (maximum acceleration): 0.1–6 m/s²; published values 0.73–1.0 m/s²; a passenger
///   car's full-throttle acceleration is 2–6 m/s² (0–100 km/h in 5–14 s).
/// - b (comfortable deceleration): 0.1–9 m/s²; published values 1.5–1.67 m/s²; 3.4 m/s² is
///   the comfortable deceleration of road design (AASHTO's stopping-sight-distance rate) and
///   a car on dry asphalt brakes at most ~9 m/s² (friction ≈ 0.9 g).
/// - v0_ratio (desired speed / the vehicle's highest logged speed): 0.5–3; a driver that
///   wants less than half or more than three times the speed it drove is not the driver
///   that was logged.
pub const PLAUSIBLE: [(f64, f64); 5] =
    [(0.1, 5.0), (0.1, 10.0), (0.1, 6.0), (0.1, 9.0), (0.5, 3.0)];
/// The IDM's free-road exponent δ: (0, 10] (published value 4).
pub const PLAUSIBLE_DELTA: f64 = 10.0;
/// The world's braking limit `model.max_decel_mps2`: (0, 12] m/s² (tyre friction ≈ 1.2 g at
/// most).
pub const PLAUSIBLE_MAX_DECEL: f64 = 12.0;
/// The world's gap floor `model.gap_floor_m`: (0, 1] m.
pub const PLAUSIBLE_GAP_FLOOR: f64 = 1.0;
/// `intrusion.threshold_m`: [−3.5, 3.5] m, a lane width either side of the line.
pub const PLAUSIBLE_THRESHOLD: f64 = 3.5;
/// The keys a "nudge.idm/1" file may hold at the top level; `sampling`, `pooled`, `metrics`
/// and `provenance` are free-form documentation of the fit, not read.
const TOP_KEYS: &[&str] = &[
    "schema",
    "units",
    "model",
    "parameter_names",
    "bounds",
    "drivers",
    "driver_sources",
    "intrusion",
    "lane_end",
    "sampling",
    "pooled",
    "metrics",
    "provenance",
];
/// The keys of `units`.
const UNIT_KEYS: &[&str] = &[
    "T",
    "s0",
    "a_max",
    "b",
    "v0_ratio",
    "gap",
    "speed",
    "threshold_m",
];
/// The keys of `model` (`acceleration`, `v0`, `gap` are prose).
const MODEL_KEYS: &[&str] = &[
    "acceleration",
    "delta",
    "v0",
    "gap",
    "max_decel_mps2",
    "gap_floor_m",
    "integration",
];
/// The keys of `intrusion` (`rule` is prose, `fit` free-form documentation).
const INTRUSION_KEYS: &[&str] = &["rule", "threshold_m", "p_yield", "fit"];
/// The units the file must state for each parameter and for the intrusion threshold.
const UNITS: [(&str, &str); 6] = [
    ("T", "s"),
    ("s0", "m"),
    ("a_max", "m/s^2"),
    ("b", "m/s^2"),
    ("v0_ratio", "1"),
    ("threshold_m", "m"),
];

/// The world file of the `idm` world under the assets directory `assets`:
/// `<assets>/worlds/idm.json` (the assets directory as for the models,
/// [`nudge_predictor::default_assets_dir`]). The only place that knows this layout.
#[must_use]
pub fn idm_path(assets: &Path) -> PathBuf {
    assets.join("worlds").join("idm.json")
}

/// One driver: IDM parameters. Units: T s, s0 m, a_max m/s², b m/s², v0_ratio 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdmDriver {
    /// Time headway T (s).
    pub t: f64,
    /// Jam gap s0 (m).
    pub s0: f64,
    /// Maximum acceleration a_max (m/s²).
    pub a_max: f64,
    /// Comfortable deceleration b (m/s²).
    pub b: f64,
    /// Desired speed over the vehicle's highest logged speed (1).
    pub v0_ratio: f64,
}

/// Where a driver's record came from (the file's `driver_sources`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DriverSource {
    /// The I-80 car-following pairs.
    I80,
    /// The US-101 tracks.
    Us101,
}

impl DriverSource {
    /// `"i80"` or `"us101"`, as in the file.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::I80 => "i80",
            Self::Us101 => "us101",
        }
    }

    /// The source a scene's metadata names (`source`, else `scene`): US-101 or I-80 in any
    /// spelling (`USA_US101-12_1_T-1.xml.gz`, `i-80`); `None` for anything else.
    #[must_use]
    pub fn of_scene(sc: &Scenario) -> Option<Self> {
        let text = sc
            .metadata
            .get("source")
            .or_else(|| sc.metadata.get("scene"))?;
        let squashed: String = text
            .chars()
            .filter(char::is_ascii_alphanumeric)
            .collect::<String>()
            .to_ascii_lowercase();
        if squashed.contains("us101") {
            Some(Self::Us101)
        } else if squashed.contains("i80") {
            Some(Self::I80)
        } else {
            None
        }
    }
}

/// The IDM's fixed parts (the file's `model`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdmModel {
    /// Free-road exponent δ (1).
    pub delta: f64,
    /// Braking floor (m/s², > 0): accelerations below −this are floored.
    pub max_decel: f64,
    /// Gap (m, > 0) used in the interaction term when the gap is at most this.
    pub gap_floor: f64,
}

impl IdmModel {
    /// The IDM acceleration (m/s²) of `driver` at speed `v` (m/s) with desired speed `v0`
    /// (m/s), behind `leader` = (bumper-to-bumper gap s (m), leader speed (m/s)) or on a free
    /// road (`None`); floored at −`max_decel`.
    #[must_use]
    pub fn accel(&self, driver: &IdmDriver, v: f64, v0: f64, leader: Option<(f64, f64)>) -> f64 {
        let free = 1.0 - (v.max(0.0) / v0).powf(self.delta);
        let interaction = leader.map_or(0.0, |(s, v_lead)| {
            let s_star = driver.s0
                + v * driver.t
                + v * (v - v_lead) / (2.0 * (driver.a_max * driver.b).sqrt());
            (s_star.max(0.0) / s.max(self.gap_floor)).powi(2)
        });
        (driver.a_max * (free - interaction)).max(-self.max_decel)
    }

    /// The steady-state gap s_e(v) = (s0 + v·T) / √(1 − (v/v0)^δ) (m) of `driver` following a
    /// leader at the same speed `v` < `v0` (m/s).
    #[must_use]
    pub fn equilibrium_gap(&self, driver: &IdmDriver, v: f64, v0: f64) -> f64 {
        (driver.s0 + v * driver.t) / (1.0 - (v / v0).powf(self.delta)).sqrt()
    }
}

/// When a follower treats an intruding ego as its leader (the file's `intrusion`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntrusionRule {
    /// A yielding follower reacts once the intruder's nearest edge is more than this inside
    /// its lane (m; negative: before the intruder reaches the line).
    pub threshold_m: f64,
    /// Probability that a follower yields early (by the threshold); the others react only at
    /// full entry.
    pub p_yield: f64,
}

impl IntrusionRule {
    /// Whether a follower in the lane `[lane.0, lane.1]` (y, m) counts an intruder with
    /// lateral extent `[extent.0, extent.1]` (y, m) as being in its lane: `yields` (its draw)
    /// and the overlap beyond the threshold, or the intruder entirely inside the lane, or
    /// (`latched`: it counted a sub-step ago) any overlap at all.
    #[must_use]
    pub fn reacts(
        &self,
        lane: (f64, f64),
        extent: (f64, f64),
        yields: bool,
        latched: bool,
    ) -> bool {
        let overlap = extent.1.min(lane.1) - extent.0.max(lane.0);
        let inside = extent.0 >= lane.0 && extent.1 <= lane.1;
        inside || (yields && overlap > self.threshold_m) || (latched && overlap > 0.0)
    }
}

nudge_planner::settings_struct! {
    /// How an IDM vehicle whose lane really ends merges (the world file's optional `lane_end`
    /// section; absent, the defaults). Units: m, m/s, m/s².
    #[derive(Copy)]
    pub struct LaneEndMerge("lane_end.") {
        /// Distance to the end of its lane within which a vehicle looks for a gap (m).
        zone_m: f64 = 200.0, closed(0.0, 1e4, "m");
        /// Safety criterion: the new follower's and the merging vehicle's IDM accelerations
        /// must both be at least −this (m/s²).
        b_safe_mps2: f64 = 4.0, open_min(0.0, 1e3, "m/s²");
        /// Smallest bumper-to-bumper gap to the new leader and to the new follower (m).
        min_gap_m: f64 = 2.0, closed(0.0, 1e3, "m");
        /// Lateral speed of the change (m/s).
        lateral_speed_mps: f64 = 1.0, open_min(0.0, 1e3, "m/s");
        /// A vehicle that finds no gap stops this far before its lane's end (m).
        stop_margin_m: f64 = 2.0, closed(0.0, 1e3, "m");
    }
}

impl LaneEndMerge {
    /// The value of field `field` (`None` for an unknown name).
    #[must_use]
    pub fn numeric(&self, field: &str) -> Option<f64> {
        self.value(field)
    }

    /// Checks every field against its range in [`Self::FIELDS`] (NaN and infinity never are
    /// in range).
    ///
    /// # Errors
    /// [`SimConfigError::OutOfRange`] naming the first field out of its range.
    pub fn validate(&self) -> Result<(), SimConfigError> {
        super::config::in_range(self.out_of_range())
    }

    /// The MOBIL-style safety criterion of a change: `follower` = (its driver, speed (m/s),
    /// desired speed (m/s), bumper-to-bumper gap to the merging vehicle (m)) when the target
    /// lane has a vehicle behind, `own` = (the merging vehicle's driver, speed, desired speed)
    /// and `leader` = (gap (m), speed (m/s)) of the vehicle ahead in the target lane when there
    /// is one: both gaps at least `min_gap_m` and both IDM accelerations after the change at
    /// least −`b_safe_mps2`.
    #[must_use]
    pub fn acceptable(
        &self,
        model: &IdmModel,
        own: (&IdmDriver, f64, f64),
        follower: Option<(&IdmDriver, f64, f64, f64)>,
        leader: Option<(f64, f64)>,
    ) -> bool {
        let (driver, v, v0) = own;
        let follower_ok = follower.is_none_or(|(d, vf, vf0, gap)| {
            gap >= self.min_gap_m && model.accel(d, vf, vf0, Some((gap, v))) >= -self.b_safe_mps2
        });
        let own_ok = leader.is_none_or(|(gap, vl)| {
            gap >= self.min_gap_m
                && model.accel(driver, v, v0, Some((gap, vl))) >= -self.b_safe_mps2
        });
        follower_ok && own_ok
    }
}

/// The fitted driver population and model of the `idm` world, parsed once per batch from a
/// "nudge.idm/1" file.
#[derive(Debug, Clone, PartialEq)]
pub struct IdmPopulation {
    /// The file it came from.
    pub path: PathBuf,
    /// The drivers, one row each.
    pub drivers: Vec<IdmDriver>,
    /// The source of each driver `[drivers.len()]`.
    pub sources: Vec<DriverSource>,
    /// The model's fixed parts.
    pub model: IdmModel,
    /// The intrusion rule.
    pub intrusion: IntrusionRule,
    /// How vehicles whose lane ends merge.
    pub lane_end: LaneEndMerge,
}

/// Field access with errors that name the file and the field.
struct Fields<'a> {
    path: &'a Path,
}

impl Fields<'_> {
    fn err(&self, field: impl Into<String>, reason: impl Into<String>) -> WorldFileError {
        WorldFileError::Field {
            path: self.path.to_path_buf(),
            field: field.into(),
            reason: reason.into(),
        }
    }

    fn get<'v>(&self, v: &'v Value, parent: &str, key: &str) -> Result<&'v Value, WorldFileError> {
        let name = if parent.is_empty() {
            key.to_string()
        } else {
            format!("{parent}.{key}")
        };
        v.get(key).ok_or_else(|| self.err(name, "missing"))
    }

    fn text<'v>(&self, v: &'v Value, field: &str) -> Result<&'v str, WorldFileError> {
        v.as_str()
            .ok_or_else(|| self.err(field, format!("expected text, got {v}")))
    }

    fn number(&self, v: &Value, field: &str) -> Result<f64, WorldFileError> {
        v.as_f64()
            .filter(|x| x.is_finite())
            .ok_or_else(|| self.err(field, format!("expected a finite number, got {v}")))
    }

    fn array<'v>(&self, v: &'v Value, field: &str) -> Result<&'v [Value], WorldFileError> {
        v.as_array()
            .map(Vec::as_slice)
            .ok_or_else(|| self.err(field, format!("expected an array, got {v}")))
    }

    /// Refuses a key of the object `v` (named `parent`, "" for the top level) that is not in
    /// `known`, naming it (`model.deltaa`).
    fn only(&self, v: &Value, parent: &str, known: &[&str]) -> Result<(), WorldFileError> {
        let Some(map) = v.as_object() else {
            let what = if parent.is_empty() {
                "the file"
            } else {
                parent
            };
            return Err(self.err(what, format!("expected an object, got {v}")));
        };
        match map.keys().find(|k| !known.contains(&k.as_str())) {
            None => Ok(()),
            Some(k) => {
                let name = if parent.is_empty() {
                    k.clone()
                } else {
                    format!("{parent}.{k}")
                };
                Err(self.err(name, format!("unknown key (known: {})", known.join(", "))))
            }
        }
    }

    /// A positive number of at most `hi` (plausibility in code).
    fn positive_to(&self, v: &Value, field: &str, hi: f64) -> Result<f64, WorldFileError> {
        let x = self.positive(v, field)?;
        if x <= hi {
            Ok(x)
        } else {
            Err(self.err(field, format!("{x} is implausible: must be in (0, {hi}]")))
        }
    }

    fn positive(&self, v: &Value, field: &str) -> Result<f64, WorldFileError> {
        let x = self.number(v, field)?;
        if x > 0.0 {
            Ok(x)
        } else {
            Err(self.err(field, format!("must be > 0, got {x}")))
        }
    }
}

/// The sections of a "nudge.idm/1" file, each read and checked on its own (in file order by
/// [`IdmPopulation::from_json`]).
impl Fields<'_> {
    /// `schema` is [`IDM_SCHEMA`] and `units` names the unit of every parameter and of
    /// `threshold_m`.
    fn check_schema_and_units(&self, root: &Value) -> Result<(), WorldFileError> {
        self.only(root, "", TOP_KEYS)?;
        let schema = self.text(self.get(root, "", "schema")?, "schema")?;
        if schema != IDM_SCHEMA {
            return Err(self.err("schema", format!("{schema:?}, expected {IDM_SCHEMA:?}")));
        }
        let units = self.get(root, "", "units")?;
        self.only(units, "units", UNIT_KEYS)?;
        for (name, unit) in UNITS {
            let field = format!("units.{name}");
            let got = self.text(self.get(units, "units", name)?, &field)?;
            if got != unit {
                return Err(self.err(field, format!("{got:?}, expected {unit:?}")));
            }
        }
        Ok(())
    }

    /// `parameter_names` is [`PARAMETER_NAMES`], in order.
    fn check_parameter_names(&self, root: &Value) -> Result<(), WorldFileError> {
        let names = self.array(self.get(root, "", "parameter_names")?, "parameter_names")?;
        let names: Vec<&str> = names.iter().filter_map(Value::as_str).collect();
        if names != PARAMETER_NAMES {
            return Err(self.err(
                "parameter_names",
                format!("{names:?}, expected {PARAMETER_NAMES:?}"),
            ));
        }
        Ok(())
    }

    /// `bounds`: the finite (lo, hi) of each parameter, in [`PARAMETER_NAMES`] order, with
    /// 0 < lo < hi (units as in `units`).
    fn bounds(&self, root: &Value) -> Result<[(f64, f64); 5], WorldFileError> {
        let bounds_v = self.get(root, "", "bounds")?;
        self.only(bounds_v, "bounds", &PARAMETER_NAMES)?;
        let mut bounds = [(0.0, 0.0); 5];
        for (k, name) in PARAMETER_NAMES.iter().enumerate() {
            let field = format!("bounds.{name}");
            let pair = self.array(self.get(bounds_v, "bounds", name)?, &field)?;
            if pair.len() != 2 {
                return Err(self.err(field, format!("{} values, expected [lo, hi]", pair.len())));
            }
            let lo = self.number(&pair[0], &format!("{field}[0]"))?;
            let hi = self.number(&pair[1], &format!("{field}[1]"))?;
            if !(0.0 < lo && lo < hi) {
                return Err(self.err(field, format!("[{lo}, {hi}] is not 0 < lo < hi")));
            }
            let (plo, phi) = PLAUSIBLE[k];
            if lo < plo || hi > phi {
                return Err(self.err(
                    field,
                    format!(
                        "[{lo}, {hi}] reaches outside the physically plausible [{plo}, {phi}] \
                         (nudge_sim::idm::PLAUSIBLE)"
                    ),
                ));
            }
            bounds[k] = (lo, hi);
        }
        Ok(bounds)
    }

    /// `model`: the positive `delta`, `max_decel_mps2` (m/s²) and `gap_floor_m` (m), and an
    /// `integration` naming the ballistic 0.1 s update.
    fn model(&self, root: &Value) -> Result<IdmModel, WorldFileError> {
        let model_v = self.get(root, "", "model")?;
        self.only(model_v, "model", MODEL_KEYS)?;
        let model = IdmModel {
            delta: self.positive_to(
                self.get(model_v, "model", "delta")?,
                "model.delta",
                PLAUSIBLE_DELTA,
            )?,
            max_decel: self.positive_to(
                self.get(model_v, "model", "max_decel_mps2")?,
                "model.max_decel_mps2",
                PLAUSIBLE_MAX_DECEL,
            )?,
            gap_floor: self.positive_to(
                self.get(model_v, "model", "gap_floor_m")?,
                "model.gap_floor_m",
                PLAUSIBLE_GAP_FLOOR,
            )?,
        };
        let integration = self.text(
            self.get(model_v, "model", "integration")?,
            "model.integration",
        )?;
        if !(integration.contains("ballistic") && integration.contains("dt = 0.1 s")) {
            return Err(self.err(
                "model.integration",
                format!(
                    "{integration:?}: the world integrates ballistic sub-steps of 0.1 s \
                     (\"ballistic, dt = 0.1 s\")"
                ),
            ));
        }
        Ok(model)
    }

    /// `drivers`: at least one row, each as [`Fields::driver`].
    fn drivers(
        &self,
        root: &Value,
        bounds: &[(f64, f64); 5],
    ) -> Result<Vec<IdmDriver>, WorldFileError> {
        let rows = self.array(self.get(root, "", "drivers")?, "drivers")?;
        if rows.is_empty() {
            return Err(self.err("drivers", "no driver"));
        }
        rows.iter()
            .enumerate()
            .map(|(i, row)| self.driver(i, row, bounds))
            .collect()
    }

    /// Row `i` of `drivers`: 5 finite values in [`PARAMETER_NAMES`] order, each within its
    /// `bounds`.
    fn driver(
        &self,
        i: usize,
        row: &Value,
        bounds: &[(f64, f64); 5],
    ) -> Result<IdmDriver, WorldFileError> {
        let field = format!("drivers[{i}]");
        let vals = self.array(row, &field)?;
        if vals.len() != PARAMETER_NAMES.len() {
            return Err(self.err(field, format!("{} values, expected 5", vals.len())));
        }
        let mut p = [0.0; 5];
        for (k, v) in vals.iter().enumerate() {
            let field = format!("drivers[{i}][{k}]");
            let x = self.number(v, &field)?;
            let (lo, hi) = bounds[k];
            if !(lo..=hi).contains(&x) {
                return Err(self.err(
                    field,
                    format!(
                        "{} = {x} outside its bounds [{lo}, {hi}]",
                        PARAMETER_NAMES[k]
                    ),
                ));
            }
            p[k] = x;
        }
        Ok(IdmDriver {
            t: p[0],
            s0: p[1],
            a_max: p[2],
            b: p[3],
            v0_ratio: p[4],
        })
    }

    /// `driver_sources`: one `"i80"` or `"us101"` per driver (`n_drivers` of them).
    fn driver_sources(
        &self,
        root: &Value,
        n_drivers: usize,
    ) -> Result<Vec<DriverSource>, WorldFileError> {
        let src = self.array(self.get(root, "", "driver_sources")?, "driver_sources")?;
        if src.len() != n_drivers {
            return Err(self.err(
                "driver_sources",
                format!("{} entries for {} drivers", src.len(), n_drivers),
            ));
        }
        let mut sources = Vec::with_capacity(src.len());
        for (i, s) in src.iter().enumerate() {
            let field = format!("driver_sources[{i}]");
            sources.push(match self.text(s, &field)? {
                "i80" => DriverSource::I80,
                "us101" => DriverSource::Us101,
                other => {
                    return Err(
                        self.err(field, format!("{other:?}, expected \"i80\" or \"us101\""))
                    );
                }
            });
        }
        Ok(sources)
    }

    /// `intrusion`: a finite `threshold_m` (m) and a `p_yield` in [0, 1].
    fn intrusion(&self, root: &Value) -> Result<IntrusionRule, WorldFileError> {
        let rule = self.get(root, "", "intrusion")?;
        self.only(rule, "intrusion", INTRUSION_KEYS)?;
        let threshold_m = self.number(
            self.get(rule, "intrusion", "threshold_m")?,
            "intrusion.threshold_m",
        )?;
        if threshold_m.abs() > PLAUSIBLE_THRESHOLD {
            return Err(self.err(
                "intrusion.threshold_m",
                format!(
                    "{threshold_m} is implausible: must be in [-{PLAUSIBLE_THRESHOLD}, \
                     {PLAUSIBLE_THRESHOLD}] m"
                ),
            ));
        }
        let p_yield = self.number(self.get(rule, "intrusion", "p_yield")?, "intrusion.p_yield")?;
        if !(0.0..=1.0).contains(&p_yield) {
            return Err(self.err(
                "intrusion.p_yield",
                format!("{p_yield} is not a probability in [0, 1]"),
            ));
        }
        Ok(IntrusionRule {
            threshold_m,
            p_yield,
        })
    }

    /// `lane_end` (optional: absent, [`LaneEndMerge::default`]): an object of
    /// [`LaneEndMerge`] fields (missing ones default, unknown ones refused), validated.
    fn lane_end(&self, root: &Value) -> Result<LaneEndMerge, WorldFileError> {
        let Some(section) = root.get("lane_end") else {
            return Ok(LaneEndMerge::default());
        };
        let rule: LaneEndMerge = serde_json::from_value(section.clone())
            .map_err(|e| self.err("lane_end", e.to_string()))?;
        rule.validate().map_err(|e| match e {
            SimConfigError::OutOfRange { field, .. } => {
                self.err(format!("lane_end.{field}"), e.to_string())
            }
            other => self.err("lane_end", other.to_string()),
        })?;
        Ok(rule)
    }
}

impl IdmPopulation {
    /// Reads and checks a "nudge.idm/1" file, opened by the checked-open routine
    /// ([`nudge_predictor::file::read_bounded`]): a regular file of at most
    /// [`MAX_WORLD_BYTES`], its type and size checked before reading.
    ///
    /// # Errors
    /// [`WorldFileError::NotRegularFile`] (a FIFO or device, refused before opening),
    /// [`WorldFileError::TooLarge`], [`WorldFileError::Io`] when the file cannot be read,
    /// otherwise as [`IdmPopulation::from_json`].
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, WorldFileError> {
        let path = path.as_ref();
        let bytes =
            nudge_predictor::file::read_bounded(path, MAX_WORLD_BYTES).map_err(|e| match e {
                nudge_predictor::PredictorError::NotRegularFile { path, kind } => {
                    WorldFileError::NotRegularFile { path, kind }
                }
                nudge_predictor::PredictorError::FileTooLarge { path, size, max } => {
                    WorldFileError::TooLarge { path, size, max }
                }
                nudge_predictor::PredictorError::Io { path, source } => {
                    WorldFileError::Io { path, source }
                }
                other => WorldFileError::Io {
                    path: path.to_path_buf(),
                    source: std::io::Error::other(other.to_string()),
                },
            })?;
        let text = String::from_utf8(bytes).map_err(|e| WorldFileError::NotJson {
            path: path.to_path_buf(),
            reason: format!("not UTF-8 text: {e}"),
        })?;
        Self::from_json(&text, path)
    }

    /// Parses and checks the text of a "nudge.idm/1" file; `path` names it in errors.
    ///
    /// Checked: no repeated key anywhere ([`nudge_predictor::json::parse`]); no unknown key at
    /// the top level or in `units`, `model`, `bounds`, `intrusion`; `schema`; `units` of every
    /// parameter and of `threshold_m`; `parameter_names` = T, s0, a_max, b, v0_ratio; `bounds`
    /// (finite, 0 < lo < hi, inside the physically plausible [`PLAUSIBLE`] ranges in code);
    /// `model.delta` in (0, [`PLAUSIBLE_DELTA`]], `model.max_decel_mps2` in
    /// (0, [`PLAUSIBLE_MAX_DECEL`]], `model.gap_floor_m` in (0, [`PLAUSIBLE_GAP_FLOOR`]] and
    /// `model.integration` naming the ballistic 0.1 s update; every `drivers` row (5 finite
    /// values within `bounds`); one `driver_sources` entry (`"i80"` or `"us101"`) per row;
    /// `intrusion.threshold_m` within ±[`PLAUSIBLE_THRESHOLD`] and `intrusion.p_yield` in
    /// [0, 1]; the optional
    /// `lane_end` section as [`LaneEndMerge::validate`] requires.
    ///
    /// # Errors
    /// [`WorldFileError::NotJson`] for text that is not JSON, [`WorldFileError::Field`]
    /// naming the first field that is missing or wrong.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, WorldFileError> {
        let f = Fields { path };
        let root: Value =
            nudge_predictor::json::parse(text).map_err(|e| WorldFileError::NotJson {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })?;
        f.check_schema_and_units(&root)?;
        f.check_parameter_names(&root)?;
        let bounds = f.bounds(&root)?;
        let model = f.model(&root)?;
        let drivers = f.drivers(&root, &bounds)?;
        let sources = f.driver_sources(&root, drivers.len())?;
        let intrusion = f.intrusion(&root)?;
        let lane_end = f.lane_end(&root)?;
        Ok(Self {
            path: path.to_path_buf(),
            drivers,
            sources,
            model,
            intrusion,
            lane_end,
        })
    }

    /// Indices of the drivers a scene of `source` draws from: the rows of that source, or
    /// every row when the source is unknown or has no row.
    #[must_use]
    pub fn rows_for(&self, source: Option<DriverSource>) -> Vec<usize> {
        let all = || (0..self.drivers.len()).collect::<Vec<_>>();
        match source {
            None => all(),
            Some(s) => {
                let rows: Vec<usize> = (0..self.drivers.len())
                    .filter(|&i| self.sources[i] == s)
                    .collect();
                if rows.is_empty() { all() } else { rows }
            }
        }
    }
}

/// SplitMix64 finaliser.
fn mix(z: u64) -> u64 {
    let mut z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A deterministic 64-bit draw of (run seed, vehicle index, purpose).
fn draw(seed: u64, vehicle: usize, purpose: u64) -> u64 {
    mix(mix(mix(seed) ^ vehicle as u64) ^ purpose)
}

/// A uniform draw in [0, 1) of (run seed, vehicle index, purpose).
fn uniform(seed: u64, vehicle: usize, purpose: u64) -> f64 {
    (draw(seed, vehicle, purpose) >> 11) as f64 / (1_u64 << 53) as f64
}

/// One IDM vehicle of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IdmVehicle {
    /// Centre x (m).
    pub x: f64,
    /// Centre y (m): fixed, except during a lane-end merge.
    pub y: f64,
    /// Speed along the road (m/s, ≥ 0).
    pub v: f64,
    /// Length (m).
    pub length: f64,
    /// Width (m).
    pub width: f64,
    /// Lane index (of its centre at the start; the new lane from a lane-end merge's decision
    /// on).
    pub lane: usize,
    /// The centre y (m) a lane-end merge moves it to; `None` while it has not changed.
    pub merging_to: Option<f64>,
    /// Its driver.
    pub driver: IdmDriver,
    /// Desired speed v0 = v0_ratio · max(v_ref, [`V_REF_MIN`]) (m/s).
    pub v0: f64,
    /// Whether it yields early to an intruder ([`IntrusionRule`]).
    pub yields: bool,
    /// Whether the ego counts as being in its lane ([`IntrusionRule::reacts`]).
    pub ego_in_lane: bool,
}

/// The ego as the other vehicles see it at one sub-step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EgoView {
    /// Centre x (m).
    pub x: f64,
    /// Lateral extent (lowest y, highest y) of its box (m).
    pub extent: (f64, f64),
    /// Rear-most x of its box (m).
    pub rear: f64,
    /// Front-most x of its box (m).
    pub front: f64,
    /// Centre y (m).
    pub y: f64,
    /// Speed along the road (m/s).
    pub vx: f64,
}

impl EgoView {
    /// The view of an ego of `size` (length, width) (m) in `state` (x, y, ψ, v).
    #[must_use]
    pub fn new(state: [f64; 4], size: [f64; 2]) -> Self {
        let (s, c) = state[2].sin_cos();
        let half_x = 0.5 * (size[0] * c.abs() + size[1] * s.abs());
        let half_y = 0.5 * (size[0] * s.abs() + size[1] * c.abs());
        Self {
            x: state[0],
            extent: (state[1] - half_y, state[1] + half_y),
            rear: state[0] - half_x,
            front: state[0] + half_x,
            y: state[1],
            vx: state[3] * c,
        }
    }
}

/// The leader a follower reacts to at one sub-step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Leader {
    /// Another IDM vehicle (index into the traffic's vehicles).
    Vehicle(usize),
    /// The ego.
    Ego,
}

/// The IDM traffic of one run: every vehicle but the ego (agent i ↔ vehicle i − 1).
#[derive(Debug, Clone, PartialEq)]
pub struct IdmTraffic {
    /// The vehicles, agent order.
    pub vehicles: Vec<IdmVehicle>,
    /// Lane-boundary y, ascending `[L + 1]` (m).
    pub lane_bounds: Vec<f64>,
    /// The model.
    pub model: IdmModel,
    /// The intrusion rule.
    pub rule: IntrusionRule,
    /// The ego's (length, width) (m).
    pub ego_size: [f64; 2],
    /// Each lane's extent `[L]` (the scene's, `None` without extents).
    pub extents: Option<Vec<LaneExtent>>,
    /// How vehicles whose lane ends merge.
    pub lane_end: LaneEndMerge,
}

/// The index of the lane holding `y` (m) among `bounds` `[L + 1]`; the nearest lane outside
/// the road.
#[must_use]
pub fn lane_index(bounds: &[f64], y: f64) -> usize {
    let lanes = bounds.len() - 1;
    (1..lanes).take_while(|&k| y >= bounds[k]).count()
}

/// The highest logged speed (m/s) of `agent`: its last observed speed and every displacement
/// over one step of its history, and of its logged future while the log is valid.
#[must_use]
pub fn highest_logged_speed(sc: &Scenario, agent: usize) -> f64 {
    let mut best = sc.speed[agent];
    let mut prev = sc.position(agent, 0);
    let speed = |a: [f64; 2], b: [f64; 2]| (b[0] - a[0]).hypot(b[1] - a[1]) / DT;
    for t in 1..T_OBS {
        let p = sc.position(agent, t);
        best = best.max(speed(prev, p));
        prev = p;
    }
    for k in 1..=sc.n_future {
        let Some(p) = sc.future_at(agent, k) else {
            break;
        };
        best = best.max(speed(prev, p));
        prev = p;
    }
    best
}

impl IdmTraffic {
    /// The traffic of scene `sc` for the run with `seed`: every other vehicle at its last
    /// observed position and speed, in the lane of its centre, with a driver drawn from the
    /// rows of the scene's source ([`IdmPopulation::rows_for`]) and a yield draw; the ego
    /// counts as being in the lane of its centre.
    #[must_use]
    pub fn new(sc: &Scenario, population: &IdmPopulation, seed: u64) -> Self {
        let rows = population.rows_for(DriverSource::of_scene(sc));
        let ego_lane = lane_index(&sc.lane_bounds, sc.position(0, T_OBS - 1)[1]);
        let vehicles = (1..sc.n_agents)
            .map(|i| {
                let p = sc.position(i, T_OBS - 1);
                let row = rows[(draw(seed, i, 1) % rows.len() as u64) as usize];
                let driver = population.drivers[row];
                let lane = lane_index(&sc.lane_bounds, p[1]);
                IdmVehicle {
                    x: p[0],
                    y: p[1],
                    v: sc.speed[i],
                    length: sc.size[i][0],
                    width: sc.size[i][1],
                    lane,
                    driver,
                    v0: driver.v0_ratio * highest_logged_speed(sc, i).max(V_REF_MIN),
                    yields: uniform(seed, i, 2) < population.intrusion.p_yield,
                    ego_in_lane: lane == ego_lane,
                    merging_to: None,
                }
            })
            .collect();
        Self {
            vehicles,
            lane_bounds: sc.lane_bounds.clone(),
            model: population.model,
            rule: population.intrusion,
            ego_size: sc.size[0],
            extents: sc.lane_extents.clone(),
            lane_end: population.lane_end,
        }
    }

    /// The real end (x, m) of vehicle `f`'s lane while it has not changed lanes and the lane
    /// really ends; `None` otherwise.
    fn lane_end_of(&self, f: usize) -> Option<f64> {
        let v = &self.vehicles[f];
        let e = self.extents.as_ref()?.get(v.lane)?;
        (v.merging_to.is_none() && e.ends).then_some(e.end)
    }

    /// The lane vehicle `f` merges into: of the adjacent lanes, those open at its x (begun,
    /// not ended) that do not end before its own lane, the one that runs on longest (the
    /// lower index on ties); `None` when there is none.
    fn merge_target(&self, f: usize, own_end: f64) -> Option<usize> {
        let ext = self.extents.as_ref()?;
        let v = &self.vehicles[f];
        let runs_to = |e: &LaneExtent| if e.ends { e.end } else { f64::INFINITY };
        let mut best: Option<(usize, f64)> = None;
        for j in [v.lane.checked_sub(1), Some(v.lane + 1)]
            .into_iter()
            .flatten()
        {
            let Some(e) = ext.get(j) else { continue };
            let open = !((e.begins && v.x < e.begin) || (e.ends && v.x > e.end));
            let outlasts = !e.ends || e.end >= own_end;
            if open && outlasts && best.is_none_or(|(_, run)| runs_to(e) > run) {
                best = Some((j, runs_to(e)));
            }
        }
        best.map(|(j, _)| j)
    }

    /// Whether vehicle `f` may change into lane `target` now with the ego seen as `ego`
    /// ([`LaneEndMerge::acceptable`]): the nearest vehicle (or the ego, by the lane of its
    /// centre) behind and ahead of it in that lane.
    fn may_merge(&self, f: usize, target: usize, ego: &EgoView) -> bool {
        let me = &self.vehicles[f];
        let (rear, front) = (me.x - 0.5 * me.length, me.x + 0.5 * me.length);
        let mut ahead: Option<(f64, f64)> = None;
        let mut behind: Option<(&IdmDriver, f64, f64, f64)> = None;
        for (j, o) in self.vehicles.iter().enumerate() {
            if j == f || o.lane != target {
                continue;
            }
            if o.x >= me.x {
                let gap = o.x - 0.5 * o.length - front;
                if ahead.is_none_or(|(g, _)| gap < g) {
                    ahead = Some((gap, o.v));
                }
            } else {
                let gap = rear - (o.x + 0.5 * o.length);
                if behind.is_none_or(|(_, _, _, g)| gap < g) {
                    behind = Some((&o.driver, o.v, o.v0, gap));
                }
            }
        }
        if lane_index(&self.lane_bounds, ego.y) == target {
            if ego.x >= me.x {
                let gap = ego.rear - front;
                if ahead.is_none_or(|(g, _)| gap < g) {
                    ahead = Some((gap, ego.vx));
                }
            } else {
                // The ego as a follower, judged with the merging vehicle's own driver.
                let gap = rear - ego.front;
                if behind.is_none_or(|(_, _, _, g)| gap < g) {
                    behind = Some((&me.driver, ego.vx.max(0.0), me.v0, gap));
                }
            }
        }
        self.lane_end
            .acceptable(&self.model, (&me.driver, me.v, me.v0), behind, ahead)
    }

    /// The lane-end decisions of one sub-step, from the states at its start: every vehicle in
    /// a lane that really ends, within `zone_m` of the end, with an acceptable gap in the lane
    /// it merges into, changes into it (its lane and target y set).
    fn decide_lane_end_merges(&mut self, ego: &EgoView) {
        if self.extents.is_none() {
            return;
        }
        let changes: Vec<(usize, usize)> = (0..self.vehicles.len())
            .filter_map(|f| {
                let end = self.lane_end_of(f)?;
                if end - self.vehicles[f].x > self.lane_end.zone_m {
                    return None;
                }
                let target = self.merge_target(f, end)?;
                self.may_merge(f, target, ego).then_some((f, target))
            })
            .collect();
        for (f, target) in changes {
            let centre = 0.5 * (self.lane_bounds[target] + self.lane_bounds[target + 1]);
            let v = &mut self.vehicles[f];
            v.lane = target;
            v.merging_to = Some(centre);
        }
    }

    /// The standing leader a vehicle's lane end makes (gap (m), speed 0) while its lane really
    /// ends ahead of its centre: `stop_margin_m` before the end.
    fn lane_end_leader(&self, f: usize) -> Option<(f64, f64)> {
        let end = self.lane_end_of(f)?;
        let v = &self.vehicles[f];
        (v.x <= end).then(|| {
            let stop = end - self.lane_end.stop_margin_m;
            (stop - (v.x + 0.5 * v.length), 0.0)
        })
    }

    /// Updates whether each vehicle counts the ego, seen as `ego`, as being in its lane
    /// ([`IntrusionRule::reacts`]).
    pub fn observe_ego(&mut self, ego: &EgoView) {
        for v in &mut self.vehicles {
            let lane = (self.lane_bounds[v.lane], self.lane_bounds[v.lane + 1]);
            v.ego_in_lane = self.rule.reacts(lane, ego.extent, v.yields, v.ego_in_lane);
        }
    }

    /// The leader of vehicle `f` with the ego seen as `ego` (counted as in its lane as last
    /// observed, [`IdmTraffic::observe_ego`]), and the gap (m) and speed (m/s) it is followed
    /// at; `None` on a free road.
    #[must_use]
    pub fn leader(&self, f: usize, ego: &EgoView) -> Option<(Leader, f64, f64)> {
        let me = &self.vehicles[f];
        let front = me.x + 0.5 * me.length;
        let mut best: Option<(Leader, f64, f64)> = None;
        let mut consider = |who: Leader, gap: f64, v: f64| {
            if best.is_none_or(|(_, g, _)| gap < g) {
                best = Some((who, gap, v));
            }
        };
        for (j, o) in self.vehicles.iter().enumerate() {
            let side_by_side = (o.y - me.y).abs() < 0.5 * (o.width + me.width);
            if j != f && (o.lane == me.lane || side_by_side) && o.x > me.x {
                consider(Leader::Vehicle(j), o.x - 0.5 * o.length - front, o.v);
            }
        }
        if ego.x > me.x && me.ego_in_lane {
            consider(Leader::Ego, ego.rear - front, ego.vx);
        }
        best
    }

    /// One sub-step of `dt` seconds with the ego seen as `ego`: the lane-end merges decided
    /// ([`LaneEndMerge`]), whether each vehicle counts the ego in its lane, every vehicle's
    /// acceleration from the current states (behind the nearer of its leader and its lane's
    /// end), then the ballistic update of all (and the lateral move of a merging one).
    pub fn substep(&mut self, ego: &EgoView, dt: f64) {
        self.decide_lane_end_merges(ego);
        self.observe_ego(ego);
        let leaders: Vec<Option<(f64, f64)>> = (0..self.vehicles.len())
            .map(|f| {
                let lead = self.leader(f, ego).map(|(_, s, v)| (s, v));
                match (lead, self.lane_end_leader(f)) {
                    (Some(l), Some(end)) => Some(if end.0 < l.0 { end } else { l }),
                    (l, end) => l.or(end),
                }
            })
            .collect();
        let lateral = self.lane_end.lateral_speed_mps * dt;
        for (veh, lead) in self.vehicles.iter_mut().zip(leaders) {
            let a = self.model.accel(&veh.driver, veh.v, veh.v0, lead);
            let v_next = (veh.v + a * dt).max(0.0);
            veh.x += 0.5 * (veh.v + v_next) * dt;
            veh.v = v_next;
            if let Some(y) = veh.merging_to {
                veh.y += (y - veh.y).clamp(-lateral, lateral);
            }
        }
    }

    /// One closed-loop step (0.3 s in [`SUBSTEPS`] sub-steps of [`SUB_DT`]) while the ego
    /// moves linearly from `ego_from` to `ego_to` (x, y, ψ, v); returns every vehicle's new
    /// centre `[n − 1]`.
    pub fn step(&mut self, ego_from: &State, ego_to: &State) -> Vec<[f64; 2]> {
        for j in 0..SUBSTEPS {
            let w = j as f64 / SUBSTEPS as f64;
            let at = |k: usize| ego_from[k] + (ego_to[k] - ego_from[k]) * w;
            let view = EgoView::new([at(0), at(1), at(2), at(3)], self.ego_size);
            self.substep(&view, SUB_DT);
        }
        self.vehicles.iter().map(|v| [v.x, v.y]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ASSETS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets");

    fn model() -> IdmModel {
        IdmModel {
            delta: 4.0,
            max_decel: 9.0,
            gap_floor: 0.01,
        }
    }

    fn driver() -> IdmDriver {
        IdmDriver {
            t: 1.2,
            s0: 2.0,
            a_max: 1.5,
            b: 2.0,
            v0_ratio: 1.0,
        }
    }

    fn vehicle(x: f64, y: f64, v: f64, lane: usize, v0: f64, yields: bool) -> IdmVehicle {
        IdmVehicle {
            x,
            y,
            v,
            length: 4.0,
            width: 1.8,
            lane,
            driver: driver(),
            v0,
            yields,
            ego_in_lane: false,
            merging_to: None,
        }
    }

    fn traffic(vehicles: Vec<IdmVehicle>) -> IdmTraffic {
        IdmTraffic {
            vehicles,
            lane_bounds: vec![-1.75, 1.75, 5.25],
            model: model(),
            rule: IntrusionRule {
                threshold_m: 0.7,
                p_yield: 0.7,
            },
            ego_size: [4.0, 1.8],
            extents: None,
            lane_end: LaneEndMerge::default(),
        }
    }

    /// An ego far behind everyone in lane 1 (never a leader of anyone in lane 0).
    fn far_ego() -> State {
        State::new(-1000.0, 3.5, 0.0, 0.0)
    }

    /// The same ego as the others see it.
    fn far_view() -> EgoView {
        EgoView::new([-1000.0, 3.5, 0.0, 0.0], [4.0, 1.8])
    }

    #[test]
    fn follower_settles_at_the_analytic_equilibrium_gap() {
        // A leader at constant speed (v0 = its speed: zero free-road acceleration) and a
        // follower that starts too close and too slow: it converges to s_e(v_lead).
        let v = 12.0;
        let mut t = traffic(vec![
            vehicle(100.0, 0.0, v, 0, v, true),
            vehicle(80.0, 0.0, 8.0, 0, 30.0, true),
        ]);
        let v0 = 30.0;
        let ego = far_ego();
        for _ in 0..2000 {
            t.step(&ego, &ego);
        }
        let lead = t.vehicles[0];
        let fol = t.vehicles[1];
        assert!((lead.v - v).abs() < 1e-12, "the leader keeps its speed");
        let gap = lead.x - 0.5 * lead.length - (fol.x + 0.5 * fol.length);
        let expected = model().equilibrium_gap(&driver(), v, v0);
        assert!((fol.v - v).abs() < 1e-6, "follower speed {}", fol.v);
        assert!(
            (gap - expected).abs() < 1e-4,
            "gap {gap} vs equilibrium {expected}"
        );
        // Free road: the IDM acceleration of the analytic formula.
        let a = model().accel(&driver(), 10.0, 20.0, None);
        assert!((a - 1.5 * (1.0 - 0.5_f64.powi(4))).abs() < 1e-15);
        // Closing in fast on a stopped leader: floored at the braking limit.
        assert_eq!(model().accel(&driver(), 30.0, 30.0, Some((1.0, 0.0))), -9.0);
    }

    /// The shared case with the Python model the drivers were fitted with
    /// (`python -m nudge_train.idm.golden`): a platoon of three on one lane, the leader slowing
    /// down on a free road; every position and speed after each 0.3 s step agrees to 1e-9.
    #[test]
    fn platoon_matches_the_python_model() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/golden/idm_platoon.json");
        let g: Value =
            serde_json::from_str(&std::fs::read_to_string(path).expect("golden")).expect("json");
        let num = |v: &Value| v.as_f64().expect("number");
        let model = IdmModel {
            delta: num(&g["delta"]),
            max_decel: num(&g["max_decel"]),
            gap_floor: num(&g["gap_floor"]),
        };
        assert_eq!(num(&g["dt"]), SUB_DT);
        assert!((SUB_DT * SUBSTEPS as f64 - DT).abs() < 1e-12);
        let cars = g["vehicles"].as_array().expect("vehicles");
        let mut t = traffic(
            cars.iter()
                .map(|c| {
                    let length = num(&c["length"]);
                    IdmVehicle {
                        x: num(&c["front"]) - 0.5 * length,
                        y: 0.0,
                        v: num(&c["v"]),
                        length,
                        width: 1.8,
                        lane: 0,
                        driver: IdmDriver {
                            t: num(&c["T"]),
                            s0: num(&c["s0"]),
                            a_max: num(&c["a_max"]),
                            b: num(&c["b"]),
                            v0_ratio: 1.0,
                        },
                        v0: num(&c["v0"]),
                        yields: true,
                        ego_in_lane: false,
                        merging_to: None,
                    }
                })
                .collect(),
        );
        t.model = model;
        let ego = far_ego();
        let mut worst: f64 = 0.0;
        for k in 1..=30 {
            let moved = t.step(&ego, &ego);
            for (i, c) in cars.iter().enumerate() {
                let x = num(&c["x_front"][SUBSTEPS * k]);
                let v = num(&c["speed"][SUBSTEPS * k]);
                let front = moved[i][0] + 0.5 * t.vehicles[i].length;
                worst = worst
                    .max((front - x).abs())
                    .max((t.vehicles[i].v - v).abs());
            }
        }
        assert!(worst < 1e-9, "largest difference {worst}");
        // The case is not trivial: the leader slowed down by several m/s.
        assert!(t.vehicles[0].v < 11.0);
    }

    #[test]
    fn intrusion_rule_switches_leader_by_threshold_or_full_entry() {
        // Follower in lane 0 ([-1.75, 1.75]) at x = 0 behind a vehicle 40 m ahead; the ego
        // 15 m ahead moves from lane 1 into lane 0 and back out.
        for yields in [true, false] {
            let mut t = traffic(vec![
                vehicle(40.0, 0.0, 10.0, 0, 12.0, true),
                vehicle(0.0, 0.0, 10.0, 0, 12.0, yields),
            ]);
            let mut leader_at = |y: f64| {
                let ego = EgoView::new([15.0, y, 0.0, 10.0], [4.0, 1.8]);
                t.observe_ego(&ego);
                t.leader(1, &ego).map(|(l, _, _)| l)
            };
            // The ego's nearest edge (y − 0.9) 0.5 m inside the line at 1.75: below the
            // threshold; 1.0 m inside: beyond it; y = 0.8: wholly inside; 2.66: wholly out.
            let (short, beyond, inside, out) = (1.75 - 0.5 + 0.9, 1.75 - 1.0 + 0.9, 0.8, 2.66);
            let ego_if_yields = if yields {
                Leader::Ego
            } else {
                Leader::Vehicle(0)
            };
            assert_eq!(leader_at(short), Some(Leader::Vehicle(0)));
            assert_eq!(leader_at(beyond), Some(ego_if_yields), "yields {yields}");
            assert_eq!(leader_at(inside), Some(Leader::Ego));
            // Counted once, the ego stays a leader while it overlaps the lane at all ...
            assert_eq!(leader_at(short), Some(Leader::Ego));
            // ... until it is wholly out; coming back, the rule applies again.
            assert_eq!(leader_at(out), Some(Leader::Vehicle(0)));
            assert_eq!(leader_at(short), Some(Leader::Vehicle(0)));
            // An ego behind the follower is never its leader.
            let behind = EgoView::new([-15.0, 0.0, 0.0, 10.0], [4.0, 1.8]);
            t.observe_ego(&behind);
            assert_eq!(t.leader(1, &behind).map(|l| l.0), Some(Leader::Vehicle(0)));
        }
    }

    #[test]
    fn an_ego_starting_in_a_lane_leads_its_followers_even_across_a_line() {
        // A non-yielding follower whose lane holds the ego's centre at the start follows the
        // ego although the ego's box already crosses the lane line (a wide vehicle).
        let mut t = traffic(vec![vehicle(0.0, 0.0, 10.0, 0, 12.0, false)]);
        t.vehicles[0].ego_in_lane = true;
        let ego = EgoView::new([15.0, 0.6, 0.0, 10.0], [5.0, 2.6]);
        assert!(ego.extent.1 > 1.75, "the ego crosses the line");
        t.substep(&ego, 0.1);
        assert_eq!(t.leader(0, &ego).map(|l| l.0), Some(Leader::Ego));
        // Without that start, the same follower ignores it until it is wholly inside.
        let mut fresh = traffic(vec![vehicle(0.0, 0.0, 10.0, 0, 12.0, false)]);
        fresh.substep(&ego, 0.1);
        assert_eq!(fresh.leader(0, &ego), None);
        // Another vehicle whose box overlaps the follower's across the road leads it although
        // its centre is in the next lane.
        let t = traffic(vec![
            vehicle(0.0, 1.0, 10.0, 0, 12.0, true),
            vehicle(20.0, 2.5, 10.0, 1, 12.0, true),
        ]);
        assert_eq!(
            t.leader(0, &far_view()).map(|l| l.0),
            Some(Leader::Vehicle(1))
        );
    }

    #[test]
    fn the_gap_to_the_ego_is_to_its_rotated_rear() {
        let mut t = traffic(vec![vehicle(0.0, 0.0, 10.0, 0, 12.0, true)]);
        let psi: f64 = 0.2;
        let ego = EgoView::new([20.0, 0.0, psi, 10.0], [4.0, 1.8]);
        t.observe_ego(&ego);
        let (who, gap, v) = t.leader(0, &ego).expect("the ego leads");
        assert_eq!(who, Leader::Ego);
        let half = 0.5 * (4.0 * psi.cos() + 1.8 * psi.sin());
        assert!((gap - (20.0 - half - 2.0)).abs() < 1e-12);
        assert!((v - 10.0 * psi.cos()).abs() < 1e-12);
    }

    #[test]
    fn lanes_of_positions() {
        let b = [-1.75, 1.75, 5.25, 8.75];
        assert_eq!(lane_index(&b, 0.0), 0);
        assert_eq!(lane_index(&b, -5.0), 0);
        assert_eq!(lane_index(&b, 1.75), 1);
        assert_eq!(lane_index(&b, 6.0), 2);
        assert_eq!(lane_index(&b, 20.0), 2);
    }

    #[test]
    fn shipped_population_parses_and_draws_are_seeded() {
        let pop = IdmPopulation::from_file(idm_path(Path::new(ASSETS))).expect("shipped file");
        assert_eq!(pop.drivers.len(), pop.sources.len());
        assert!((pop.intrusion.threshold_m - 0.7).abs() < 1e-12);
        assert!((pop.model.delta - 4.0).abs() < 1e-12);
        let us = pop.rows_for(Some(DriverSource::Us101));
        assert!(!us.is_empty() && us.len() < pop.drivers.len());
        assert!(us.iter().all(|&i| pop.sources[i] == DriverSource::Us101));
        let sc = Scenario::from_file(
            Path::new(ASSETS).join("scenes/us101-11_1-t02.1-ego144.safetensors"),
        )
        .expect("shipped scene");
        assert_eq!(DriverSource::of_scene(&sc), Some(DriverSource::Us101));
        let a = IdmTraffic::new(&sc, &pop, 7);
        assert_eq!(a, IdmTraffic::new(&sc, &pop, 7));
        let b = IdmTraffic::new(&sc, &pop, 8);
        assert_ne!(a.vehicles, b.vehicles, "another seed draws other drivers");
        let ego_lane = lane_index(&sc.lane_bounds, sc.position(0, T_OBS - 1)[1]);
        for (i, v) in a.vehicles.iter().enumerate() {
            assert_eq!(v.ego_in_lane, v.lane == ego_lane);
            let row = pop
                .drivers
                .iter()
                .position(|d| *d == v.driver)
                .expect("a row");
            assert_eq!(pop.sources[row], DriverSource::Us101);
            let v_ref = highest_logged_speed(&sc, i + 1).max(V_REF_MIN);
            assert!(v_ref >= sc.speed[i + 1]);
            assert!((v.v0 - v.driver.v0_ratio * v_ref).abs() < 1e-12);
        }
        let yielding = (0..2000)
            .filter(|&k| uniform(11, k, 2) < pop.intrusion.p_yield)
            .count();
        assert!(
            (1250..1550).contains(&yielding),
            "p_yield 0.7: {yielding} of 2000"
        );
    }

    #[test]
    fn bad_files_name_the_field() {
        let text = std::fs::read_to_string(idm_path(Path::new(ASSETS))).expect("read");
        let good: Value = serde_json::from_str(&text).expect("json");
        type Edit = Box<dyn Fn(&mut Value)>;
        let cases: [(&str, Edit); 8] = [
            ("schema", Box::new(|v| v["schema"] = "nudge.idm/2".into())),
            ("units.s0", Box::new(|v| v["units"]["s0"] = "ft".into())),
            (
                "drivers[3][1]",
                Box::new(|v| v["drivers"][3][1] = 99.0.into()),
            ),
            (
                "drivers[0][4]",
                Box::new(|v| v["drivers"][0][4] = "fast".into()),
            ),
            (
                "driver_sources[2]",
                Box::new(|v| v["driver_sources"][2] = "a1".into()),
            ),
            (
                "intrusion.p_yield",
                Box::new(|v| v["intrusion"]["p_yield"] = 1.5.into()),
            ),
            (
                "model.delta",
                Box::new(|v| v["model"]["delta"] = (-4.0).into()),
            ),
            (
                "bounds.T",
                Box::new(|v| v["bounds"]["T"] = serde_json::json!([3.0, 0.3])),
            ),
        ];
        for (field, edit) in cases {
            let mut v = good.clone();
            edit(&mut v);
            match IdmPopulation::from_json(&v.to_string(), Path::new("w.json")) {
                Err(WorldFileError::Field { field: f, path, .. }) => {
                    assert_eq!((f.as_str(), path.as_path()), (field, Path::new("w.json")));
                }
                other => panic!("{field}: expected a field error, got {other:?}"),
            }
        }
        assert!(matches!(
            IdmPopulation::from_json("{", Path::new("w.json")),
            Err(WorldFileError::NotJson { .. })
        ));
        assert!(matches!(
            IdmPopulation::from_file("/nonexistent/idm.json"),
            Err(WorldFileError::Io { .. })
        ));
    }

    /// Issue 49 class 11: drivers are checked against physical plausibility in code, not only
    /// against the bounds the same file declares (before: a file declaring wide bounds loaded
    /// absurd drivers); unknown and repeated keys are refused by name.
    #[test]
    fn world_files_are_checked_against_bounds_in_code_and_their_keys() {
        let text = std::fs::read_to_string(idm_path(Path::new(ASSETS))).expect("read");
        let good: Value = serde_json::from_str(&text).expect("json");
        type Edit = Box<dyn Fn(&mut Value)>;
        let wide = |v: &mut Value| {
            for name in PARAMETER_NAMES {
                v["bounds"][name] = serde_json::json!([1e-3, 1e3]);
            }
        };
        let cases: Vec<(&str, Edit)> = vec![
            // The file's own box wider than plausible: refused at the box.
            ("bounds.T", Box::new(move |v| wide(v))),
            // Absurd drivers inside an absurd box: refused at the first.
            (
                "bounds.a_max",
                Box::new(|v| {
                    v["bounds"]["a_max"] = serde_json::json!([0.3, 60.0]);
                    v["drivers"][0][2] = 50.0.into();
                }),
            ),
            (
                "model.max_decel_mps2",
                Box::new(|v| v["model"]["max_decel_mps2"] = 900.0.into()),
            ),
            (
                "model.delta",
                Box::new(|v| v["model"]["delta"] = 1e6.into()),
            ),
            (
                "intrusion.threshold_m",
                Box::new(|v| v["intrusion"]["threshold_m"] = 1e9.into()),
            ),
            ("drivers_typo", Box::new(|v| v["drivers_typo"] = 1.into())),
            (
                "model.deltaa",
                Box::new(|v| v["model"]["deltaa"] = 4.into()),
            ),
            ("units.foo", Box::new(|v| v["units"]["foo"] = "m".into())),
            (
                "bounds.extra",
                Box::new(|v| v["bounds"]["extra"] = serde_json::json!([1, 2])),
            ),
            (
                "intrusion.p_yeld",
                Box::new(|v| v["intrusion"]["p_yeld"] = 0.5.into()),
            ),
        ];
        for (field, edit) in cases {
            let mut v = good.clone();
            edit(&mut v);
            match IdmPopulation::from_json(&v.to_string(), Path::new("w.json")) {
                Err(WorldFileError::Field { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: expected a field error, got {other:?}"),
            }
        }
        // A repeated key: serde_json alone keeps the last one.
        let dup = text.replacen("\"schema\"", "\"schema\": \"nudge.idm/1\", \"schema\"", 1);
        assert_ne!(dup, text);
        match IdmPopulation::from_json(&dup, Path::new("w.json")) {
            Err(WorldFileError::NotJson { reason, .. }) => {
                assert!(reason.contains("duplicate key `schema`"), "{reason}");
            }
            other => panic!("expected a duplicate-key refusal, got {other:?}"),
        }
        // The shipped file's own box lies inside the plausible ranges.
        for (k, name) in PARAMETER_NAMES.iter().enumerate() {
            let (lo, hi) = PLAUSIBLE[k];
            let b = &good["bounds"][name];
            let (flo, fhi) = (b[0].as_f64().expect("lo"), b[1].as_f64().expect("hi"));
            assert!(lo <= flo && fhi <= hi, "{name}");
        }
    }

    /// Issue 49 class 2: the world file is opened by the one checked-open routine: a FIFO is
    /// refused without blocking (before: read forever), `/dev/zero` without reading (before:
    /// read until memory ran out), a file above [`MAX_WORLD_BYTES`] by its size; each a typed
    /// error naming the file.
    #[cfg(unix)]
    #[test]
    fn fifo_device_and_huge_world_files_are_refused_by_name() {
        let dir = std::env::temp_dir().join(format!("nudge-world-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let fifo = dir.join("idm.fifo");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .expect("mkfifo");
        assert!(made.success());
        let (tx, rx) = std::sync::mpsc::channel();
        let f = fifo.clone();
        std::thread::spawn(move || {
            let _ = tx.send(IdmPopulation::from_file(&f));
        });
        let got = rx
            .recv_timeout(std::time::Duration::from_secs(10))
            .expect("reading a FIFO world file blocked");
        match got {
            Err(WorldFileError::NotRegularFile { path, kind }) => {
                assert_eq!((path.as_path(), kind), (fifo.as_path(), "a FIFO"));
            }
            other => panic!("expected NotRegularFile, got {other:?}"),
        }
        let e = IdmPopulation::from_file("/dev/zero").expect_err("device");
        assert!(
            matches!(
                &e,
                WorldFileError::NotRegularFile {
                    kind: "a character device",
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("/dev/zero"), "{e}");
        let big = dir.join("big.json");
        let file = std::fs::File::create(&big).expect("create");
        file.set_len(MAX_WORLD_BYTES + 1).expect("set_len");
        match IdmPopulation::from_file(&big) {
            Err(WorldFileError::TooLarge { path, size, max }) => {
                assert_eq!(
                    (path, size, max),
                    (big.clone(), MAX_WORLD_BYTES + 1, MAX_WORLD_BYTES)
                );
            }
            other => panic!("expected TooLarge, got {other:?}"),
        }
        std::fs::remove_dir_all(&dir).expect("clean");
    }

    /// Lane 0 (y in [-1.75, 1.75]) really ends at x = 300; lane 1 runs on.
    fn ending(vehicles: Vec<IdmVehicle>) -> IdmTraffic {
        let e = |end, ends| LaneExtent {
            begin: -1000.0,
            end,
            begins: false,
            ends,
        };
        IdmTraffic {
            extents: Some(vec![e(300.0, true), e(5000.0, false)]),
            ..traffic(vehicles)
        }
    }

    #[test]
    fn the_safety_criterion_is_the_new_followers_idm_deceleration() {
        let (m, d, rule) = (model(), driver(), LaneEndMerge::default());
        let own = (&d, 20.0, 25.0);
        assert!(rule.acceptable(&m, own, None, None), "an empty lane");
        // A follower at 25 m/s behind a merger at 20 m/s: its IDM acceleration decides.
        let a = |gap: f64| m.accel(&d, 25.0, 25.0, Some((gap, 20.0)));
        let (lo, hi) = (10.0_f64, 200.0_f64);
        assert!(a(lo) < -rule.b_safe_mps2 && a(hi) > -rule.b_safe_mps2);
        // The gap where it brakes at exactly b_safe, by bisection on the model itself.
        let (mut l, mut h) = (lo, hi);
        for _ in 0..100 {
            let mid = 0.5 * (l + h);
            if a(mid) < -rule.b_safe_mps2 {
                l = mid
            } else {
                h = mid
            }
        }
        let f = |gap| Some((&d, 25.0, 25.0, gap));
        assert!(rule.acceptable(&m, own, f(h + 1e-6), None));
        assert!(!rule.acceptable(&m, own, f(l - 1e-6), None));
        // The merger's own braking behind a slow new leader counts too, and so does min_gap.
        assert!(!rule.acceptable(&m, own, None, Some((3.0, 0.0))));
        assert!(rule.acceptable(&m, own, None, Some((80.0, 20.0))));
        assert!(
            !rule.acceptable(&m, (&d, 0.0, 25.0), None, Some((1.0, 30.0))),
            "min_gap"
        );
    }

    #[test]
    fn a_vehicle_whose_lane_ends_merges_into_a_free_lane() {
        let mut t = ending(vec![vehicle(200.0, 0.0, 15.0, 0, 15.0, true)]);
        let ego = far_ego();
        let mut merged_at = None;
        for k in 0..200 {
            t.step(&ego, &ego);
            let v = &t.vehicles[0];
            if v.lane == 1 && merged_at.is_none() {
                merged_at = Some((k, v.x));
            }
            // Never past the end in the ended lane (by its centre's y).
            assert!(
                v.x <= 300.0 || lane_index(&t.lane_bounds, v.y) == 1,
                "{v:?}"
            );
        }
        // Inside the zone from the start (100 m before the end), with a free lane: at once.
        assert_eq!(merged_at.map(|(k, _)| k), Some(0));
        // A vehicle farther back waits until it enters the zone (200 m before the end).
        let mut far = ending(vec![vehicle(0.0, 0.0, 15.0, 0, 15.0, true)]);
        let mut decided = None;
        for _ in 0..40 {
            let x = far.vehicles[0].x;
            far.step(&ego, &ego);
            if far.vehicles[0].lane == 1 && decided.is_none() {
                decided = Some(x);
            }
        }
        let x = decided.expect("merged");
        assert!(
            (95.0..=100.0).contains(&x),
            "decided in the step from x = {x}"
        );
        let v = &t.vehicles[0];
        assert!((v.y - 3.5).abs() < 1e-12 && v.x > 400.0, "{v:?}");
    }

    #[test]
    fn a_vehicle_without_an_acceptable_gap_stops_at_its_lane_end() {
        // A dense platoon in lane 1 at 15 m/s, 7 m apart, from x = -300 to 400: no gap.
        let mut cars = vec![vehicle(200.0, 0.0, 15.0, 0, 15.0, true)];
        let mut x = -300.0;
        while x <= 400.0 {
            cars.push(vehicle(x, 3.5, 15.0, 1, 15.0, true));
            x += 7.0;
        }
        let mut t = ending(cars);
        let ego = far_ego();
        for _ in 0..60 {
            t.step(&ego, &ego);
            let v = &t.vehicles[0];
            assert_eq!((v.lane, v.y), (0, 0.0), "no change without a gap");
            assert!(v.x + 0.5 * v.length <= 300.0 - 2.0 + 1e-9, "{v:?}");
        }
        let v = &t.vehicles[0];
        assert!(v.v < 0.1 && v.x > 280.0, "stopped at the end: {v:?}");
    }

    #[test]
    fn lane_end_merges_are_deterministic_and_leave_other_scenes_alone() {
        let cars = || {
            let mut c = vec![vehicle(150.0, 0.0, 18.0, 0, 20.0, true)];
            for k in 0..12 {
                c.push(vehicle(
                    -100.0 + 25.0 * f64::from(k),
                    3.5,
                    15.0,
                    1,
                    16.0,
                    k % 2 == 0,
                ));
            }
            c
        };
        let ego = far_ego();
        let run = |mut t: IdmTraffic| (0..80).map(|_| t.step(&ego, &ego)).collect::<Vec<_>>();
        assert_eq!(run(ending(cars())), run(ending(cars())));
        // Without extents (or with ends that are not real) nothing changes lanes.
        let mut open = ending(cars());
        if let Some(e) = &mut open.extents {
            e[0].ends = false;
        }
        assert_eq!(run(open), run(traffic(cars())));
    }

    #[test]
    fn lane_end_settings_default_validate_and_parse() {
        let d = LaneEndMerge::default();
        d.validate().expect("ok");
        let back: LaneEndMerge =
            serde_json::from_str(&serde_json::to_string(&d).expect("ok")).expect("ok");
        assert_eq!(back, d);
        for (field, value) in [
            ("b_safe_mps2", 0.0),
            ("lateral_speed_mps", -1.0),
            ("zone_m", f64::NAN),
        ] {
            let mut bad = d;
            match field {
                "b_safe_mps2" => bad.b_safe_mps2 = value,
                "lateral_speed_mps" => bad.lateral_speed_mps = value,
                _ => bad.zone_m = value,
            }
            let err = bad.validate().expect_err("refused").to_string();
            assert!(err.contains(field), "{err}");
        }
        // In the world file: absent, the defaults; a bad value names the field.
        let text = std::fs::read_to_string(idm_path(Path::new(ASSETS))).expect("ok");
        let p = IdmPopulation::from_json(&text, Path::new("idm.json")).expect("ok");
        assert_eq!(p.lane_end, d);
        let mut v: Value = serde_json::from_str(&text).expect("ok");
        v["lane_end"] = serde_json::json!({"b_safe_mps2": 3.0});
        let p = IdmPopulation::from_json(&v.to_string(), Path::new("idm.json")).expect("ok");
        assert_eq!(p.lane_end.b_safe_mps2, 3.0);
        v["lane_end"] = serde_json::json!({"b_safe_mps2": -3.0});
        let err =
            IdmPopulation::from_json(&v.to_string(), Path::new("idm.json")).expect_err("refused");
        assert!(err.to_string().contains("lane_end.b_safe_mps2"), "{err}");
        v["lane_end"] = serde_json::json!({"bogus": 1.0});
        let err =
            IdmPopulation::from_json(&v.to_string(), Path::new("idm.json")).expect_err("refused");
        assert!(err.to_string().contains("lane_end"), "{err}");
    }
}
