//! # nudge-fuzz
//!
//! Structure-aware mutation fuzzing of nudge's input files (weights, scenarios, settings,
//! CommonRoad scenarios and the solutions written from them, IDM world files) and planning
//! problems. Not published: a development tool of the workspace, run by `make fuzz`
//! (the `nudge-fuzz` binary, `src/main.rs`) and, in its short mode, by `make test`
//! (`tests/short_mode.rs`).
//!
//! Every try takes a valid seed input, applies one to three mutations drawn from a seeded
//! generator (try `i` of target `T` under seed `s` is reproducible on its own: `--replay`), and
//! judges the outcome with the target's oracle:
//!
//! * a typed error (counted by kind), or
//! * an accepted input that is valid: weights whose network predicts finite, plausible
//!   positions on three scenes (every Ok prediction is re-checked here); a scenario that
//!   passes an independent re-check of the plausibility ranges and on which a short closed
//!   loop and one MPC call return finite states equal to the roll-out of the plan's inputs;
//!   settings whose every field is in its documented range and with which one MPC call returns
//!   finite results; a planning problem (arbitrary ego state, inputs, target, road, sizes and
//!   histories, planned with constant velocity, the shipped student or teacher, or a foreign
//!   predictor that corrupts some of its predictions) that lies in the documented ranges of
//!   `PlanningProblem::check`, whose plan is finite and never reported safe on a safety value
//!   that is not a finite number above the threshold; a CommonRoad file whose values pass an
//!   independent re-check of the reader's ranges, and whose scene, scenario and solution (of
//!   random inputs) are typed errors or finite; an IDM world whose drivers lie in the physical
//!   ranges in code and whose short closed loop is finite (`src/surfaces.rs`);
//!
//! anything else is a defect: a panic (caught and counted), an accepted-but-invalid result, a
//! try running past the per-try limit (a watchdog stops the process naming the try), or a peak
//! RSS above the limit.
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    clippy::unwrap_used,
    clippy::cast_possible_truncation
)]

use std::collections::BTreeMap;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use nudge_planner::scenario::{
    EGO_LANE_TOLERANCE, LANE_WIDTH, MAX_HEADING, MAX_SPEED, ROAD_TOLERANCE,
};
use nudge_planner::{
    EgoState, PlanStatus, Planner, PlannerSettings, PlanningProblem, Scenario, State,
};
use nudge_predictor::limits::{MAX_STEP, canonical_scene};
use nudge_predictor::weights::{restamp, synthetic_weights};
use nudge_predictor::{
    ConstantVelocity, History, ModelConfig, ModelKind, ModelWeights, Predictor, Student, T_OBS,
    Teacher,
};
use nudge_sim::{SimConfig, World, WorldModel, simulate};

mod surfaces;

// ---------------------------------------------------------------------------------------------
// Configuration and report.
// ---------------------------------------------------------------------------------------------

/// The repository root, whose `assets/` hold the seed inputs: the directory above this crate's
/// (`fuzz/` sits at the root of the workspace).
#[must_use]
pub fn repo_root() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest.parent().unwrap_or(manifest).to_path_buf()
}

/// One fuzz target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Target {
    /// `.safetensors` weights files (ModelWeights → Teacher/Student).
    Weights,
    /// `.safetensors` scenario files (Scenario → closed loop, MPC call).
    Scenarios,
    /// Planner settings JSON (PlannerSettings → MPC call).
    Settings,
    /// Planning problems (PlanningProblem → `Planner::plan` with every predictor).
    Plan,
    /// CommonRoad scenario files (`RawScenario::read` → scene → scenario → solution writer).
    CommonRoad,
    /// IDM world files (`IdmPopulation::from_json` → a short IDM closed loop).
    World,
}

impl Target {
    /// Every target.
    pub const ALL: [Self; 6] = [
        Self::Weights,
        Self::Scenarios,
        Self::Settings,
        Self::Plan,
        Self::CommonRoad,
        Self::World,
    ];

    /// Name on the command line and in the report.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Weights => "weights",
            Self::Scenarios => "scenarios",
            Self::Settings => "settings",
            Self::Plan => "plan",
            Self::CommonRoad => "commonroad",
            Self::World => "world",
        }
    }

    fn id(self) -> u64 {
        self as u64 + 1
    }
}

/// What to run.
#[derive(Debug, Clone)]
pub struct Config {
    /// Master seed.
    pub seed: u64,
    /// Wall-clock budget per target (s; infinite: until `max_tries`).
    pub seconds_per_target: f64,
    /// Most tries per target (`None`: until the time budget is spent).
    pub max_tries: Option<u64>,
    /// Targets to run.
    pub targets: Vec<Target>,
    /// A try running longer than this is a hang (s): the process reports it and exits.
    pub try_limit_s: f64,
    /// A try running longer than this is counted as slow (s).
    pub slow_s: f64,
    /// Peak resident memory above this is a defect (MiB).
    pub rss_limit_mib: u64,
    /// Repository root (seed inputs are read from `assets/`).
    pub repo: PathBuf,
    /// Print each defect as it is found.
    pub verbose: bool,
    /// Count plans whose states are not the roll-out of their inputs as defects (the default:
    /// the planner guarantees it); otherwise they are counted apart.
    pub strict_rollout: bool,
}

impl Config {
    /// Tries per target of the short mode (about 6 s for the first four targets on one core of
    /// the 2-core development machine, plus the CommonRoad and world targets).
    pub const SHORT_TRIES: u64 = 400;

    /// The few-second mode CI runs inside `make test`: a fixed [`Self::SHORT_TRIES`] tries per
    /// target and no time budget, so every machine runs the same tries (with a time budget a
    /// faster machine reached tries a slower one never ran, and a hang went unseen locally).
    #[must_use]
    pub fn short(repo: PathBuf) -> Self {
        Self {
            seed: 0x5eed,
            seconds_per_target: f64::INFINITY,
            max_tries: Some(Self::SHORT_TRIES),
            targets: Target::ALL.to_vec(),
            try_limit_s: 60.0,
            slow_s: 5.0,
            rss_limit_mib: 2048,
            repo,
            verbose: true,
            strict_rollout: true,
        }
    }
}

/// Counts of one target.
#[derive(Debug, Default, Clone)]
pub struct Stats {
    /// Tries run.
    pub tries: u64,
    /// Typed errors by kind (error variant; a self-check failure shows its cause).
    pub errors: BTreeMap<String, u64>,
    /// Accepted inputs that passed the oracle.
    pub valid: u64,
    /// Accepted inputs whose later use gave a typed error (counted by kind).
    pub later_errors: BTreeMap<String, u64>,
    /// Panics caught.
    pub panics: u64,
    /// Accepted-but-invalid results.
    pub invalid: u64,
    /// Accepted, finite plans whose states are not the roll-out of their inputs.
    pub not_rollout: u64,
    /// Tries slower than `Config::slow_s`.
    pub slow: u64,
    /// Longest try (s).
    pub max_try_s: f64,
    /// Wall time (s).
    pub seconds: f64,
    /// The first defects found (target, try, what).
    pub defects: Vec<String>,
}

impl Stats {
    /// Panics plus accepted-but-invalid results.
    #[must_use]
    pub fn defect_count(&self) -> u64 {
        self.panics + self.invalid
    }
}

/// Counts of every target that ran, plus the peak RSS.
#[derive(Debug, Default, Clone)]
pub struct Report {
    /// Per target.
    pub targets: BTreeMap<Target, Stats>,
    /// Peak resident set size of the process (MiB), from `/proc/self/status` (0 elsewhere).
    pub peak_rss_mib: u64,
    /// Whether the peak RSS exceeded the limit.
    pub rss_exceeded: bool,
}

impl Report {
    /// Every defect of every target (panics, invalid results, memory).
    #[must_use]
    pub fn defects(&self) -> u64 {
        self.targets.values().map(Stats::defect_count).sum::<u64>() + u64::from(self.rss_exceeded)
    }

    /// The table printed at the end of a run.
    #[must_use]
    pub fn render(&self) -> String {
        let mut s = String::new();
        for (t, st) in &self.targets {
            s += &format!(
                "{}: {} tries in {:.1} s (longest {:.3} s, {} slow): {} typed errors, {} accepted and valid, \
                 {} accepted then refused later, {} panics, {} accepted but invalid; \
                 {} finite plans whose states are not the roll-out of their inputs\n",
                t.name(),
                st.tries,
                st.seconds,
                st.max_try_s,
                st.slow,
                st.errors.values().sum::<u64>(),
                st.valid,
                st.later_errors.values().sum::<u64>(),
                st.panics,
                st.invalid,
                st.not_rollout
            );
            for (k, n) in &st.errors {
                s += &format!("    error {k}: {n}\n");
            }
            for (k, n) in &st.later_errors {
                s += &format!("    later {k}: {n}\n");
            }
            for d in &st.defects {
                s += &format!("    DEFECT {d}\n");
            }
        }
        s += &format!(
            "peak RSS {} MiB{}\ndefects: {}\n",
            self.peak_rss_mib,
            if self.rss_exceeded {
                " (over the limit: DEFECT)"
            } else {
                ""
            },
            self.defects()
        );
        s
    }
}

// ---------------------------------------------------------------------------------------------
// Deterministic generator.
// ---------------------------------------------------------------------------------------------

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// splitmix64: deterministic, seedable, good enough to drive mutations.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// The generator of try `i` of `target` under `seed`.
    #[must_use]
    pub fn for_try(seed: u64, target: Target, i: u64) -> Self {
        Self(splitmix(seed ^ splitmix(target.id() << 40 ^ i)))
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        splitmix(self.0)
    }

    /// Uniform in `0..n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    fn pick<T: Copy>(&mut self, v: &[T]) -> T {
        v[self.below(v.len())]
    }

    /// A value a hostile file might hold: special, huge, tiny, ordinary.
    fn wild(&mut self) -> f64 {
        match self.below(10) {
            0 => self.pick(&[f64::NAN, f64::INFINITY, f64::NEG_INFINITY]),
            1 => self.pick(&[
                1e300,
                -1e300,
                1e154,
                3.4e38,
                -3.4e38,
                f64::MAX,
                f64::MIN_POSITIVE,
            ]),
            2 => self.pick(&[0.0, -0.0, 1.0, -1.0]),
            3 => 10f64.powf(self.range(-12.0, 40.0)) * self.pick(&[1.0, -1.0]),
            _ => self.range(-100.0, 100.0),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// safetensors surgery: header as JSON, data as bytes.
// ---------------------------------------------------------------------------------------------

/// A safetensors image split into its header JSON and data section.
struct Image {
    header: serde_json::Map<String, serde_json::Value>,
    data: Vec<u8>,
}

impl Image {
    fn parse(bytes: &[u8]) -> Option<Self> {
        let n = u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?) as usize;
        let text = bytes.get(8..8usize.checked_add(n)?)?;
        let header = serde_json::from_slice(text).ok()?;
        Some(Self {
            header,
            data: bytes[8 + n..].to_vec(),
        })
    }

    fn bytes(&self) -> Vec<u8> {
        let mut text = serde_json::to_vec(&self.header).unwrap();
        while !text.len().is_multiple_of(8) {
            text.push(b' ');
        }
        let mut out = (text.len() as u64).to_le_bytes().to_vec();
        out.extend(text);
        out.extend(&self.data);
        out
    }

    fn tensor_names(&self) -> Vec<String> {
        self.header
            .keys()
            .filter(|k| *k != "__metadata__")
            .cloned()
            .collect()
    }

    /// `(begin, end)` of a tensor's bytes in the data section.
    fn span(&self, name: &str) -> Option<(usize, usize)> {
        let off = self.header.get(name)?.get("data_offsets")?.as_array()?;
        let b = off.first()?.as_u64()? as usize;
        let e = off.get(1)?.as_u64()? as usize;
        (b <= e && e <= self.data.len()).then_some((b, e))
    }

    fn dtype(&self, name: &str) -> Option<&str> {
        self.header.get(name)?.get("dtype")?.as_str()
    }

    fn meta_mut(&mut self) -> &mut serde_json::Map<String, serde_json::Value> {
        self.header
            .entry("__metadata__")
            .or_insert_with(|| serde_json::json!({}))
            .as_object_mut()
            .unwrap()
    }

    /// Element `i` (wrapped) of an F32 or F64 tensor set to `v`.
    fn set_float(&mut self, name: &str, i: usize, v: f64) {
        let (Some((b, e)), Some(dt)) = (self.span(name), self.dtype(name).map(str::to_owned))
        else {
            return;
        };
        let w = if dt == "F64" { 8 } else { 4 };
        let n = (e - b) / w;
        if n == 0 {
            return;
        }
        let o = b + (i % n) * w;
        if w == 8 {
            self.data[o..o + 8].copy_from_slice(&v.to_le_bytes());
        } else {
            self.data[o..o + 4].copy_from_slice(&(v as f32).to_le_bytes());
        }
    }

    fn f64s(&self, name: &str) -> Vec<f64> {
        let Some((b, e)) = self.span(name) else {
            return Vec::new();
        };
        self.data[b..e]
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }

    fn set_f64s(&mut self, name: &str, v: &[f64]) {
        if let Some((b, e)) = self.span(name) {
            for (k, c) in self.data[b..e]
                .chunks_exact_mut(8)
                .enumerate()
                .take(v.len())
            {
                c.copy_from_slice(&v[k].to_le_bytes());
            }
        }
    }
}

/// Generic byte-level and header-level mutations shared by the file targets; returns what was
/// done (for replay output).
fn mutate_generic(rng: &mut Rng, bytes: &mut Vec<u8>) -> &'static str {
    match rng.below(5) {
        0 => {
            if !bytes.is_empty() {
                let i = rng.below(bytes.len());
                bytes[i] ^= 1 << rng.below(8);
            }
            "bit flip"
        }
        1 => {
            let n = rng.below(bytes.len() + 1);
            bytes.truncate(n);
            "truncation"
        }
        2 => {
            // Header length field.
            if bytes.len() >= 8 {
                let v: u64 = match rng.below(4) {
                    0 => u64::MAX,
                    1 => bytes.len() as u64,
                    2 => rng.next_u64() % 1_000_000,
                    _ => u64::from_le_bytes(bytes[..8].try_into().unwrap()) ^ (1 << rng.below(64)),
                };
                bytes[..8].copy_from_slice(&v.to_le_bytes());
            }
            "header length"
        }
        _ => {
            let Some(mut img) = Image::parse(bytes) else {
                return "header edit (unparsable)";
            };
            let names = img.tensor_names();
            if names.is_empty() {
                return "header edit (no tensor)";
            }
            let name = names[rng.below(names.len())].clone();
            if !img.header[&name].is_object() {
                img.header.insert(name.clone(), serde_json::json!({}));
            }
            let what = match rng.below(6) {
                0 => {
                    let dt = rng.pick(&["F16", "F64", "F32", "I64", "U8", "BOOL", "BF16", "X"]);
                    img.header[&name]["dtype"] = serde_json::json!(dt);
                    "dtype edit"
                }
                1 => {
                    if let Some(shape) = img.header[&name]["shape"].as_array_mut() {
                        if shape.is_empty() || rng.chance(0.2) {
                            shape.push(serde_json::json!(rng.below(4)));
                        } else {
                            let k = rng.below(shape.len());
                            let v = shape[k].as_u64().unwrap_or(0);
                            shape[k] = serde_json::json!(match rng.below(4) {
                                0 => 0,
                                1 => v + 1,
                                2 => v.saturating_sub(1),
                                _ => u64::MAX / 2,
                            });
                        }
                    }
                    "shape edit"
                }
                2 => {
                    if let Some(off) = img.header[&name]["data_offsets"].as_array_mut() {
                        let k = rng.below(2.min(off.len().max(1)));
                        if let Some(v) = off.get_mut(k) {
                            let x = v.as_u64().unwrap_or(0);
                            *v = serde_json::json!(match rng.below(4) {
                                0 => 0,
                                1 => x + 4,
                                2 => x.saturating_sub(4),
                                _ => u64::MAX,
                            });
                        }
                    }
                    "offset edit"
                }
                3 => {
                    img.header.remove(&name);
                    "tensor removed"
                }
                4 => {
                    let v = img.header[&name].clone();
                    img.header.insert(format!("{name}.copy"), v);
                    "tensor duplicated"
                }
                _ => {
                    img.header[&name] = serde_json::json!(rng.pick(&[0.0, -1.0]));
                    "entry replaced"
                }
            };
            *bytes = img.bytes();
            what
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Oracles' helpers.
// ---------------------------------------------------------------------------------------------

/// The error's kind: its variant name, with a self-check's cause appended.
fn kind<E: std::fmt::Debug>(e: &E) -> String {
    let dbg = format!("{e:?}");
    let head: String = dbg
        .chars()
        .take_while(|c| c.is_alphanumeric() || *c == '_')
        .collect();
    if ["SelfCheck", "Predictor", "Planner", "Settings"].contains(&head.as_str()) {
        let rest = &dbg[head.len()..];
        let at = if let Some(r) = rest.strip_prefix('(') {
            Some(r)
        } else {
            rest.find("source: ").map(|i| &rest[i + 8..])
        };
        if let Some(r) = at {
            let inner: String = r
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            return format!("{head}({inner})");
        }
    }
    head
}

/// Re-checks predictions: `out` is `[batch, n - 1, t, 2]`; every position finite and within
/// [`MAX_STEP`] of the agent's previous one (its last observed position for step 1).
fn predictions_valid(history: &History, out: &[f64], t: usize) -> Result<(), String> {
    let n = history.n_agents();
    if n < 2 {
        return Ok(());
    }
    for (b, cand) in out.chunks_exact((n - 1) * t * 2).enumerate() {
        for (i, traj) in cand.chunks_exact(2 * t).enumerate() {
            let mut prev = history.at(i + 1, T_OBS - 1);
            for (k, p) in traj.chunks_exact(2).enumerate() {
                let d = (p[0] - prev[0]).hypot(p[1] - prev[1]);
                if !(p[0].is_finite() && p[1].is_finite() && d <= MAX_STEP * (1.0 + 1e-12)) {
                    return Err(format!(
                        "prediction of agent {} at step {} (candidate {b}) is ({}, {}), {d} m from the previous",
                        i + 1,
                        k + 1,
                        p[0],
                        p[1]
                    ));
                }
                prev = [p[0], p[1]];
            }
        }
    }
    Ok(())
}

/// Judges one plan: finite inputs, states and cost (else `Invalid`), states equal to the
/// nonlinear roll-out of the inputs from `ego` to 1e-6 relative (else `NotRollout`).
fn judge_plan(planner: &Planner, ego: EgoState, plan: &nudge_planner::Plan) -> Outcome {
    match plan_finite(plan) {
        Err(why) => Outcome::Invalid(why),
        Ok(()) => match rollout_consistent(planner, ego, plan) {
            Ok(()) => Outcome::Valid,
            Err(why) => Outcome::NotRollout(why),
        },
    }
}

/// Slack over a call's wall-clock budget (s): one predictor call and the QP work of the
/// execution check after the deadline, on a loaded machine.
const BUDGET_SLACK_S: f64 = 2.0;

/// The call kept its work budget whatever the settings (issue 49, class 7): at most
/// `budget.calls` (0: `MAX_CALLS`) predictor calls, at most `budget.seconds` (0:
/// `MAX_SECONDS`) plus [`BUDGET_SLACK_S`] of wall clock, and a limit recorded only when the
/// call reached it.
fn within_budget(
    settings: &PlannerSettings,
    plan: &nudge_planner::Plan,
    took: f64,
) -> Result<(), String> {
    let calls = match settings.budget.calls {
        0 => PlannerSettings::MAX_CALLS,
        c => c,
    };
    let seconds = if settings.budget.seconds > 0.0 {
        settings.budget.seconds
    } else {
        PlannerSettings::MAX_SECONDS
    };
    if plan.predictor_calls > calls {
        return Err(format!(
            "{} predictor calls, budget {calls}",
            plan.predictor_calls
        ));
    }
    if took > seconds + BUDGET_SLACK_S {
        return Err(format!("the call took {took:.2} s, budget {seconds} s"));
    }
    // The planner holds back 2 calls for its execution check: it stops at calls − 2.
    if plan.budget_reached == Some(nudge_planner::BudgetLimit::Calls)
        && plan.predictor_calls + 2 < calls
    {
        return Err(format!(
            "budget_reached Calls after {} of {calls} calls",
            plan.predictor_calls
        ));
    }
    Ok(())
}

fn plan_finite(plan: &nudge_planner::Plan) -> Result<(), String> {
    for (k, ((d, a), s)) in plan
        .delta
        .iter()
        .zip(&plan.accel)
        .zip(&plan.states)
        .enumerate()
    {
        if !(d.is_finite() && a.is_finite() && s.iter().all(|v| v.is_finite())) {
            return Err(format!(
                "non-finite plan at step {k}: delta {d}, accel {a}, state {s:?}"
            ));
        }
    }
    if plan.states.len() != plan.delta.len() || plan.accel.len() != plan.delta.len() {
        return Err("plan lengths differ".to_owned());
    }
    if !plan.cost.is_finite() {
        return Err(format!("cost {} ({:?})", plan.cost, plan.status));
    }
    Ok(())
}

/// States equal the nonlinear roll-out of the plan's inputs from `ego` (to 1e-6 relative).
fn rollout_consistent(
    planner: &Planner,
    ego: EgoState,
    plan: &nudge_planner::Plan,
) -> Result<(), String> {
    let model = planner.model();
    let mut z = State::new(ego.x, ego.y, ego.psi, ego.v);
    for (k, ((d, a), s)) in plan
        .delta
        .iter()
        .zip(&plan.accel)
        .zip(&plan.states)
        .enumerate()
    {
        // The planner's model: one bicycle step, then the speed clamped at 0 (a vehicle that
        // brakes to a stop stays stopped; it never reverses).
        z = model.step(&z, *d, *a);
        z[3] = z[3].max(0.0);
        let err = (0..4)
            .map(|i| (z[i] - s[i]).abs() / (1.0 + z[i].abs()))
            .fold(0.0, f64::max);
        if err > 1e-6 {
            return Err(format!(
                "state {k} {s:?} is not the roll-out of the inputs ({:?}), relative error {err:e}",
                [z[0], z[1], z[2], z[3]]
            ));
        }
    }
    Ok(())
}

/// Outcome of one try.
enum Outcome {
    /// Refused with a typed error of this kind.
    Refused(String),
    /// Accepted and valid.
    Valid,
    /// Accepted; its use then gave a typed error of this kind.
    LaterRefused(String),
    /// Accepted but invalid (a defect).
    Invalid(String),
    /// Accepted and finite, but the plan's states are not the roll-out of its inputs: a
    /// planner-side property (ADMM returns its Z), counted apart unless `strict_rollout`.
    NotRollout(String),
}

// ---------------------------------------------------------------------------------------------
// Target: weights.
// ---------------------------------------------------------------------------------------------

struct WeightsSeeds {
    files: Vec<Vec<u8>>,
    scenes: Vec<(History, Vec<f64>)>,
}

fn weights_seeds(repo: &Path) -> WeightsSeeds {
    let mut files = vec![
        synthetic_weights(&ModelConfig::teacher(), 1).unwrap(),
        synthetic_weights(&ModelConfig::student(), 2).unwrap(),
    ];
    for k in ["student", "teacher"] {
        if let Ok(b) = std::fs::read(repo.join(format!("assets/models/{k}.safetensors"))) {
            files.push(b);
        }
    }
    // Canonical, a 2-agent and a real scene's history (ego-centred candidates).
    let mut scenes = vec![canonical_scene(6)];
    let two: Vec<f64> = (0..2)
        .flat_map(|a| {
            (0..T_OBS).flat_map(move |t| [a as f64 * 12.0 + t as f64 * 8.0, a as f64 * 3.7])
        })
        .collect();
    scenes.push((History::new(two, 2).unwrap(), straight(56.0, 0.0, 8.0)));
    if let Ok(sc) =
        Scenario::from_file(repo.join("assets/scenes/us101-11_1-t02.1-ego132.safetensors"))
    {
        let h = History::new(sc.history.clone(), sc.n_agents).unwrap();
        let [x, y] = sc.position(0, T_OBS - 1);
        scenes.push((h, straight(x, y, sc.speed[0] * 0.3)));
    }
    WeightsSeeds { files, scenes }
}

/// Two candidates `[2, 6, 2]` from `(x, y)` at `v` metres per step: keep lane, drift left.
fn straight(x: f64, y: f64, v: f64) -> Vec<f64> {
    let mut c = Vec::new();
    for lat in [0.0, 0.4] {
        for k in 1..=6 {
            c.push(x + v * k as f64);
            c.push(y + lat * k as f64);
        }
    }
    c
}

fn weights_try(rng: &mut Rng, seeds: &WeightsSeeds) -> Outcome {
    let mut bytes = seeds.files[rng.below(seeds.files.len())].clone();
    let mut restamp_after = false;
    for _ in 0..=rng.below(3) {
        match rng.below(3) {
            0 => {
                mutate_generic(rng, &mut bytes);
            }
            1 => {
                // Value edits inside tensors (a finite network may still compute NaN).
                if let Some(mut img) = Image::parse(&bytes) {
                    let names = img.tensor_names();
                    if !names.is_empty() {
                        for _ in 0..=rng.below(3) {
                            let name = names[rng.below(names.len())].clone();
                            let i = rng.below(1 << 16);
                            let v = rng.wild();
                            img.set_float(&name, i, v);
                        }
                        bytes = img.bytes();
                    }
                }
                restamp_after = rng.chance(0.8);
            }
            _ => {
                // Config edits.
                if let Some(mut img) = Image::parse(&bytes) {
                    let meta = img.meta_mut();
                    match rng.below(4) {
                        0 => {
                            meta.remove("sha256");
                        }
                        1 => {
                            let k = rng.pick(&["format", "trained", "config", "provenance"]);
                            meta.insert(
                                k.into(),
                                serde_json::json!(rng.pick(&["", "{}", "true", "x"])),
                            );
                        }
                        _ => {
                            if let Some(cfg) = meta.get("config").and_then(|c| c.as_str())
                                && let Ok(mut v) = serde_json::from_str::<serde_json::Value>(cfg)
                                && let Some(obj) = v.as_object_mut()
                            {
                                let mut keys: Vec<String> = obj.keys().cloned().collect();
                                keys.push("batch_norm".to_owned());
                                let key = keys[rng.below(keys.len())].clone();
                                let val = match rng.below(6) {
                                    0 => serde_json::json!(rng.below(70)),
                                    1 => serde_json::json!(u64::MAX),
                                    2 => serde_json::json!(-1),
                                    3 => serde_json::json!(rng.wild().to_string()),
                                    4 => serde_json::json!(0.3),
                                    _ => serde_json::json!(
                                        rng.pick(&["teacher", "student", "relu", ""])
                                    ),
                                };
                                obj.insert(key, val);
                                meta.insert("config".into(), serde_json::json!(v.to_string()));
                            }
                        }
                    }
                    bytes = img.bytes();
                }
                restamp_after = rng.chance(0.7);
            }
        }
    }
    if restamp_after && let Ok(b) = restamp(&bytes) {
        bytes = b;
    }
    let weights = match ModelWeights::from_bytes(&bytes) {
        Ok(w) => w,
        Err(e) => return Outcome::Refused(kind(&e)),
    };
    let built: Result<Box<dyn Predictor>, _> = match weights.config().kind {
        ModelKind::Teacher => {
            Teacher::from_weights(&weights).map(|p| Box::new(p) as Box<dyn Predictor>)
        }
        ModelKind::Student => {
            Student::from_weights(&weights).map(|p| Box::new(p) as Box<dyn Predictor>)
        }
    };
    let mut p = match built {
        Ok(p) => p,
        Err(e) => return Outcome::Refused(kind(&e)),
    };
    let t = p.horizon();
    for (history, cand6) in &seeds.scenes {
        // Candidates for this horizon: extend the 6-step ones at their last velocity.
        let cand = resize_candidates(cand6, t);
        let n = history.n_agents();
        let mut out = vec![0.0; cand.len() / 2 * (n - 1) * 2];
        let r = p
            .set_scene(history)
            .and_then(|()| p.predict(&cand, &mut out));
        match r {
            Ok(()) => {
                if let Err(why) = predictions_valid(history, &out, t) {
                    return Outcome::Invalid(why);
                }
            }
            Err(e) => return Outcome::LaterRefused(kind(&e)),
        }
    }
    Outcome::Valid
}

/// `[b, 6, 2]` candidates resized to `[b, t, 2]` (truncated, or extended at the last step's
/// displacement).
fn resize_candidates(c6: &[f64], t: usize) -> Vec<f64> {
    let mut out = Vec::new();
    for c in c6.chunks_exact(12) {
        let d = [c[10] - c[8], c[11] - c[9]];
        for k in 0..t {
            if k < 6 {
                out.extend_from_slice(&c[2 * k..2 * k + 2]);
            } else {
                let s = (k - 5) as f64;
                out.push(c[10] + s * d[0]);
                out.push(c[11] + s * d[1]);
            }
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Target: scenarios.
// ---------------------------------------------------------------------------------------------

fn scenario_seeds(repo: &Path) -> Vec<Vec<u8>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(repo.join("assets/scenes"))
        .map(|rd| {
            rd.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "safetensors"))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v.iter().filter_map(|p| std::fs::read(p).ok()).collect()
}

fn mutate_scenario_semantics(rng: &mut Rng, img: &mut Image) -> &'static str {
    let n = img.f64s("heading").len().max(1);
    let a = rng.below(n);
    match rng.below(10) {
        0 => {
            let mut h = img.f64s("history");
            let dy = if rng.chance(0.5) {
                rng.range(-5.0, 5.0)
            } else {
                rng.range(-200.0, 200.0)
            };
            for t in 0..T_OBS {
                if let Some(v) = h.get_mut((a * T_OBS + t) * 2 + 1) {
                    *v += dy;
                }
            }
            img.set_f64s("history", &h);
            "agent moved sideways"
        }
        1 => {
            let v = match rng.below(4) {
                0 => std::f64::consts::PI,
                1 => 1e10,
                2 => rng.range(-1.0, 1.0),
                _ => rng.wild(),
            };
            img.set_float("heading", a, v);
            "heading"
        }
        2 => {
            let v = match rng.below(3) {
                0 => 1e6,
                1 => rng.range(0.0, 80.0),
                _ => rng.wild(),
            };
            img.set_float("speed", a, v);
            "speed"
        }
        3 => {
            let mut b = img.f64s("lane_bounds");
            let s = rng.pick(&[1e-9, 0.5, 0.7, 1.3, 2.0, 10.0]);
            let mid = b.first().copied().unwrap_or(0.0);
            b.iter_mut().for_each(|v| *v = mid + (*v - mid) * s);
            img.set_f64s("lane_bounds", &b);
            if rng.chance(0.7) {
                let mut c = img.f64s("lane_centres");
                c.iter_mut().for_each(|v| *v = mid + (*v - mid) * s);
                img.set_f64s("lane_centres", &c);
            }
            "lane widths scaled"
        }
        4 => {
            if let Some((b, e)) = img.span("ego_lane")
                && e - b >= 8
            {
                let v: i64 = rng.pick(&[-1, 0, 1, 2, 3, 5, 7, i64::MAX]);
                img.data[b..b + 8].copy_from_slice(&v.to_le_bytes());
            }
            "ego_lane"
        }
        5 => {
            let v = match rng.below(3) {
                0 => rng.range(0.0, 50.0),
                1 => rng.range(0.0, 3.0),
                _ => rng.wild(),
            };
            img.set_float("size", 2 * a + rng.below(2), v);
            "size"
        }
        6 => {
            let mut h = img.f64s("history");
            let k = rng.below(T_OBS);
            let dx = rng.range(-100.0, 100.0);
            for t in k..T_OBS {
                if let Some(v) = h.get_mut((a * T_OBS + t) * 2) {
                    *v += dx;
                }
            }
            img.set_f64s("history", &h);
            "history jump"
        }
        7 => {
            let name = rng.pick(&[
                "history",
                "future",
                "lane_centres",
                "lane_bounds",
                "heading",
                "speed",
                "size",
            ]);
            let i = rng.below(1 << 12);
            let v = rng.wild();
            img.set_float(name, i, v);
            "special value"
        }
        8 => {
            if let Some((b, e)) = img.span("future_valid") {
                for x in &mut img.data[b..e] {
                    if rng.chance(0.3) {
                        *x = rng.pick(&[0, 1, 2, 255]);
                    }
                }
            }
            "future_valid"
        }
        _ => {
            let meta = img.meta_mut();
            let k = rng.pick(&["dt", "schema"]);
            meta.insert(
                k.into(),
                serde_json::json!(rng.pick(&["0.1", "0.3", "nudge.scenario/2", "x", ""])),
            );
            "metadata"
        }
    }
}

/// Independent re-check of the documented plausibility ranges of an accepted scenario.
fn scenario_plausible(sc: &Scenario) -> Result<(), String> {
    let [right, left] = sc.road();
    for w in sc.lane_bounds.windows(2) {
        let width = w[1] - w[0];
        if !(LANE_WIDTH[0]..=LANE_WIDTH[1]).contains(&width) {
            return Err(format!("lane width {width}"));
        }
    }
    for a in 0..sc.n_agents {
        for t in 0..T_OBS {
            let [x, y] = sc.position(a, t);
            if !(x.is_finite() && y >= right - ROAD_TOLERANCE && y <= left + ROAD_TOLERANCE) {
                return Err(format!(
                    "agent {a} at ({x}, {y}) at step {t}, road [{right}, {left}]"
                ));
            }
        }
        if sc.heading[a].abs().is_nan() || sc.heading[a].abs() > MAX_HEADING {
            return Err(format!("agent {a} heading {}", sc.heading[a]));
        }
        if !(0.0..=MAX_SPEED).contains(&sc.speed[a]) {
            return Err(format!("agent {a} speed {}", sc.speed[a]));
        }
    }
    let y = sc.position(0, T_OBS - 1)[1];
    let (lo, hi) = (sc.lane_bounds[sc.ego_lane], sc.lane_bounds[sc.ego_lane + 1]);
    if !(y >= lo - EGO_LANE_TOLERANCE && y <= hi + EGO_LANE_TOLERANCE) {
        return Err(format!("ego at y {y} outside its lane [{lo}, {hi}]"));
    }
    Ok(())
}

fn scenario_try(rng: &mut Rng, seeds: &[Vec<u8>], student: Option<&Student>) -> Outcome {
    let mut bytes = seeds[rng.below(seeds.len())].clone();
    for _ in 0..=rng.below(2) {
        if rng.chance(0.35) {
            mutate_generic(rng, &mut bytes);
        } else if let Some(mut img) = Image::parse(&bytes) {
            mutate_scenario_semantics(rng, &mut img);
            bytes = img.bytes();
        }
    }
    let sc = match Scenario::from_bytes(&bytes, Path::new("fuzz.safetensors")) {
        Ok(sc) => sc,
        Err(e) => return Outcome::Refused(kind(&e)),
    };
    if let Err(why) = scenario_plausible(&sc) {
        return Outcome::Invalid(format!("accepted implausible scenario: {why}"));
    }
    // One MPC call with the constant-velocity predictor: finite states = roll-out of inputs.
    let settings = PlannerSettings::default();
    let history = match History::new(sc.history.clone(), sc.n_agents) {
        Ok(h) => h,
        Err(e) => return Outcome::LaterRefused(kind(&e)),
    };
    let [x, y] = sc.position(0, T_OBS - 1);
    let ego = EgoState {
        x,
        y,
        psi: sc.heading[0],
        v: sc.speed[0],
    };
    let target = if sc.ego_lane + 1 < sc.lane_centres.len() {
        sc.ego_lane + 1
    } else {
        sc.ego_lane.saturating_sub(1)
    };
    let problem = PlanningProblem {
        ego,
        last_delta: 0.0,
        last_accel: 0.0,
        history: &history,
        sizes: &sc.size,
        y_target: sc.lane_centres[target],
        v_ref: sc.speed[0],
        road: sc.road(),
        y_retreat: Some(sc.lane_centres[sc.ego_lane]),
        lanes: sc.lanes(),
    };
    let mut planner = Planner::new(settings.clone()).unwrap();
    let mut cv = ConstantVelocity::default();
    let mut not_rollout = None;
    match planner.plan(&problem, &mut cv) {
        Ok(plan) => match judge_plan(&planner, ego, &plan) {
            Outcome::Invalid(why) => {
                return Outcome::Invalid(format!("MPC on an accepted scenario: {why}"));
            }
            Outcome::NotRollout(why) => not_rollout = Some(why),
            _ => {}
        },
        Err(e) => return Outcome::LaterRefused(kind(&e)),
    }
    // A short closed loop (log replay), with the student planning on some tries.
    let cfg = SimConfig {
        max_steps: 2,
        world: World::LogReplay,
        ..SimConfig::default()
    };
    let mut student = student.filter(|_| rng.chance(0.2)).cloned();
    let planner_pred: &mut dyn Predictor = match &mut student {
        Some(s) => s,
        None => &mut cv,
    };
    match simulate(
        &sc,
        &settings,
        &cfg,
        rng.next_u64() % 1000,
        planner_pred,
        WorldModel::LogReplay,
    ) {
        Ok(rec) => {
            for st in &rec.steps {
                if !st.ego.iter().all(|v| v.is_finite())
                    || !st.delta.is_finite()
                    || !st.accel.is_finite()
                {
                    return Outcome::Invalid(format!(
                        "closed-loop step {} is not finite: {st:?}",
                        st.step
                    ));
                }
            }
            not_rollout.map_or(Outcome::Valid, |why| {
                Outcome::NotRollout(format!("MPC on an accepted scenario: {why}"))
            })
        }
        Err(e) => Outcome::LaterRefused(kind(&e)),
    }
}

// ---------------------------------------------------------------------------------------------
// Target: settings.
// ---------------------------------------------------------------------------------------------

struct SettingsScene {
    sc: Scenario,
    history: History,
}

fn settings_value(rng: &mut Rng, field: &str) -> serde_json::Value {
    let range = PlannerSettings::fields()
        .filter_map(|f| f.range)
        .find(|r| r.field == field);
    let (group, leaf) = field.split_once('.').unwrap_or(("", field));
    let is_int = serde_json::to_value(PlannerSettings::default())
        .unwrap()
        .get(group)
        .and_then(|g| g.get(leaf))
        .is_some_and(serde_json::Value::is_u64);
    match rng.below(12) {
        0 => serde_json::json!(rng.pick(&[1e300, -1e300, 0.0, -1.0, 1e-300])),
        1 => serde_json::json!(u64::MAX),
        2 => serde_json::json!(rng.pick(&["x", ""])),
        3 => serde_json::Value::Null,
        4 => serde_json::json!([1.0, 2.0]),
        5 => serde_json::json!(rng.chance(0.5)),
        _ => {
            let Some(r) = range else {
                return serde_json::json!(rng.chance(0.5));
            };
            // Mostly in or near the range; integer counts mostly moderate so a try stays short.
            let hi = if is_int {
                r.max.min(r.min + 40.0)
            } else {
                r.max
            };
            let v = match rng.below(6) {
                0 => r.min,
                1 => r.max,
                2 => r.min - (r.max - r.min) * 0.01,
                3 => r.max + (r.max - r.min) * 0.01,
                _ => rng.range(r.min, hi),
            };
            if is_int {
                if v < 0.0 {
                    serde_json::json!(v as i64)
                } else if rng.chance(0.1) {
                    serde_json::json!(v + 0.5)
                } else {
                    serde_json::json!(v.round() as u64)
                }
            } else {
                serde_json::json!(v)
            }
        }
    }
}

fn settings_try(rng: &mut Rng, scene: &SettingsScene) -> Outcome {
    // Dotted keys of every field (`cost.w_y`), written as nested groups.
    let keys: Vec<String> = PlannerSettings::fields()
        .map(|f| f.field.to_owned())
        .collect();
    let mut obj = serde_json::Map::new();
    for _ in 0..=rng.below(4) {
        let k = keys[rng.below(keys.len())].clone();
        let v = settings_value(rng, &k);
        let (group, leaf) = k.split_once('.').unwrap_or(("", &k));
        let entry = obj
            .entry(group.to_owned())
            .or_insert_with(|| serde_json::json!({}));
        if let Some(m) = entry.as_object_mut() {
            m.insert(leaf.to_owned(), v);
        }
    }
    let mut text = serde_json::Value::Object(obj.clone()).to_string();
    match rng.below(10) {
        0 => {
            // Positional array.
            let v: Vec<f64> = (0..=rng.below(5)).map(|_| rng.range(-10.0, 10.0)).collect();
            text = serde_json::json!(v).to_string();
        }
        1 if !text.is_empty() => {
            let mut b = text.into_bytes();
            let i = rng.below(b.len());
            b[i] ^= 1 << rng.below(7);
            text = String::from_utf8_lossy(&b).into_owned();
        }
        2 => {
            let n = rng.below(text.len() + 1);
            text.truncate(n);
        }
        3 => {
            // A repeated key, or an unknown one.
            let k = keys[rng.below(keys.len())].clone();
            let extra = if rng.chance(0.5) { k } else { format!("{k}_x") };
            text = format!("{{\"{extra}\": 1, {}", text.trim_start_matches('{'));
        }
        _ => {}
    }
    let s = match PlannerSettings::from_json(&text) {
        Ok(s) => s,
        Err(e) => return Outcome::Refused(kind(&e)),
    };
    for r in PlannerSettings::fields().filter_map(|f| f.range) {
        let v = s.numeric(r.field).unwrap_or(f64::NAN);
        if !r.contains(v) {
            return Outcome::Invalid(format!("accepted {} = {v} outside {r}", r.field));
        }
    }
    let mut planner = match Planner::new(s.clone()) {
        Ok(p) => p,
        Err(e) => return Outcome::LaterRefused(kind(&e)),
    };
    let mut cv = match ConstantVelocity::new(s.model.horizon) {
        Ok(cv) => cv,
        Err(e) => return Outcome::LaterRefused(kind(&e)),
    };
    let sc = &scene.sc;
    let [x, y] = sc.position(0, T_OBS - 1);
    let ego = EgoState {
        x,
        y,
        psi: sc.heading[0],
        v: sc.speed[0],
    };
    let problem = PlanningProblem {
        ego,
        last_delta: 0.0,
        last_accel: 0.0,
        history: &scene.history,
        sizes: &sc.size,
        y_target: sc.lane_centres[(sc.ego_lane + 1).min(sc.lane_centres.len() - 1)],
        v_ref: sc.speed[0],
        road: sc.road(),
        y_retreat: Some(sc.lane_centres[sc.ego_lane]),
        lanes: sc.lanes(),
    };
    match planner.plan(&problem, &mut cv) {
        Ok(plan) => match judge_plan(&planner, ego, &plan) {
            Outcome::Invalid(why) => Outcome::Invalid(format!("MPC with accepted settings: {why}")),
            Outcome::NotRollout(why) => {
                Outcome::NotRollout(format!("MPC with accepted settings: {why}"))
            }
            other => other,
        },
        Err(e) => Outcome::LaterRefused(kind(&e)),
    }
}

// ---------------------------------------------------------------------------------------------
// Target: planning problems.
// ---------------------------------------------------------------------------------------------

struct PlanSeeds {
    scenes: Vec<Scenario>,
    student: Option<Student>,
    teacher: Option<Teacher>,
}

fn plan_seeds(repo: &Path, scene_bytes: &[Vec<u8>]) -> PlanSeeds {
    PlanSeeds {
        scenes: scene_bytes
            .iter()
            .filter_map(|b| Scenario::from_bytes(b, Path::new("seed.safetensors")).ok())
            .collect(),
        student: Student::from_file(repo.join("assets/models/student.safetensors")).ok(),
        teacher: Teacher::from_file(repo.join("assets/models/teacher.safetensors")).ok(),
    }
}

/// A predictor from outside nudge-predictor: constant velocity whose predictions are
/// corrupted (NaN, ±∞, huge values, or an agent moved 31–500 m) on some calls, at a random
/// place. Every corruption is one the output check must catch.
struct Foreign {
    inner: ConstantVelocity,
    rng: Rng,
    rate: f64,
    /// Whether any prediction handed out was corrupted.
    corrupted: bool,
}

impl Predictor for Foreign {
    fn name(&self) -> &'static str {
        "foreign"
    }
    fn horizon(&self) -> usize {
        self.inner.horizon()
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.inner.set_scene(history)
    }
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        self.inner.predict(candidates, out)?;
        if !out.is_empty() && self.rng.chance(self.rate) {
            let i = self.rng.below(out.len());
            out[i] = match self.rng.below(4) {
                0 => f64::NAN,
                1 => self.rng.pick(&[f64::INFINITY, f64::NEG_INFINITY]),
                2 => self.rng.pick(&[2e39, -1e300, 1e154]),
                _ => out[i] + self.rng.pick(&[1.0, -1.0]) * self.rng.range(31.0, 500.0),
            };
            self.corrupted = true;
        }
        Ok(())
    }
}

/// The documented ranges of `PlanningProblem::check`, re-checked independently.
fn problem_in_range(p: &PlanningProblem<'_>) -> Result<(), String> {
    let e = p.ego;
    let finite = [
        e.x,
        e.y,
        e.psi,
        e.v,
        p.last_delta,
        p.last_accel,
        p.y_target,
        p.v_ref,
        p.road[0],
        p.road[1],
    ]
    .iter()
    .all(|v| v.is_finite());
    let checks = [
        (finite, "a non-finite number"),
        (e.x.abs() <= 1e6 && e.y.abs() <= 1e6, "ego beyond 1e6 m"),
        (
            (0.0..=100.0).contains(&e.v),
            "ego speed outside 0..=100 m/s",
        ),
        (
            e.psi.abs() <= std::f64::consts::FRAC_PI_2,
            "heading beyond pi/2",
        ),
        (p.last_delta.abs() <= 1.5, "last_delta beyond 1.5 rad"),
        (p.last_accel.abs() <= 15.0, "last_accel beyond 15 m/s2"),
        (p.road[0] < p.road[1], "unordered road"),
        (p.road[1] - p.road[0] <= 72.0, "road wider than 72 m"),
        (
            p.road[0].abs() <= 1e6 && p.road[1].abs() <= 1e6,
            "road beyond 1e6 m",
        ),
        (
            p.road[0] <= p.y_target && p.y_target <= p.road[1],
            "y_target off the road",
        ),
        ((0.0..=60.0).contains(&p.v_ref), "v_ref outside 0..=60 m/s"),
        (
            p.sizes.len() == p.history.n_agents()
                && p.sizes.iter().all(|s| s[0] > 0.0 && s[1] > 0.0),
            "sizes",
        ),
    ];
    match checks.iter().find(|(ok, _)| !ok) {
        Some((_, why)) => Err(format!("accepted a problem with {why}: {p:?}")),
        None => Ok(()),
    }
}

fn plan_try(rng: &mut Rng, seeds: &PlanSeeds) -> Outcome {
    let base = &seeds.scenes[rng.below(seeds.scenes.len())];
    let sc = if rng.chance(0.5) {
        base.nearest(rng.below(8))
    } else {
        base.clone()
    };
    let mut positions = sc.history.clone();
    let mut sizes = sc.size.clone();
    let [x, y] = sc.position(0, T_OBS - 1);
    let lane = if sc.ego_lane + 1 < sc.lane_centres.len() {
        sc.ego_lane + 1
    } else {
        sc.ego_lane.saturating_sub(1)
    };
    let mut ego = EgoState {
        x,
        y,
        psi: sc.heading[0],
        v: sc.speed[0],
    };
    let mut last = (0.0, 0.0);
    let mut y_target = sc.lane_centres[lane];
    let mut y_retreat = rng.chance(0.5).then(|| sc.lane_centres[sc.ego_lane]);
    let mut v_ref = sc.speed[0];
    let mut road = sc.road();
    // Zero to four edits; most tries keep most of the scene so that plans run.
    for _ in 0..rng.below(5) {
        match rng.below(12) {
            0 => {
                ego.x = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    x + rng.range(-5.0, 5.0)
                }
            }
            1 => {
                ego.y = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    y + rng.range(-3.0, 3.0)
                }
            }
            2 => {
                ego.psi = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    rng.range(-1.7, 1.7)
                }
            }
            3 => {
                ego.v = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    rng.range(-1.0, 70.0)
                }
            }
            4 => {
                last.0 = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    rng.range(-0.3, 0.3)
                }
            }
            5 => {
                last.1 = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    rng.range(-8.0, 8.0)
                }
            }
            6 => {
                let y = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    rng.range(road[0] - 3.0, road[1] + 3.0)
                };
                if rng.chance(0.5) {
                    y_target = y;
                } else {
                    y_retreat = Some(y);
                }
            }
            7 => {
                v_ref = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    rng.range(-5.0, 70.0)
                }
            }
            8 => {
                let i = rng.below(2);
                road[i] = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    road[i] + rng.range(-5.0, 5.0)
                };
            }
            9 => {
                let i = rng.below(sizes.len());
                sizes[i][rng.below(2)] = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    rng.range(0.1, 30.0)
                };
            }
            10 => {
                // One observed position of one agent.
                let i = rng.below(positions.len());
                positions[i] = if rng.chance(0.5) {
                    rng.wild()
                } else {
                    positions[i] + rng.range(-40.0, 40.0)
                };
            }
            _ => {
                // Every position shifted: far from the origin.
                let d = rng.pick(&[1e3, 1e5, 1e6, 2e6, 1e9]);
                for v in &mut positions {
                    *v += d;
                }
                ego.x += d;
                ego.y += d;
                y_target += d;
                y_retreat = y_retreat.map(|y| y + d);
                road = [road[0] + d, road[1] + d];
            }
        }
    }
    let history = match History::new(positions, sc.n_agents) {
        Ok(h) => h,
        Err(e) => return Outcome::Refused(kind(&e)),
    };
    let problem = PlanningProblem {
        ego,
        last_delta: last.0,
        last_accel: last.1,
        history: &history,
        sizes: &sizes,
        y_target,
        v_ref,
        road,
        y_retreat,
        lanes: sc.lanes(),
    };
    let settings = PlannerSettings::default();
    let mut planner = Planner::new(settings.clone()).unwrap();
    let mut cv = ConstantVelocity::default();
    let mut foreign = Foreign {
        inner: ConstantVelocity::default(),
        rng: Rng(rng.next_u64()),
        rate: rng.pick(&[0.01, 0.1, 1.0]),
        corrupted: false,
    };
    let mut student = seeds.student.clone();
    let mut teacher = seeds.teacher.clone();
    let predictor: &mut dyn Predictor = match rng.below(8) {
        0..=2 => &mut cv,
        3 | 4 => match &mut student {
            Some(s) => s,
            None => &mut cv,
        },
        5 => match &mut teacher {
            Some(t) => t,
            None => &mut cv,
        },
        _ => &mut foreign,
    };
    let started = std::time::Instant::now();
    let result = planner.plan(&problem, predictor);
    let took = started.elapsed().as_secs_f64();
    if let Ok(plan) = &result
        && let Err(why) = within_budget(&settings, plan, took)
    {
        return Outcome::Invalid(why);
    }
    if foreign.corrupted {
        // The planner saw a corrupted prediction: a typed error naming it, or an Unsafe plan.
        return match result {
            Err(
                e @ nudge_planner::PlannerError::Predictor(
                    nudge_predictor::PredictorError::NonFiniteOutput { .. }
                    | nudge_predictor::PredictorError::ImplausibleOutput { .. },
                ),
            ) => Outcome::LaterRefused(kind(&e)),
            Ok(plan) if plan.status == PlanStatus::Unsafe => Outcome::Valid,
            Ok(plan) => Outcome::Invalid(format!(
                "planned on a corrupted prediction: {:?} with min_safety {:?}",
                plan.status, plan.min_safety
            )),
            Err(e) => Outcome::Invalid(format!(
                "a corrupted prediction was not reported as such: {e}"
            )),
        };
    }
    match result {
        Err(e @ nudge_planner::PlannerError::BadProblem { .. }) => Outcome::Refused(kind(&e)),
        Err(e) => Outcome::LaterRefused(kind(&e)),
        Ok(plan) => {
            if let Err(why) = problem_in_range(&problem) {
                return Outcome::Invalid(why);
            }
            if matches!(
                plan.status,
                PlanStatus::Converged | PlanStatus::MaxIterations
            ) && !plan
                .min_safety
                .is_none_or(|b| b.is_finite() && b > settings.safety.safety_min)
            {
                return Outcome::Invalid(format!(
                    "{:?} (reported safe) with min_safety {:?}",
                    plan.status, plan.min_safety
                ));
            }
            judge_plan(&planner, ego, &plan)
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Driver.
// ---------------------------------------------------------------------------------------------

/// Peak resident set size (MiB) from `/proc/self/status` (`VmHWM`); 0 where unavailable.
#[must_use]
pub fn peak_rss_mib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb / 1024)
}

/// The per-try watchdog: a try running past the limit is a hang; the process reports the try
/// (replayable) and exits with status 3.
struct Watchdog {
    start_ms: Arc<AtomicU64>,
    label: Arc<Mutex<String>>,
    stop: Arc<AtomicBool>,
    t0: Instant,
}

impl Watchdog {
    fn new(limit_s: f64) -> Self {
        let start_ms = Arc::new(AtomicU64::new(u64::MAX));
        let label = Arc::new(Mutex::new(String::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let t0 = Instant::now();
        let (s, l, st) = (start_ms.clone(), label.clone(), stop.clone());
        std::thread::spawn(move || {
            while !st.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(100));
                let begun = s.load(Ordering::Relaxed);
                if begun == u64::MAX {
                    continue;
                }
                let now = t0.elapsed().as_millis() as u64;
                if now.saturating_sub(begun) as f64 > limit_s * 1e3 {
                    let what = l.lock().map(|g| g.clone()).unwrap_or_default();
                    eprintln!("DEFECT hang: {what} ran longer than {limit_s} s");
                    std::process::exit(3);
                }
            }
        });
        Self {
            start_ms,
            label,
            stop,
            t0,
        }
    }

    fn begin(&self, label: String) {
        if let Ok(mut g) = self.label.lock() {
            *g = label;
        }
        self.start_ms
            .store(self.t0.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    fn end(&self) {
        self.start_ms.store(u64::MAX, Ordering::Relaxed);
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// Runs one try of `target` (for replay and for the driver).
fn one_try(target: Target, rng: &mut Rng, ctx: &Context) -> Outcome {
    match target {
        Target::Weights => weights_try(rng, &ctx.weights),
        Target::Scenarios => scenario_try(rng, &ctx.scenes, ctx.student.as_ref()),
        Target::Settings => settings_try(rng, &ctx.settings_scene),
        Target::Plan => plan_try(rng, &ctx.plan),
        Target::CommonRoad => surfaces::commonroad_try(rng, &ctx.surfaces),
        Target::World => surfaces::world_try(rng, &ctx.surfaces),
    }
}

/// Seed inputs, loaded once.
struct Context {
    weights: WeightsSeeds,
    scenes: Vec<Vec<u8>>,
    student: Option<Student>,
    settings_scene: SettingsScene,
    plan: PlanSeeds,
    surfaces: surfaces::SurfaceSeeds,
}

fn context(repo: &Path) -> Context {
    let scenes = scenario_seeds(repo);
    assert!(
        !scenes.is_empty(),
        "no seed scenes under {}",
        repo.join("assets/scenes").display()
    );
    let sc = Scenario::from_bytes(&scenes[0], Path::new("seed.safetensors")).unwrap();
    let history = History::new(sc.history.clone(), sc.n_agents).unwrap();
    Context {
        plan: plan_seeds(repo, &scenes),
        weights: weights_seeds(repo),
        student: Student::from_file(repo.join("assets/models/student.safetensors")).ok(),
        scenes,
        settings_scene: SettingsScene { sc, history },
        surfaces: surfaces::seeds(repo),
    }
}

/// Replays try `i` of `target` under `seed` and describes its outcome.
#[must_use]
pub fn replay(repo: &Path, seed: u64, target: Target, i: u64) -> String {
    let ctx = context(repo);
    let mut rng = Rng::for_try(seed, target, i);
    match std::panic::catch_unwind(AssertUnwindSafe(|| one_try(target, &mut rng, &ctx))) {
        Err(_) => "panic".to_owned(),
        Ok(Outcome::Refused(k)) => format!("typed error {k}"),
        Ok(Outcome::Valid) => "accepted and valid".to_owned(),
        Ok(Outcome::LaterRefused(k)) => format!("accepted, then typed error {k}"),
        Ok(Outcome::Invalid(why)) => format!("accepted but invalid: {why}"),
        Ok(Outcome::NotRollout(why)) => format!("accepted, plan states not the roll-out: {why}"),
    }
}

/// Runs every configured target and returns the counts.
#[must_use]
pub fn run(cfg: &Config) -> Report {
    let ctx = context(&cfg.repo);
    let watchdog = Watchdog::new(cfg.try_limit_s);
    // Panics are caught and counted; keep their messages out of the output.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let mut report = Report::default();
    for &target in &cfg.targets {
        let mut st = Stats::default();
        let t0 = Instant::now();
        let mut i = 0u64;
        while t0.elapsed().as_secs_f64() < cfg.seconds_per_target
            && cfg.max_tries.is_none_or(|m| i < m)
        {
            let mut rng = Rng::for_try(cfg.seed, target, i);
            let label = format!("target {} try {i} (seed {})", target.name(), cfg.seed);
            watchdog.begin(label.clone());
            let ts = Instant::now();
            let outcome =
                std::panic::catch_unwind(AssertUnwindSafe(|| one_try(target, &mut rng, &ctx)));
            let dt = ts.elapsed().as_secs_f64();
            watchdog.end();
            st.tries += 1;
            st.max_try_s = st.max_try_s.max(dt);
            if dt > cfg.slow_s {
                st.slow += 1;
            }
            let defect = |st: &mut Stats, what: String| {
                if cfg.verbose {
                    eprintln!("DEFECT {label}: {what}");
                }
                if st.defects.len() < 20 {
                    st.defects.push(format!("{label}: {what}"));
                }
            };
            match outcome {
                Err(_) => {
                    st.panics += 1;
                    defect(&mut st, "panic".to_owned());
                }
                Ok(Outcome::Refused(k)) => *st.errors.entry(k).or_default() += 1,
                Ok(Outcome::Valid) => st.valid += 1,
                Ok(Outcome::LaterRefused(k)) => *st.later_errors.entry(k).or_default() += 1,
                Ok(Outcome::Invalid(why)) => {
                    st.invalid += 1;
                    defect(&mut st, why);
                }
                Ok(Outcome::NotRollout(why)) => {
                    if cfg.strict_rollout {
                        st.invalid += 1;
                        defect(&mut st, why);
                    } else {
                        st.not_rollout += 1;
                    }
                }
            }
            if i.is_multiple_of(64) && peak_rss_mib() > cfg.rss_limit_mib {
                report.rss_exceeded = true;
                defect(&mut st, format!("peak RSS {} MiB", peak_rss_mib()));
                break;
            }
            i += 1;
        }
        st.seconds = t0.elapsed().as_secs_f64();
        report.targets.insert(target, st);
    }
    std::panic::set_hook(hook);
    report.peak_rss_mib = peak_rss_mib();
    report.rss_exceeded |= report.peak_rss_mib > cfg.rss_limit_mib;
    report
}
