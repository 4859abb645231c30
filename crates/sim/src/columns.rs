//! Closed-loop records as named columns, and the summary and per-step listing of a batch:
//! the one place that decides what the front ends report. The `nudge` CLI writes these tables
//! as CSV ([`Table::write_csv`]) and prints the [`Summary`] and [`step_listing`]; `nudge.simulate`
//! hands the same columns to Python as numpy arrays.

use std::fmt::{self, Write as _};

use nudge_planner::scenario::Scenario;

use super::batch::RunOutput;
use super::metrics::{Collision, RunMetrics};
use super::records::{RunOutcome, RunRecord, StepRecord, StepStatus};

/// Run columns, in order (one row per run, failed runs included). The metric columns are
/// those of [`crate::metrics::RunMetrics`] (comfort flattened).
pub const RUN_COLUMNS: [&str; 42] = [
    "scenario",
    "scene_index",
    "seed",
    "predictor",
    "world",
    "n_agents",
    "target_lane",
    "y_target",
    "success",
    "steps_to_target",
    "collision",
    "aborts",
    "n_steps",
    "collisions_at_fault",
    "collisions_not_at_fault",
    "collisions_at_fault_nuplan",
    "start_overhang",
    "off_road_steps",
    "straddle_steps",
    "steps_to_lane",
    "slow_steps",
    "slow_planned_steps",
    "slow_planned_free_steps",
    "min_ttc",
    "progress",
    "progress_ratio",
    "max_abs_jerk",
    "rms_jerk",
    "max_abs_lat_accel",
    "rms_lat_accel",
    "max_abs_yaw_rate",
    "rms_yaw_rate",
    "max_abs_yaw_accel",
    "min_accel",
    "max_accel",
    "comfortable",
    "max_abs_heading",
    "max_overshoot",
    "free_gap",
    "score",
    "outcome",
    "error",
];

/// Step columns, in order (one row per planning step of every run that ran). The metric
/// columns are those of [`crate::metrics::StepMetrics`]; `lane_violation` is the plan
/// step (1..T) of the applied plan's first state in a lane that has not begun or has ended
/// ([`nudge_planner::Plan::lane_violation`]), −1 when none; `decided_by` is
/// [`nudge_planner::DecidedBy::label`]: `admm` exactly when the ADMM iterate was applied unchanged;
/// `violation_*` are [`nudge_planner::Violation`]'s fields (units of b, rad, m, m, m).
pub const STEP_COLUMNS: [&str; 43] = [
    "run",
    "step",
    "mpc_s",
    "z_updates",
    "z_s",
    "z_median_s",
    "iterations",
    "predictor_calls",
    "cost",
    "primal_residual",
    "min_b",
    "collision",
    "status",
    "decided_by",
    "violation_safety",
    "violation_heading",
    "violation_corridor",
    "violation_edge",
    "violation_lane",
    "delta",
    "accel",
    "x",
    "y",
    "psi",
    "v",
    "y_goal",
    "v_planned",
    "lane_violation",
    "road_excess",
    "off_road",
    "straddle",
    "in_target_lane",
    "traffic_v",
    "slow",
    "slow_planned",
    "lead_gap",
    "slow_planned_free",
    "ttc",
    "progress",
    "jerk",
    "yaw_rate",
    "lat_accel",
    "yaw_accel",
];

/// Collision columns, in order (one row per collision event of every run that ran; the
/// fields of [`crate::metrics::Collision`] and the other vehicle's source id).
pub const COLLISION_COLUMNS: [&str; 18] = [
    "run",
    "step",
    "other",
    "other_id",
    "at_fault",
    "other_behind",
    "rear_hit",
    "ego_in_lane",
    "ego_accel",
    "dx",
    "dy",
    "ego_heading",
    "other_heading",
    "ego_v",
    "other_v",
    "nuplan_type",
    "nuplan_at_fault",
    "free_gap",
];

/// One column's values.
#[derive(Debug, Clone, PartialEq)]
pub enum Column {
    /// Floats; NaN where a value is missing (`min_b` with no vehicle checked, `y_target` of a
    /// failed run, `jerk` of a first step, `traffic_v` with no traffic around); +∞ for a time
    /// to collision with nobody closing in.
    Float(Vec<f64>),
    /// Signed integers; −1 where a value is missing (`steps_to_target` of a run that did not
    /// settle, `target_lane` of a failed run).
    Int(Vec<i64>),
    /// Unsigned integers (seeds).
    UInt(Vec<u64>),
    /// Booleans.
    Bool(Vec<bool>),
    /// Text (names, statuses).
    Text(Vec<String>),
    /// Optional text (`error`: `None` for a run that ran).
    OptText(Vec<Option<String>>),
}

impl Column {
    /// Number of rows.
    #[must_use]
    pub fn len(&self) -> usize {
        match self {
            Self::Float(v) => v.len(),
            Self::Int(v) => v.len(),
            Self::UInt(v) => v.len(),
            Self::Bool(v) => v.len(),
            Self::Text(v) => v.len(),
            Self::OptText(v) => v.len(),
        }
    }

    /// No rows.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Row `i` as CSV text: numbers in Rust's shortest round-trip form, `true`/`false`,
    /// an empty cell for missing text.
    fn cell(&self, i: usize) -> String {
        match self {
            Self::Float(v) => v[i].to_string(),
            Self::Int(v) => v[i].to_string(),
            Self::UInt(v) => v[i].to_string(),
            Self::Bool(v) => v[i].to_string(),
            Self::Text(v) => v[i].clone(),
            Self::OptText(v) => v[i].clone().unwrap_or_default(),
        }
    }
}

/// Named columns of equal length.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    columns: Vec<(&'static str, Column)>,
}

impl Table {
    /// The columns, in order.
    #[must_use]
    pub fn columns(&self) -> &[(&'static str, Column)] {
        &self.columns
    }

    /// The column `name`.
    #[must_use]
    pub fn column(&self, name: &str) -> Option<&Column> {
        self.columns
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, c)| c)
    }

    /// Takes the columns.
    #[must_use]
    pub fn into_columns(self) -> Vec<(&'static str, Column)> {
        self.columns
    }

    /// Number of rows.
    #[must_use]
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, |(_, c)| c.len())
    }

    /// Writes a header of the column names and one CSV record per row.
    ///
    /// # Errors
    /// The writer's I/O error.
    pub fn write_csv<W: std::io::Write>(&self, out: W) -> Result<(), csv::Error> {
        let mut w = csv::Writer::from_writer(out);
        w.write_record(self.columns.iter().map(|(n, _)| *n))?;
        for i in 0..self.rows() {
            w.write_record(self.columns.iter().map(|(_, c)| c.cell(i)))?;
        }
        w.flush()?;
        Ok(())
    }
}

/// A usize as i64 (saturating; counts never come near).
fn int(v: usize) -> i64 {
    i64::try_from(v).unwrap_or(i64::MAX)
}

/// One value per run: `ran` of its record, or `failed` when it could not run.
fn per_run<T: Clone>(outputs: &[RunOutput], ran: impl Fn(&RunRecord) -> T, failed: T) -> Vec<T> {
    outputs
        .iter()
        .map(|o| o.result.as_ref().map_or_else(|_| failed.clone(), &ran))
        .collect()
}

/// The run columns ([`RUN_COLUMNS`]) of a batch run on `scenes`.
#[must_use]
pub fn run_table(scenes: &[Scenario], outputs: &[RunOutput]) -> Table {
    let from_spec = |f: &dyn Fn(&RunOutput) -> i64| outputs.iter().map(f).collect::<Vec<_>>();
    let text = |f: fn(&RunRecord) -> String| Column::Text(per_run(outputs, f, String::new()));
    let flag = |f: fn(&RunRecord) -> bool| Column::Bool(per_run(outputs, f, false));
    let count = |name: &'static str, f: fn(&RunMetrics) -> usize| {
        (
            name,
            Column::Int(per_run(outputs, |r| int(f(&r.metrics)), -1)),
        )
    };
    let float = |name: &'static str, f: fn(&RunMetrics) -> f64| {
        (
            name,
            Column::Float(per_run(outputs, |r| f(&r.metrics), f64::NAN)),
        )
    };
    let columns = vec![
        (
            "scenario",
            Column::Text(
                outputs
                    .iter()
                    .map(|o| scenes[o.spec.scene].name.clone())
                    .collect(),
            ),
        ),
        (
            "scene_index",
            Column::Int(from_spec(&|o| int(o.spec.scene))),
        ),
        (
            "seed",
            Column::UInt(outputs.iter().map(|o| o.spec.seed).collect()),
        ),
        ("predictor", text(|r| r.predictor.clone())),
        ("world", text(|r| r.world.as_str().to_string())),
        (
            "n_agents",
            Column::Int(from_spec(&|o| int(scenes[o.spec.scene].n_agents))),
        ),
        (
            "target_lane",
            Column::Int(per_run(outputs, |r| int(r.target_lane), -1)),
        ),
        (
            "y_target",
            Column::Float(per_run(outputs, |r| r.y_target, f64::NAN)),
        ),
        ("success", flag(|r| r.success)),
        (
            "steps_to_target",
            Column::Int(per_run(outputs, |r| r.steps_to_target.map_or(-1, int), -1)),
        ),
        ("collision", flag(|r| r.collision)),
        (
            "aborts",
            Column::Int(per_run(outputs, |r| int(r.aborts), 0)),
        ),
        (
            "n_steps",
            Column::Int(per_run(outputs, |r| int(r.steps.len()), 0)),
        ),
        count("collisions_at_fault", |m| m.collisions_at_fault),
        count("collisions_not_at_fault", |m| m.collisions_not_at_fault),
        count("collisions_at_fault_nuplan", |m| {
            m.collisions_at_fault_nuplan
        }),
        float("start_overhang", |m| m.start_overhang),
        count("off_road_steps", |m| m.off_road_steps),
        count("straddle_steps", |m| m.straddle_steps),
        (
            "steps_to_lane",
            Column::Int(per_run(
                outputs,
                |r| r.metrics.steps_to_lane.map_or(-1, int),
                -1,
            )),
        ),
        count("slow_steps", |m| m.slow_steps),
        count("slow_planned_steps", |m| m.slow_planned_steps),
        count("slow_planned_free_steps", |m| m.slow_planned_free_steps),
        float("min_ttc", |m| m.min_ttc.unwrap_or(f64::INFINITY)),
        float("progress", |m| m.progress),
        float("progress_ratio", |m| m.progress_ratio.unwrap_or(f64::NAN)),
        float("max_abs_jerk", |m| m.comfort.max_abs_jerk),
        float("rms_jerk", |m| m.comfort.rms_jerk),
        float("max_abs_lat_accel", |m| m.comfort.max_abs_lat_accel),
        float("rms_lat_accel", |m| m.comfort.rms_lat_accel),
        float("max_abs_yaw_rate", |m| m.comfort.max_abs_yaw_rate),
        float("rms_yaw_rate", |m| m.comfort.rms_yaw_rate),
        float("max_abs_yaw_accel", |m| m.comfort.max_abs_yaw_accel),
        float("min_accel", |m| m.comfort.accel_range.0),
        float("max_accel", |m| m.comfort.accel_range.1),
        ("comfortable", flag(|r| r.metrics.comfort.comfortable)),
        float("max_abs_heading", |m| m.max_abs_heading),
        float("max_overshoot", |m| m.max_overshoot),
        float("free_gap", |m| m.free_gap),
        float("score", |m| m.score),
        ("outcome", text(|r| r.outcome.as_str().to_string())),
        (
            "error",
            Column::OptText(
                outputs
                    .iter()
                    .map(|o| o.result.as_ref().err().map(ToString::to_string))
                    .collect(),
            ),
        ),
    ];
    Table { columns }
}

/// The median by the nearest-rank rule used in every report (index round((n − 1)/2) of the
/// sorted values); NaN when empty.
fn median(v: &[f64]) -> f64 {
    quantile(&mut v.to_vec(), 0.5)
}

/// The q-quantile by nearest rank (sorts `v`); NaN when empty.
fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let idx = ((v.len() - 1) as f64 * q).round() as usize;
    v[idx]
}

/// The step columns ([`STEP_COLUMNS`]) of a batch; `run` is the row of the run in
/// [`run_table`].
#[must_use]
pub fn step_table(outputs: &[RunOutput]) -> Table {
    let steps: Vec<(usize, &StepRecord)> = outputs
        .iter()
        .enumerate()
        .filter_map(|(i, o)| o.result.as_ref().ok().map(|r| (i, r)))
        .flat_map(|(i, r)| r.steps.iter().map(move |s| (i, s)))
        .collect();
    let float =
        |f: &dyn Fn(&StepRecord) -> f64| Column::Float(steps.iter().map(|(_, s)| f(s)).collect());
    let count = |f: &dyn Fn(&StepRecord) -> usize| {
        Column::Int(steps.iter().map(|(_, s)| int(f(s))).collect())
    };
    let flag =
        |f: &dyn Fn(&StepRecord) -> bool| Column::Bool(steps.iter().map(|(_, s)| f(s)).collect());
    let columns = vec![
        (
            "run",
            Column::Int(steps.iter().map(|(i, _)| int(*i)).collect()),
        ),
        ("step", count(&|s| s.step)),
        ("mpc_s", float(&|s| s.mpc_s)),
        ("z_updates", count(&|s| s.z_updates_s.len())),
        ("z_s", float(&|s| s.z_updates_s.iter().sum())),
        ("z_median_s", float(&|s| median(&s.z_updates_s))),
        ("iterations", count(&|s| s.iterations)),
        ("predictor_calls", count(&|s| s.predictor_calls)),
        ("cost", float(&|s| s.cost)),
        ("primal_residual", float(&|s| s.primal_residual)),
        ("min_b", float(&|s| s.min_b.unwrap_or(f64::NAN))),
        ("collision", flag(&|s| s.collision)),
        (
            "status",
            Column::Text(steps.iter().map(|(_, s)| s.status.to_string()).collect()),
        ),
        (
            "decided_by",
            Column::Text(steps.iter().map(|(_, s)| s.decided_by.label()).collect()),
        ),
        ("violation_safety", float(&|s| s.violation.safety)),
        ("violation_heading", float(&|s| s.violation.heading)),
        ("violation_corridor", float(&|s| s.violation.corridor)),
        ("violation_edge", float(&|s| s.violation.road_edge)),
        ("violation_lane", float(&|s| s.violation.lane)),
        ("delta", float(&|s| s.delta)),
        ("accel", float(&|s| s.accel)),
        ("x", float(&|s| s.ego[0])),
        ("y", float(&|s| s.ego[1])),
        ("psi", float(&|s| s.ego[2])),
        ("v", float(&|s| s.ego[3])),
        ("y_goal", float(&|s| s.y_goal)),
        ("v_planned", float(&|s| s.v_planned)),
        (
            "lane_violation",
            Column::Int(
                steps
                    .iter()
                    .map(|(_, s)| s.lane_violation.map_or(-1, |v| int(v.step)))
                    .collect(),
            ),
        ),
        ("road_excess", float(&|s| s.metrics.road_excess)),
        ("off_road", flag(&|s| s.metrics.off_road)),
        ("straddle", flag(&|s| s.metrics.straddle)),
        ("in_target_lane", flag(&|s| s.metrics.in_target_lane)),
        (
            "traffic_v",
            float(&|s| s.metrics.traffic_v.unwrap_or(f64::NAN)),
        ),
        ("slow", flag(&|s| s.metrics.slow)),
        ("slow_planned", flag(&|s| s.metrics.slow_planned)),
        (
            "lead_gap",
            float(&|s| s.metrics.lead_gap.unwrap_or(f64::INFINITY)),
        ),
        ("slow_planned_free", flag(&|s| s.metrics.slow_planned_free)),
        ("ttc", float(&|s| s.metrics.ttc.unwrap_or(f64::INFINITY))),
        ("progress", float(&|s| s.metrics.progress)),
        (
            "jerk",
            float(&|s| s.metrics.kinematics.jerk.unwrap_or(f64::NAN)),
        ),
        ("yaw_rate", float(&|s| s.metrics.kinematics.yaw_rate)),
        ("lat_accel", float(&|s| s.metrics.kinematics.lat_accel)),
        (
            "yaw_accel",
            float(&|s| s.metrics.kinematics.yaw_accel.unwrap_or(f64::NAN)),
        ),
    ];
    Table { columns }
}

/// The collision columns ([`COLLISION_COLUMNS`]) of a batch run on `scenes`; `run` is the
/// row of the run in [`run_table`], `other_id` the other vehicle's source id, `free_gap`
/// the run's ([`crate::metrics::free_gap`]).
#[must_use]
pub fn collision_table(scenes: &[Scenario], outputs: &[RunOutput]) -> Table {
    let events: Vec<(usize, &RunRecord, &Collision)> = outputs
        .iter()
        .enumerate()
        .filter_map(|(i, o)| o.result.as_ref().ok().map(|r| (i, r)))
        .flat_map(|(i, r)| r.collisions.iter().map(move |c| (i, r, c)))
        .collect();
    let id_of = |i: usize, c: &Collision| scenes[outputs[i].spec.scene].agent_ids[c.other];
    let float = |f: &dyn Fn(&Collision) -> f64| {
        Column::Float(events.iter().map(|(_, _, c)| f(c)).collect())
    };
    let flag = |f: &dyn Fn(&Collision) -> bool| {
        Column::Bool(events.iter().map(|(_, _, c)| f(c)).collect())
    };
    let columns = vec![
        (
            "run",
            Column::Int(events.iter().map(|(i, _, _)| int(*i)).collect()),
        ),
        (
            "step",
            Column::Int(events.iter().map(|(_, _, c)| int(c.step)).collect()),
        ),
        (
            "other",
            Column::Int(events.iter().map(|(_, _, c)| int(c.other)).collect()),
        ),
        (
            "other_id",
            Column::Int(events.iter().map(|(i, _, c)| id_of(*i, c)).collect()),
        ),
        ("at_fault", flag(&|c| c.at_fault)),
        ("other_behind", flag(&|c| c.other_behind)),
        ("rear_hit", flag(&|c| c.rear_hit)),
        ("ego_in_lane", flag(&|c| c.ego_in_lane)),
        ("ego_accel", float(&|c| c.ego_accel)),
        ("dx", float(&|c| c.dx)),
        ("dy", float(&|c| c.dy)),
        ("ego_heading", float(&|c| c.ego_heading)),
        ("other_heading", float(&|c| c.other_heading)),
        ("ego_v", float(&|c| c.ego_v)),
        ("other_v", float(&|c| c.other_v)),
        (
            "nuplan_type",
            Column::Text(
                events
                    .iter()
                    .map(|(_, _, c)| c.nuplan_type.as_str().to_string())
                    .collect(),
            ),
        ),
        ("nuplan_at_fault", flag(&|c| c.nuplan_at_fault)),
        (
            "free_gap",
            Column::Float(events.iter().map(|(_, r, _)| r.metrics.free_gap).collect()),
        ),
    ];
    Table { columns }
}

/// Mean and (population) standard deviation; NaN when empty.
fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64;
    (m, var.sqrt())
}

/// What a batch achieved, over the runs that ran. Times in seconds.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Runs that ran.
    pub runs: usize,
    /// Runs that could not run.
    pub failed: usize,
    /// Planning steps over all runs.
    pub planning_steps: usize,
    /// Runs that settled in the target lane.
    pub successes: usize,
    /// Steps to the target of the successful runs: (mean, std).
    pub steps_to_target: (f64, f64),
    /// Runs with a collision.
    pub collisions: usize,
    /// Runs that ended because the ego's centre was in a lane past its end (outcome
    /// `LaneEnded`), and before its begin (`LaneNotBegun`).
    pub lane_out: (usize, usize),
    /// Runs that reached the step limit waiting in a lane that ends ahead (outcome
    /// `Waiting`).
    pub waiting: usize,
    /// Runs per outcome, in [`RunOutcome::ALL`] order.
    pub outcomes: [usize; RunOutcome::ALL.len()],
    /// Collision events with the ego at fault, and runs with at least one.
    pub at_fault: (usize, usize),
    /// Collision events with the ego not at fault, and runs with at least one.
    pub not_at_fault: (usize, usize),
    /// Off-road steps, and runs with at least one.
    pub off_road: (usize, usize),
    /// Runs whose ego starts with a corner beyond the road's edge.
    pub start_overhang_runs: usize,
    /// Steps straddling a lane line.
    pub straddle_steps: usize,
    /// Steps slow in a live lane: executed, planned, planned on a free road
    /// ([`crate::metrics::StepMetrics::slow_planned_free`]).
    pub slow_steps: (usize, usize, usize),
    /// Smallest time to collision over every run (s; +∞ when nobody closed in).
    pub min_ttc: f64,
    /// Runs within every comfort limit.
    pub comfortable: usize,
    /// Mean score over the runs that ran.
    pub score: f64,
    /// Lane-change aborts over all runs.
    pub aborts: usize,
    /// Runs with at least one abort.
    pub aborted_runs: usize,
    /// Planning time per step: (median, p90) (s).
    pub mpc_s: (f64, f64),
    /// Median Z-update time over every Z-update (s).
    pub z_median_s: f64,
    /// Plan cost per step: (mean, std) over finite costs.
    pub cost: (f64, f64),
    /// Steps with status `Unsafe`.
    pub unsafe_steps: usize,
    /// Steps with status `SolverFailed`.
    pub solver_failed_steps: usize,
}

impl Summary {
    /// The summary of a batch's outputs.
    #[must_use]
    pub fn of(outputs: &[RunOutput]) -> Self {
        let records: Vec<&RunRecord> = outputs
            .iter()
            .filter_map(|o| o.result.as_ref().ok())
            .collect();
        let steps = || records.iter().flat_map(|r| r.steps.iter());
        let with_status = |st: StepStatus| steps().filter(|s| s.status == st).count();
        let to_target: Vec<f64> = records
            .iter()
            .filter_map(|r| r.steps_to_target.map(|s| s as f64))
            .collect();
        let mut mpc: Vec<f64> = steps().map(|s| s.mpc_s).collect();
        let z: Vec<f64> = steps()
            .flat_map(|s| s.z_updates_s.iter().copied())
            .collect();
        let costs: Vec<f64> = steps().map(|s| s.cost).filter(|c| c.is_finite()).collect();
        let metrics = || records.iter().map(|r| &r.metrics);
        let events = |f: &dyn Fn(&RunMetrics) -> usize| {
            (
                metrics().map(f).sum(),
                metrics().filter(|m| f(m) > 0).count(),
            )
        };
        Self {
            runs: records.len(),
            failed: outputs.len() - records.len(),
            planning_steps: steps().count(),
            successes: records.iter().filter(|r| r.success).count(),
            steps_to_target: mean_std(&to_target),
            collisions: records.iter().filter(|r| r.collision).count(),
            at_fault: events(&|m| m.collisions_at_fault),
            not_at_fault: events(&|m| m.collisions_not_at_fault),
            off_road: events(&|m| m.off_road_steps),
            start_overhang_runs: metrics().filter(|m| m.start_overhang > 0.0).count(),
            straddle_steps: metrics().map(|m| m.straddle_steps).sum(),
            slow_steps: (
                metrics().map(|m| m.slow_steps).sum(),
                metrics().map(|m| m.slow_planned_steps).sum(),
                metrics().map(|m| m.slow_planned_free_steps).sum(),
            ),
            min_ttc: metrics()
                .filter_map(|m| m.min_ttc)
                .fold(f64::INFINITY, f64::min),
            comfortable: metrics().filter(|m| m.comfort.comfortable).count(),
            score: mean_std(&metrics().map(|m| m.score).collect::<Vec<_>>()).0,
            lane_out: (
                records
                    .iter()
                    .filter(|r| r.outcome == RunOutcome::LaneEnded)
                    .count(),
                records
                    .iter()
                    .filter(|r| r.outcome == RunOutcome::LaneNotBegun)
                    .count(),
            ),
            waiting: records
                .iter()
                .filter(|r| r.outcome == RunOutcome::Waiting)
                .count(),
            outcomes: RunOutcome::ALL.map(|o| records.iter().filter(|r| r.outcome == o).count()),
            aborts: records.iter().map(|r| r.aborts).sum(),
            aborted_runs: records.iter().filter(|r| r.aborts > 0).count(),
            mpc_s: (quantile(&mut mpc, 0.5), quantile(&mut mpc, 0.9)),
            z_median_s: median(&z),
            cost: mean_std(&costs),
            unsafe_steps: with_status(StepStatus::Unsafe),
            solver_failed_steps: with_status(StepStatus::SolverFailed),
        }
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.runs;
        let (sm, ss) = self.steps_to_target;
        writeln!(
            f,
            "runs {n} (+{} that could not run), planning steps {}",
            self.failed, self.planning_steps
        )?;
        writeln!(
            f,
            "success rate {:.1} % ({}/{n}); steps to target {sm:.1} ± {ss:.1} ({:.1} ± {:.1} s)",
            100.0 * self.successes as f64 / n.max(1) as f64,
            self.successes,
            sm * nudge_predictor::DT,
            ss * nudge_predictor::DT
        )?;
        writeln!(
            f,
            "runs with a collision: {}; collisions at fault {} (in {} runs), not at fault {} (in {} runs)",
            self.collisions,
            self.at_fault.0,
            self.at_fault.1,
            self.not_at_fault.0,
            self.not_at_fault.1
        )?;
        let outcomes: Vec<String> = RunOutcome::ALL
            .iter()
            .zip(self.outcomes)
            .filter(|(_, n)| *n > 0)
            .map(|(o, n)| format!("{o} {n}"))
            .collect();
        writeln!(f, "outcomes: {}", outcomes.join(", "))?;
        if self.lane_out != (0, 0) {
            writeln!(
                f,
                "runs ended in a lane past its end (LaneEnded): {}; before its begin (LaneNotBegun): {}",
                self.lane_out.0, self.lane_out.1
            )?;
        }
        if self.waiting > 0 {
            writeln!(
                f,
                "runs waiting before the end of their lane at the step limit (Waiting): {}",
                self.waiting
            )?;
        }
        writeln!(
            f,
            "off-road steps {} (in {} runs; {} egos start over the road's edge); steps straddling a lane line {}",
            self.off_road.0, self.off_road.1, self.start_overhang_runs, self.straddle_steps
        )?;
        writeln!(
            f,
            "steps slow in a live lane: executed {}, planned {} (on a free road {}); min time to collision {:.2} s",
            self.slow_steps.0, self.slow_steps.1, self.slow_steps.2, self.min_ttc
        )?;
        writeln!(
            f,
            "comfortable runs {}/{n}; mean score {:.3}",
            self.comfortable, self.score
        )?;
        writeln!(
            f,
            "lane-change aborts: {} in {} runs",
            self.aborts, self.aborted_runs
        )?;
        writeln!(
            f,
            "planning time per step: median {:.2} ms, p90 {:.2} ms; Z-update median {:.3} ms",
            self.mpc_s.0 * 1e3,
            self.mpc_s.1 * 1e3,
            self.z_median_s * 1e3
        )?;
        writeln!(
            f,
            "plan cost mean ± std: {:.2} ± {:.2}",
            self.cost.0, self.cost.1
        )?;
        writeln!(
            f,
            "steps with status Unsafe: {}; with a Clarabel failure (SolverFailed): {}",
            self.unsafe_steps, self.solver_failed_steps
        )
    }
}

/// A step's flags: `O` off-road, `S` straddling, `L` slow in a live lane, `T` centre inside
/// the target lane; `.` when none.
fn step_flags(st: &StepRecord) -> String {
    let m = &st.metrics;
    let f: String = [
        (m.off_road, 'O'),
        (m.straddle, 'S'),
        (m.slow, 'L'),
        (m.in_target_lane, 'T'),
    ]
    .iter()
    .filter(|(on, _)| *on)
    .map(|(_, c)| *c)
    .collect();
    if f.is_empty() { ".".into() } else { f }
}

/// The per-step table of one run, as the CLI prints it (flags: `O` off-road, `S` straddling,
/// `L` slow in a live lane, `T` centre inside the target lane).
#[must_use]
pub fn step_listing(r: &RunRecord) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "run {} seed {} ({} vehicles, target lane {} at y = {:.2} m, predictor {}, world {})",
        r.scenario, r.seed, r.n_agents, r.target_lane, r.y_target, r.predictor, r.world
    );
    let _ = writeln!(
        s,
        "{:>4} {:>9} {:>9} {:>5} {:>6} {:>10} {:>9} {:>7} {:>7} {:>8} {:>8} {:>6} {:>6} {:>6} {:>4} {:>6} {:>4} status",
        "step",
        "mpc_ms",
        "zmed_ms",
        "iters",
        "calls",
        "cost",
        "primal",
        "min_b",
        "delta",
        "accel",
        "x",
        "y",
        "y_goal",
        "v",
        "coll",
        "ttc_s",
        "flag"
    );
    for st in &r.steps {
        let _ = writeln!(
            s,
            "{:>4} {:>9.2} {:>9.3} {:>5} {:>6} {:>10.2} {:>9.2e} {:>7} {:>7.3} {:>8.2} {:>8.1} {:>6.2} {:>6.2} {:>6.2} {:>4} {:>6} {:>4} {}",
            st.step,
            st.mpc_s * 1e3,
            median(&st.z_updates_s) * 1e3,
            st.iterations,
            st.predictor_calls,
            st.cost,
            st.primal_residual,
            st.min_b
                .map_or_else(|| "-".to_string(), |b| format!("{b:.2}")),
            st.delta,
            st.accel,
            st.ego[0],
            st.ego[1],
            st.y_goal,
            st.ego[3],
            if st.collision { "YES" } else { "no" },
            st.metrics
                .ttc
                .map_or_else(|| "-".to_string(), |t| format!("{t:.2}")),
            step_flags(st),
            st.status
        );
    }
    let m = &r.metrics;
    let _ = writeln!(
        s,
        "success {} {}, collision {} (at fault {}, not at fault {}), lane-change aborts {}",
        r.success,
        r.steps_to_target.map_or_else(
            || "(not settled in the target lane)".to_string(),
            |n| format!("after {n} steps")
        ),
        r.collision,
        m.collisions_at_fault,
        m.collisions_not_at_fault,
        r.aborts
    );
    let _ = writeln!(
        s,
        "off-road steps {}, straddling {}, slow {} (planned {}, on a free road {}), progress {:.1} m, score {:.3}",
        m.off_road_steps,
        m.straddle_steps,
        m.slow_steps,
        m.slow_planned_steps,
        m.slow_planned_free_steps,
        m.progress,
        m.score
    );
    s
}
