//! Closed-loop records as named columns, and the summary and per-step listing of a batch:
//! the one place that decides what the front ends report. The `nudge` CLI writes these tables
//! as CSV ([`Table::write_csv`]) and prints the [`Summary`] and [`step_listing`]; `nudge.simulate`
//! hands the same columns to Python as numpy arrays.

use std::fmt::{self, Write as _};

use crate::scenario::Scenario;

use super::batch::RunOutput;
use super::records::{RunRecord, StepRecord, StepStatus};

/// Run columns, in order (one row per run, failed runs included).
pub const RUN_COLUMNS: [&str; 14] = [
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
    "error",
];

/// Step columns, in order (one row per planning step of every run that ran).
pub const STEP_COLUMNS: [&str; 20] = [
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
    "delta",
    "accel",
    "x",
    "y",
    "psi",
    "v",
    "y_goal",
];

/// One column's values.
#[derive(Debug, Clone, PartialEq)]
pub enum Column {
    /// Floats; NaN where a value is missing (`min_b` with no vehicle checked, `y_target` of a
    /// failed run).
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
        (
            "collision",
            Column::Bool(steps.iter().map(|(_, s)| s.collision).collect()),
        ),
        (
            "status",
            Column::Text(steps.iter().map(|(_, s)| s.status.to_string()).collect()),
        ),
        ("delta", float(&|s| s.delta)),
        ("accel", float(&|s| s.accel)),
        ("x", float(&|s| s.ego[0])),
        ("y", float(&|s| s.ego[1])),
        ("psi", float(&|s| s.ego[2])),
        ("v", float(&|s| s.ego[3])),
        ("y_goal", float(&|s| s.y_goal)),
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
        Self {
            runs: records.len(),
            failed: outputs.len() - records.len(),
            planning_steps: steps().count(),
            successes: records.iter().filter(|r| r.success).count(),
            steps_to_target: mean_std(&to_target),
            collisions: records.iter().filter(|r| r.collision).count(),
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
        writeln!(f, "runs with a collision: {}", self.collisions)?;
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

/// The per-step table of one run, as the CLI prints it.
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
        "{:>4} {:>9} {:>9} {:>5} {:>6} {:>10} {:>9} {:>7} {:>7} {:>8} {:>8} {:>6} {:>6} {:>6} {:>4} status",
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
        "coll"
    );
    for st in &r.steps {
        let _ = writeln!(
            s,
            "{:>4} {:>9.2} {:>9.3} {:>5} {:>6} {:>10.2} {:>9.2e} {:>7} {:>7.3} {:>8.2} {:>8.1} {:>6.2} {:>6.2} {:>6.2} {:>4} {}",
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
            st.status
        );
    }
    let _ = writeln!(
        s,
        "success {} after {:?} steps, collision {}, lane-change aborts {}",
        r.success, r.steps_to_target, r.collision, r.aborts
    );
    s
}
