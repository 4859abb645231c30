//! `nudge simulate`: many closed-loop runs in parallel, a per-step table for one run, a
//! summary, and the records as CSV and JSON.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use clap::{Args, ValueEnum};
use nudge_planner::{
    PlannerSettings, PredictorPair, RunRecord, RunSpec, Scenario, SimConfig, WorldMode,
    simulate_many,
};
use nudge_predictor::{ConstantVelocity, Predictor, PredictorError, load_predictor};

/// Planning predictor choices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PredictorKind {
    /// Social-GAN teacher (recursive, 6 generator calls per prediction).
    Teacher,
    /// Distilled one-pass student.
    Student,
    /// Interaction-unaware constant velocity.
    ConstantVelocity,
}

/// World-model choices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum WorldKind {
    /// The teacher's one-step interactive prediction moves the other vehicles.
    Teacher,
    /// The logged future moves the other vehicles.
    LogReplay,
}

/// Arguments of `nudge simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Directory of "nudge.scenario/1" `.safetensors` files.
    #[arg(long, default_value = "assets/scenes")]
    pub scenes: PathBuf,
    /// Predictor used inside the planner.
    #[arg(long, value_enum, default_value = "student")]
    pub predictor: PredictorKind,
    /// Weights of the planning predictor (default: assets/models/<predictor>.safetensors).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// How the other vehicles move.
    #[arg(long, value_enum, default_value = "teacher")]
    pub world: WorldKind,
    /// Teacher weights for the world model.
    #[arg(long, default_value = "assets/models/teacher.safetensors")]
    pub world_weights: PathBuf,
    /// Planner settings JSON (missing fields default).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Base seed: run r uses scenario r mod #scenes and seed + r for its target lane.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Number of runs.
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// Worker threads (each planner call is single-threaded); default: all cores.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Most planning steps per run.
    #[arg(long, default_value_t = 30)]
    pub max_steps: usize,
    /// Abort a lane change after this many consecutive steps without a safe plan while the ego
    /// is not yet inside the target lane (it aims at its own lane, then retries); 0 disables.
    #[arg(long, default_value_t = SimConfig::default().abort_after)]
    pub abort_after: usize,
    /// Steps an aborted lane change keeps to the ego's own lane before retrying.
    #[arg(long, default_value_t = SimConfig::default().abort_hold)]
    pub abort_hold: usize,
    /// Output directory for steps.csv, runs.csv and records.json.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the per-step table of the first run even when running many.
    #[arg(long)]
    pub verbose_run: bool,
}

fn model_path(kind: PredictorKind, weights: Option<&Path>) -> PathBuf {
    weights.map_or_else(
        || match kind {
            PredictorKind::Teacher => PathBuf::from("assets/models/teacher.safetensors"),
            _ => PathBuf::from("assets/models/student.safetensors"),
        },
        Path::to_path_buf,
    )
}

fn make_pair(a: &SimulateArgs) -> Result<PredictorPair, PredictorError> {
    let plan: Box<dyn Predictor> = match a.predictor {
        PredictorKind::ConstantVelocity => Box::new(ConstantVelocity::default()),
        k => load_predictor(model_path(k, a.weights.as_deref()))?,
    };
    let world = match a.world {
        WorldKind::Teacher => Some(load_predictor(&a.world_weights)?),
        WorldKind::LogReplay => None,
    };
    Ok((plan, world))
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let idx = ((v.len() - 1) as f64 * q).round() as usize;
    v[idx]
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64;
    (m, var.sqrt())
}

fn step_table(r: &RunRecord) -> String {
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
        let mut z = st.z_updates_s.clone();
        let _ = writeln!(
            s,
            "{:>4} {:>9.2} {:>9.3} {:>5} {:>6} {:>10.2} {:>9.2e} {:>7} {:>7.3} {:>8.2} {:>8.1} {:>6.2} {:>6.2} {:>6.2} {:>4} {}",
            st.step,
            st.mpc_s * 1e3,
            quantile(&mut z, 0.5) * 1e3,
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

fn summary(records: &[RunRecord], failed: usize) -> String {
    let n = records.len();
    let succ = records.iter().filter(|r| r.success).count();
    let coll = records.iter().filter(|r| r.collision).count();
    let aborts: usize = records.iter().map(|r| r.aborts).sum();
    let aborted_runs = records.iter().filter(|r| r.aborts > 0).count();
    let steps: Vec<f64> = records
        .iter()
        .filter_map(|r| r.steps_to_target.map(|s| s as f64))
        .collect();
    let mut mpc: Vec<f64> = records
        .iter()
        .flat_map(|r| r.steps.iter().map(|s| s.mpc_s))
        .collect();
    let mut zup: Vec<f64> = records
        .iter()
        .flat_map(|r| r.steps.iter().flat_map(|s| s.z_updates_s.iter().copied()))
        .collect();
    let costs: Vec<f64> = records
        .iter()
        .flat_map(|r| r.steps.iter().map(|s| s.cost))
        .filter(|c| c.is_finite())
        .collect();
    let qp_fail = records
        .iter()
        .flat_map(|r| &r.steps)
        .filter(|s| s.status.starts_with("QpFailed"))
        .count();
    let unsafe_steps = records
        .iter()
        .flat_map(|r| &r.steps)
        .filter(|s| s.status == "Unsafe")
        .count();
    let total_steps: usize = records.iter().map(|r| r.steps.len()).sum();
    let (sm, ss) = mean_std(&steps);
    let (cm, cs) = mean_std(&costs);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "runs {n} (+{failed} that could not run), planning steps {total_steps}"
    );
    let _ = writeln!(
        out,
        "success rate {:.1} % ({succ}/{n}); steps to target {sm:.1} ± {ss:.1} ({:.1} ± {:.1} s)",
        100.0 * succ as f64 / n.max(1) as f64,
        sm * 0.3,
        ss * 0.3
    );
    let _ = writeln!(out, "runs with a collision: {coll}");
    let _ = writeln!(out, "lane-change aborts: {aborts} in {aborted_runs} runs");
    let _ = writeln!(
        out,
        "planning time per step: median {:.2} ms, p90 {:.2} ms; Z-update median {:.3} ms",
        quantile(&mut mpc, 0.5) * 1e3,
        quantile(&mut mpc, 0.9) * 1e3,
        quantile(&mut zup, 0.5) * 1e3
    );
    let _ = writeln!(out, "plan cost mean ± std: {cm:.2} ± {cs:.2}");
    let _ = writeln!(
        out,
        "steps with status Unsafe: {unsafe_steps}; with a Clarabel failure: {qp_fail}"
    );
    out
}

fn write_outputs(dir: &Path, records: &[RunRecord]) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut steps = String::from(
        "run,scenario,seed,predictor,world,step,mpc_s,z_update_median_s,z_updates,iterations,predictor_calls,cost,primal_residual,min_b,collision,status,delta,accel,x,y,psi,v,y_goal\n",
    );
    let mut runs = String::from(
        "run,scenario,seed,predictor,world,n_agents,target_lane,y_target,success,steps_to_target,collision,aborts,steps\n",
    );
    for (i, r) in records.iter().enumerate() {
        let _ = writeln!(
            runs,
            "{i},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.scenario,
            r.seed,
            r.predictor,
            r.world,
            r.n_agents,
            r.target_lane,
            r.y_target,
            r.success,
            r.steps_to_target
                .map_or_else(String::new, |s| s.to_string()),
            r.collision,
            r.aborts,
            r.steps.len()
        );
        for s in &r.steps {
            let mut z = s.z_updates_s.clone();
            let _ = writeln!(
                steps,
                "{i},{},{},{},{},{},{},{},{},{},{},{},{},{},{},\"{}\",{},{},{},{},{},{},{}",
                r.scenario,
                r.seed,
                r.predictor,
                r.world,
                s.step,
                s.mpc_s,
                quantile(&mut z, 0.5),
                s.z_updates_s.len(),
                s.iterations,
                s.predictor_calls,
                s.cost,
                s.primal_residual,
                s.min_b.map_or_else(String::new, |b| b.to_string()),
                s.collision,
                s.status.replace('"', "'"),
                s.delta,
                s.accel,
                s.ego[0],
                s.ego[1],
                s.ego[2],
                s.ego[3],
                s.y_goal
            );
        }
    }
    let write = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).map_err(|e| format!("{}: {e}", p.display()))
    };
    write("steps.csv", &steps)?;
    write("runs.csv", &runs)?;
    let json = serde_json::to_string_pretty(records).map_err(|e| e.to_string())?;
    write("records.json", &json)?;
    Ok(())
}

/// Runs `nudge simulate`.
///
/// # Errors
/// A message naming the problem: unreadable scenes or settings, missing weights, a run that
/// fails for a reason other than a recorded Clarabel failure.
pub fn run(a: &SimulateArgs) -> Result<(), String> {
    if a.runs == 0 {
        return Err("--runs must be at least 1".into());
    }
    let settings = match &a.settings {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            PlannerSettings::from_json(&text).map_err(|e| format!("{}: {e}", p.display()))?
        }
        None => PlannerSettings::default(),
    };
    settings.validate().map_err(|e| e.to_string())?;
    let (scenes, bad) = Scenario::load_dir(&a.scenes).map_err(|e| e.to_string())?;
    for (p, e) in &bad {
        eprintln!("skipping {}: {e}", p.display());
    }
    if scenes.is_empty() {
        return Err(format!("no usable scenario in {}", a.scenes.display()));
    }
    // Fail early (and clearly) on missing weights.
    make_pair(a).map_err(|e| e.to_string())?;
    let cfg = SimConfig {
        max_steps: a.max_steps,
        abort_after: a.abort_after,
        abort_hold: a.abort_hold,
        world: match a.world {
            WorldKind::Teacher => WorldMode::Predictor,
            WorldKind::LogReplay => WorldMode::LogReplay,
        },
        ..SimConfig::default()
    };
    let specs: Vec<RunSpec> = (0..a.runs)
        .map(|r| RunSpec {
            scenario: r % scenes.len(),
            seed: a.seed + r as u64,
        })
        .collect();
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = a.threads {
        pool = pool.num_threads(t.max(1));
    }
    let pool = pool.build().map_err(|e| e.to_string())?;
    let results = pool.install(|| simulate_many(&scenes, &specs, &settings, &cfg, || make_pair(a)));
    let mut records = Vec::new();
    let mut failed = 0;
    for (spec, r) in specs.iter().zip(results) {
        match r {
            Ok(rec) => records.push(rec),
            Err(e) => {
                failed += 1;
                eprintln!(
                    "run on {} seed {} failed: {e}",
                    scenes[spec.scenario].name, spec.seed
                );
            }
        }
    }
    if a.runs == 1 || a.verbose_run {
        if let Some(first) = records.first() {
            println!("{}", step_table(first));
        }
    }
    println!("{}", summary(&records, failed));
    if let Some(dir) = &a.out {
        write_outputs(dir, &records)?;
        println!("records written to {}", dir.display());
    }
    Ok(())
}
