//! `nudge simulate`: closed-loop runs in parallel over a directory of scenes, the per-step
//! table of one run, the summary, and the records as CSV and JSON. Everything but the
//! argument parsing and the file writing is `nudge_sim`, shared with Python.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use clap::Args;
use nudge_planner::{PlannerSettings, Scenario};
use nudge_predictor::{assets_dir, scenes_dir};
use nudge_sim::defaults;
use nudge_sim::{Batch, BatchRequest, Cancel, Keep, Progress, RunOutput, SimConfig, World};
use nudge_sim::{Summary, step_listing};

use crate::animate::{AnimationSettings, Reel, animate, find_ffmpeg};
use crate::provenance::{Inputs, Provenance};

/// The closed-loop defaults the flags' help shows.
const DEFAULT: SimConfig = SimConfig::DEFAULT;

/// `text [default: value]`.
fn noted(text: &str, value: impl std::fmt::Display) -> String {
    format!("{text} [default: {value}]")
}

/// Arguments of `nudge simulate`. Closed-loop settings come from `--config` (a `SimConfig`
/// JSON file; its defaults otherwise), each overridable by its own flag.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Directory of "nudge.scenario/1" or "/2" `.safetensors` files (run in sorted file-name order)
    /// [default: <assets>/scenes, the shipped real scenes].
    #[arg(long)]
    pub scenes: Option<PathBuf>,
    /// Planning predictor: teacher, student, constant_velocity, or a weights file.
    #[arg(long, default_value = defaults::PREDICTOR.as_str())]
    pub predictor: PathBuf,
    #[arg(long, help = noted("World model of a teacher world: teacher or a teacher weights file", defaults::WORLD_PREDICTOR))]
    pub world_predictor: Option<PathBuf>,
    /// Driver population of an idm world ("nudge.idm/1" JSON)
    /// [default: <assets>/worlds/idm.json].
    #[arg(long)]
    pub idm: Option<PathBuf>,
    /// Directory of the named models (<assets>/models/<name>.safetensors), worlds
    /// (<assets>/worlds/idm.json) and the shipped scenes [default: $NUDGE_ASSETS, else the
    /// assets shipped with this nudge: ./assets for the binary of a checkout, the package's
    /// own for the pip-installed command].
    #[arg(long)]
    pub assets: Option<PathBuf>,
    /// Planner settings JSON (missing fields default).
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Ablate the predicted reaction (planner setting `ablate_reaction` = true, over
    /// --settings): the planner's predictor sees the ego's keep-lane path instead of each
    /// candidate, so the predicted traffic cannot depend on the ego's plan.
    #[arg(long)]
    pub ablate_reaction: bool,
    /// Closed-loop settings JSON (`SimConfig`; missing fields default).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Base seed: run r of scene i draws its target lane from seed + i·runs + r.
    #[arg(long, default_value_t = defaults::SEED)]
    pub seed: u64,
    /// Runs per scene.
    #[arg(long, default_value_t = defaults::RUNS_PER_SCENE)]
    pub runs: usize,
    /// Worker threads (each planner call is single-threaded) [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
    #[arg(long, value_parser = clap::builder::ValueParser::new(parse_world),
          help = noted("How the other vehicles move: teacher, idm or log_replay", DEFAULT.world))]
    pub world: Option<World>,
    #[arg(long, help = noted("Most planning steps per run", DEFAULT.max_steps))]
    pub max_steps: Option<usize>,
    #[arg(long, help = noted("Settled when |y − y_target| ≤ this (m) ...", DEFAULT.settle_y))]
    pub settle_y: Option<f64>,
    #[arg(long, help = noted("... and |ψ| ≤ this (rad) ...", DEFAULT.settle_psi))]
    pub settle_psi: Option<f64>,
    #[arg(long, help = noted("... for this many consecutive steps", DEFAULT.settle_steps))]
    pub settle_steps: Option<usize>,
    #[arg(long, help = noted(
        "Abort a lane change after this many consecutive steps without a safe plan while the \
         ego is not yet inside the target lane (it aims at its own lane, then retries); 0 disables",
        DEFAULT.abort_after,
    ))]
    pub abort_after: Option<usize>,
    #[arg(long, help = noted("Steps an aborted lane change keeps to the ego's own lane before retrying", DEFAULT.abort_hold))]
    pub abort_hold: Option<usize>,
    #[arg(long, help = noted(
        "Also abort a lane change whose ego moved less than this (m) towards the target lane on \
         each of abort_after steps while straddling the lane line before crossing it; 0 disables",
        DEFAULT.stall_progress,
    ))]
    pub stall_progress: Option<f64>,
    #[arg(long, help = noted(
        "Abort a lane change whose ego starts with its box across a line of its own lane after \
         this many steps without a safe plan (before its first safe plan); 0 disables",
        DEFAULT.start_abort_after,
    ))]
    pub start_abort_after: Option<usize>,
    #[arg(long, help = noted(
        "Gap seeking: while a target-lane vehicle alongside blocks the lane change, aim this \
         much (m/s) above its speed when the ego will be ahead of it, else below; 0 disables",
        DEFAULT.gap_speed,
    ))]
    pub gap_speed: Option<f64>,
    #[arg(long, help = noted(
        "Gap seeking: bumper gap along the road (m) below which a target-lane vehicle blocks",
        DEFAULT.gap_window,
    ))]
    pub gap_window: Option<f64>,
    #[arg(long, help = noted(
        "Crawl reference: once the ego's starting speed is below this fraction of the median \
         speed of the goal lane's vehicles within 50 m, its reference speed keeps up with that \
         median; 0 disables",
        DEFAULT.crawl_fraction,
    ))]
    pub crawl_fraction: Option<f64>,
    #[arg(long, help = noted(
        "At-fault rule: an ego hit from behind while inside one lane is not at fault only if it \
         braked no harder than this (m/s²)",
        DEFAULT.fault_brake_limit,
    ))]
    pub fault_brake_limit: Option<f64>,
    #[arg(long, help = noted(
        "Log replay past a vehicle's log: the share of its last sideways displacement it \
         repeats per step (its speed along the road held); 1 is constant velocity, 0 holds \
         its lateral position",
        DEFAULT.replay_lateral_decay,
    ))]
    pub replay_lateral_decay: Option<f64>,
    /// Output directory for steps.csv, runs.csv, collisions.csv, records.json and
    /// provenance.json (what made them: version, git commit, command, settings, file hashes,
    /// seeds, machine; docs/records.md).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// No progress bar (it is drawn on stderr only when stderr is a terminal).
    #[arg(long)]
    pub no_progress: bool,
    /// Print the per-step table of the first run even when running many.
    #[arg(long)]
    pub verbose_run: bool,
    #[command(flatten)]
    pub commonroad: super::commonroad::CommonRoadArgs,
    /// Trace every step (its plan and the predicted reaction of the others, kept in
    /// records.json) and write an animation of each run into <out>/animations:
    /// <scene>-seed<seed>.gif, and .mp4 when ffmpeg is on PATH. Needs --out.
    #[arg(long)]
    pub animate: bool,
    /// Animate only the first N runs that ran [default: every run].
    #[arg(long, value_name = "N", requires = "animate")]
    pub animate_runs: Option<usize>,
}

fn parse_world(s: &str) -> Result<World, String> {
    s.parse()
        .map_err(|e: nudge_sim::SimConfigError| e.to_string())
}

impl SimulateArgs {
    /// The closed-loop settings: `--config` (or the defaults) with the flags applied.
    fn sim_config(&self) -> Result<SimConfig, String> {
        let mut c = match &self.config {
            Some(p) => SimConfig::from_file(p).map_err(|e| format!("{}: {e}", p.display()))?,
            None => SimConfig::default(),
        };
        c.world = self.world.unwrap_or(c.world);
        c.max_steps = self.max_steps.unwrap_or(c.max_steps);
        c.settle_y = self.settle_y.unwrap_or(c.settle_y);
        c.settle_psi = self.settle_psi.unwrap_or(c.settle_psi);
        c.settle_steps = self.settle_steps.unwrap_or(c.settle_steps);
        c.abort_after = self.abort_after.unwrap_or(c.abort_after);
        c.abort_hold = self.abort_hold.unwrap_or(c.abort_hold);
        c.stall_progress = self.stall_progress.unwrap_or(c.stall_progress);
        c.start_abort_after = self.start_abort_after.unwrap_or(c.start_abort_after);
        c.gap_speed = self.gap_speed.unwrap_or(c.gap_speed);
        c.gap_window = self.gap_window.unwrap_or(c.gap_window);
        c.crawl_fraction = self.crawl_fraction.unwrap_or(c.crawl_fraction);
        c.fault_brake_limit = self.fault_brake_limit.unwrap_or(c.fault_brake_limit);
        c.replay_lateral_decay = self.replay_lateral_decay.unwrap_or(c.replay_lateral_decay);
        Ok(c)
    }

    /// The planner settings: `--settings` or the defaults, with `--ablate-reaction` applied.
    fn planner_settings(&self) -> Result<PlannerSettings, String> {
        let mut s = match &self.settings {
            Some(p) => {
                PlannerSettings::from_file(p).map_err(|e| format!("{}: {e}", p.display()))?
            }
            None => PlannerSettings::default(),
        };
        s.safety.ablate_reaction |= self.ablate_reaction;
        Ok(s)
    }
}

/// How often the progress bar is redrawn.
const PROGRESS_TICK: Duration = Duration::from_millis(100);

/// Runs `batch`, drawing a progress bar with the runs done and the time left on stderr while
/// it runs when `show` (the caller checks that stderr is a terminal); the outputs are those of
/// [`Batch::run`] either way.
fn run_with_progress(
    batch: &Batch,
    keep: Keep,
    show: bool,
    policy: Option<&nudge_sim::PolicyFactory<'_>>,
) -> Vec<RunOutput> {
    let cancel = Cancel::new();
    let progress = Progress::new();
    if !show {
        return batch.run_counted(keep, &cancel, None, policy, &progress);
    }
    let total = batch.specs.len() as u64;
    let bar = indicatif::ProgressBar::with_draw_target(
        Some(total),
        indicatif::ProgressDrawTarget::stderr(),
    );
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{elapsed_precise} [{wide_bar}] {pos}/{len} runs, {eta} left",
    ) {
        bar.set_style(style);
    }
    /// Sets its flag when dropped: the ticker stops even when the batch panics.
    struct Finish<'f>(&'f AtomicBool);
    impl Drop for Finish<'_> {
        fn drop(&mut self) {
            self.0.store(true, Ordering::Relaxed);
        }
    }
    let finished = AtomicBool::new(false);
    let outputs = std::thread::scope(|scope| {
        scope.spawn(|| {
            while !finished.load(Ordering::Relaxed) {
                bar.set_position(progress.done() as u64);
                std::thread::sleep(PROGRESS_TICK);
            }
        });
        let _finish = Finish(&finished);
        batch.run_counted(keep, &cancel, None, policy, &progress)
    });
    bar.finish_and_clear();
    outputs
}

/// Writes an animation of each of the first `n` runs of `outputs` that ran into the directory
/// `dir` (`<scene>-seed<seed>.gif`, and `.mp4` when ffmpeg is on `PATH`), printing each file
/// with its frame count, size and rendering time.
fn animate_runs(
    dir: &Path,
    scenes: &[Scenario],
    outputs: &[nudge_sim::RunOutput],
    n: usize,
) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let ffmpeg = find_ffmpeg();
    if ffmpeg.is_none() {
        println!("ffmpeg not found on PATH: animations as GIF only (no MP4)");
    }
    let settings = AnimationSettings::default();
    let ran = outputs
        .iter()
        .filter_map(|o| Some((o.spec, o.result.as_ref().ok()?)));
    for (spec, rec) in ran.take(n) {
        let t0 = Instant::now();
        let reel = Reel::from_run(&scenes[spec.scene], rec).map_err(|e| e.to_string())?;
        let stem = format!("{}-seed{}", rec.scenario, spec.seed);
        let gif = dir.join(format!("{stem}.gif"));
        let mp4 = dir.join(format!("{stem}.mp4"));
        let video = ffmpeg.as_deref().map(|f| (mp4.as_path(), f));
        let w = animate(&reel, &settings, &gif, video).map_err(|e| e.to_string())?;
        let files: Vec<String> = std::iter::once(&w.gif)
            .chain(w.mp4.as_ref())
            .map(|p| p.display().to_string())
            .collect();
        println!(
            "animation: {} ({} frames, {}x{} px, {:.2} s)",
            files.join(" and "),
            w.frames,
            w.size.0,
            w.size.1,
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// Why `nudge simulate` stopped short of [`ExitStatus::Success`]/[`ExitStatus::RunsFailed`]
/// (its exit status: [`Stop::status`]).
///
/// [`ExitStatus::Success`]: super::ExitStatus::Success
/// [`ExitStatus::RunsFailed`]: super::ExitStatus::RunsFailed
#[derive(Debug)]
pub enum Stop {
    /// Refused before any run (exit 1): the message names the argument, setting or file.
    Refused(String),
    /// The runs ran but an output (records, solution, animation) could not be written or
    /// made (exit 4): the message names the file.
    Output(String),
}

impl From<String> for Stop {
    fn from(message: String) -> Self {
        Self::Refused(message)
    }
}

impl Stop {
    /// The exit status: [`super::ExitStatus::Refused`] or [`super::ExitStatus::OutputFailed`].
    #[must_use]
    pub fn status(&self) -> super::ExitStatus {
        match self {
            Self::Refused(_) => super::ExitStatus::Refused,
            Self::Output(_) => super::ExitStatus::OutputFailed,
        }
    }

    /// The message.
    #[must_use]
    pub fn message(&self) -> &str {
        match self {
            Self::Refused(m) | Self::Output(m) => m,
        }
    }
}

/// Runs `nudge simulate` (the named models and the default scenes under `--assets`, else
/// under [`assets_dir`] of `shipped_assets`): every argument is checked by the library's
/// [`BatchRequest::prepare`] (the one validation `nudge.simulate` uses too) before any run
/// starts. Returns the number of runs that could not run (they are reported on stderr).
///
/// # Errors
/// A message naming the problem, before any run: unreadable scenes or settings, invalid or
/// incompatible settings, missing weights, a bad count, an output path that cannot be a
/// directory, `--animate` without `--out`; after the runs, an output that cannot be written.
pub fn run(a: &SimulateArgs, shipped_assets: &Path) -> Result<usize, Stop> {
    if a.animate && a.out.is_none() {
        return Err(Stop::Refused(
            "--animate needs --out (the animations go to <out>/animations)".into(),
        ));
    }
    let settings = a.planner_settings()?;
    let mut config = a.sim_config()?;
    let assets = a
        .assets
        .clone()
        .unwrap_or_else(|| assets_dir(shipped_assets));
    let commonroad = a.commonroad.prepare(a.out.as_deref())?;
    if let Some(c) = &commonroad {
        config = c.goal_config(&config)?;
    }
    let scene_paths = match &commonroad {
        Some(c) => vec![c.scenario_path.clone()],
        None => {
            let scenes = a.scenes.clone().unwrap_or_else(|| scenes_dir(&assets));
            Scenario::paths_in(&scenes).map_err(|e| e.to_string())?
        }
    };
    let batch = BatchRequest {
        scene_paths: &scene_paths,
        predictor: &a.predictor,
        world_predictor: a.world_predictor.as_deref(),
        idm: a.idm.as_deref(),
        assets: &assets,
        seed: a.seed,
        runs_per_scene: a.runs,
        scene_seeds: None,
        threads: a.threads,
        settings: &settings,
        config: &config,
    }
    .prepare()
    .map_err(|e| e.to_string())?;
    if let Some(dir) = &a.out {
        crate::records::prepare_dir(dir, "--out")?;
    }
    let keep = Keep {
        examples: false,
        traces: a.animate,
    };
    let show = !a.no_progress && std::io::stderr().is_terminal();
    // A planning problem's goal: every run driven to it (CommonRoad, crate::commonroad::goal).
    let goal = commonroad.as_ref().and_then(|c| c.goal.map(|g| (c, g)));
    let factory = goal.map(|(c, g)| {
        let s = &settings;
        move |_: &Scenario, _: u64| c.goal_policy(g, s)
    });
    let outputs = run_with_progress(&batch, keep, show, factory.as_ref().map(|f| f as _));
    let scenes = &batch.scenes;
    let failed: Vec<String> = outputs
        .iter()
        .filter_map(|o| {
            let e = o.result.as_ref().err()?;
            let name = &scenes[o.spec.scene].name;
            Some(format!("run on {name} seed {}: {e}", o.spec.seed))
        })
        .collect();
    for f in &failed {
        eprintln!("could not run: {f}");
    }
    let first = outputs.iter().find_map(|o| o.result.as_ref().ok());
    if let (Some(first), true) = (first, outputs.len() == 1 || a.verbose_run) {
        println!("{}", step_listing(first));
    }
    println!("{}", Summary::of(&outputs));
    if let Some(dir) = &a.out {
        let (mut extra, lines) = match &commonroad {
            Some(c) => c
                .solution_files(&outputs, &settings)
                .map_err(Stop::Output)?,
            None => (Vec::new(), Vec::new()),
        };
        let inputs = Inputs {
            settings: (&settings, a.settings.as_deref()),
            config: (&config, a.config.as_deref()),
            assets: &assets,
            predictor: &a.predictor,
            world_predictor: a.world_predictor.as_deref(),
            idm: a.idm.as_deref(),
            scene_paths: &scene_paths,
            specs: &batch.specs,
            seed: (a.seed, a.runs),
            threads: batch.threads(),
        };
        let command = std::env::args_os()
            .map(|s| s.to_string_lossy().into_owned())
            .collect();
        let provenance = Provenance::new(&inputs, command).map_err(Stop::Output)?;
        extra.push(provenance.file().map_err(Stop::Output)?);
        crate::records::write_records(dir, scenes, &outputs, &extra).map_err(Stop::Output)?;
        println!(
            "records written to {} (manifest {})",
            dir.display(),
            crate::files::MANIFEST
        );
        for line in lines {
            println!("{line}");
        }
        if a.animate {
            let n = a.animate_runs.unwrap_or(usize::MAX);
            animate_runs(&dir.join("animations"), scenes, &outputs, n).map_err(Stop::Output)?;
        }
    }
    if let Some(why) = failed.first() {
        eprintln!(
            "error: {} of {} runs could not run (first: {why})",
            failed.len(),
            outputs.len()
        );
    }
    Ok(failed.len())
}
