//! Batches of closed-loop runs, as both front ends (the `nudge` CLI and `nudge.simulate`) run
//! them: the run-spec rule ([`run_specs`]), the predictors of a batch resolved once
//! ([`Predictors`]), and [`simulate_many`] on a rayon pool.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use nudge_predictor::{Predictor, PredictorKind, PredictorSpec, Recording, Records};
use rayon::prelude::*;

use crate::error::SimError;
use crate::policy::Policy;
use nudge_planner::scenario::Scenario;
use nudge_planner::settings::PlannerSettings;

use super::config::{SimConfig, World};
use super::idm::{IdmPopulation, idm_path};
use super::records::RunRecord;
use super::run::{Cancel, RunControl, simulate_policy, simulate_with};
use super::world::WorldModel;

/// The front ends' defaults besides [`SimConfig::default`] and [`PlannerSettings::default`]
/// (one source for the CLI and Python).
pub mod defaults {
    use nudge_predictor::PredictorKind;

    /// The planning predictor.
    pub const PREDICTOR: PredictorKind = PredictorKind::Student;
    /// The world model of a `teacher` world (a named model under the assets directory).
    pub const WORLD_PREDICTOR: PredictorKind = PredictorKind::Teacher;
    /// The base seed.
    pub const SEED: u64 = 0;
    /// Runs per scene.
    pub const RUNS_PER_SCENE: usize = 1;
}

/// Most runs one batch may hold.
pub const MAX_RUNS: usize = 1_000_000;
/// Most worker threads of a batch.
pub const MAX_THREADS: usize = 256;

/// The rayon pool of a batch: `threads` workers (`None`: one per core).
///
/// # Errors
/// [`SimError::Runs`] (field `threads`) for 0 or more than [`MAX_THREADS`] threads, or when
/// the pool cannot start.
pub fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool, SimError> {
    let bad = |reason: String| SimError::Runs {
        field: "threads",
        reason,
    };
    if let Some(t) = threads
        && !(1..=MAX_THREADS).contains(&t)
    {
        return Err(bad(format!(
            "must be in 1..={MAX_THREADS} (or unset for all cores), got {t}"
        )));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()
        .map_err(|e| {
            let n = threads.map_or_else(
                || "one thread per core".to_string(),
                |t| format!("{t} threads"),
            );
            bad(format!("cannot start {n}: {e}"))
        })
}

/// One run of a batch: which scene (index into the batch's scenes) and which seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunSpec {
    /// Index into the scene slice.
    pub scene: usize,
    /// Target-lane seed.
    pub seed: u64,
}

/// The runs of a batch: scene-major over `n_scenes` scenes (in the given order), `runs_per_scene`
/// each; scene i, run r gets seed `scene_seeds[i] + r` when per-scene seeds are given, else
/// `seed + i · runs_per_scene + r`.
///
/// # Errors
/// [`SimError::Runs`] for zero runs per scene, a number of per-scene seeds other than
/// `n_scenes`, more than [`MAX_RUNS`] runs, or a seed beyond `u64::MAX`.
///
/// # Examples
///
/// ```
/// use nudge_sim::{RunSpec, run_specs};
///
/// let specs = run_specs(2, 2, 10, None)?;
/// let seeds: Vec<(usize, u64)> = specs.iter().map(|r| (r.scene, r.seed)).collect();
/// assert_eq!(seeds, [(0, 10), (0, 11), (1, 12), (1, 13)]);
/// let per_scene = run_specs(2, 2, 10, Some(&[7, 3]))?;
/// assert_eq!(per_scene[2], RunSpec { scene: 1, seed: 3 });
/// # Ok::<(), nudge_sim::SimError>(())
/// ```
pub fn run_specs(
    n_scenes: usize,
    runs_per_scene: usize,
    seed: u64,
    scene_seeds: Option<&[u64]>,
) -> Result<Vec<RunSpec>, SimError> {
    let bad = |field: &'static str, reason: String| SimError::Runs { field, reason };
    if runs_per_scene == 0 {
        return Err(bad("runs", "must be at least 1".into()));
    }
    if let Some(s) = scene_seeds
        && s.len() != n_scenes
    {
        return Err(bad(
            "scene_seeds",
            format!("expected one seed per scene ({n_scenes}), got {}", s.len()),
        ));
    }
    let total = n_scenes
        .checked_mul(runs_per_scene)
        .filter(|&n| n <= MAX_RUNS)
        .ok_or_else(|| {
            bad(
                "runs",
                format!("{n_scenes} scenes × {runs_per_scene} runs exceeds {MAX_RUNS} runs"),
            )
        })?;
    let mut specs = Vec::with_capacity(total);
    for scene in 0..n_scenes {
        let base = match scene_seeds {
            Some(s) => Some(s[scene]),
            None => (scene as u64)
                .checked_mul(runs_per_scene as u64)
                .and_then(|o| seed.checked_add(o)),
        };
        for r in 0..runs_per_scene as u64 {
            let seed = base.and_then(|b| b.checked_add(r)).ok_or_else(|| {
                bad(
                    "seed",
                    format!("the seed of scene {scene}, run {r} exceeds u64::MAX"),
                )
            })?;
            specs.push(RunSpec { scene, seed });
        }
    }
    Ok(specs)
}

/// The world model of a batch, loaded once.
#[derive(Debug, Clone)]
pub enum WorldSpec {
    /// A `log_replay` world: none.
    LogReplay,
    /// A `teacher` world: the teacher, cloned for every run.
    Teacher(PredictorSpec),
    /// An `idm` world: the driver population, shared by every run.
    Idm(IdmPopulation),
}

impl WorldSpec {
    /// The world it moves.
    #[must_use]
    pub fn world(&self) -> World {
        match self {
            Self::LogReplay => World::LogReplay,
            Self::Teacher(_) => World::Teacher,
            Self::Idm(_) => World::Idm,
        }
    }
}

/// The predictors and the world model of a batch, each loaded once.
#[derive(Debug, Clone)]
pub struct Predictors {
    /// The planning predictor.
    pub planning: PredictorSpec,
    /// The world model.
    pub world: WorldSpec,
}

impl Predictors {
    /// Resolves the planning predictor and the world model of `world`: for a
    /// [`World::Teacher`] world the teacher `world_predictor` (default the shipped teacher),
    /// by name or path ([`PredictorSpec::resolve`], named models under `assets`); for a
    /// [`World::Idm`] world the driver population of the file `idm` (default
    /// [`idm_path`]`(assets)`), each for `horizon` steps.
    ///
    /// # Errors
    /// [`SimError::Model`] when a predictor cannot be loaded; [`SimError::WorldFile`] when
    /// the IDM file cannot be used; [`SimError::WorldModel`] when the world model is not a
    /// teacher, or a world model or IDM file is named for a world that does not use it.
    pub fn resolve(
        predictor: impl AsRef<Path>,
        world: World,
        world_predictor: Option<&Path>,
        idm: Option<&Path>,
        assets: &Path,
        horizon: usize,
    ) -> Result<Self, SimError> {
        let planning = PredictorSpec::resolve(predictor, assets, horizon).map_err(|source| {
            SimError::Model {
                role: "predictor",
                source,
            }
        })?;
        let unused = |what: &str, p: &Path| SimError::WorldModel {
            world: world.as_str(),
            reason: format!("{what} {} would be ignored", p.display()),
        };
        if let (false, Some(p)) = (world == World::Teacher, world_predictor) {
            return Err(unused("world_predictor", p));
        }
        if let (false, Some(p)) = (world == World::Idm, idm) {
            return Err(unused("idm", p));
        }
        let world = match world {
            World::LogReplay => WorldSpec::LogReplay,
            World::Idm => {
                let path = idm.map_or_else(|| idm_path(assets), Path::to_path_buf);
                WorldSpec::Idm(IdmPopulation::from_file(path)?)
            }
            World::Teacher => {
                let name = Path::new(defaults::WORLD_PREDICTOR.as_str());
                let spec = PredictorSpec::resolve(world_predictor.unwrap_or(name), assets, horizon)
                    .map_err(|source| SimError::Model {
                        role: "world_predictor",
                        source,
                    })?;
                if spec.kind() != PredictorKind::Teacher {
                    return Err(SimError::WorldModel {
                        world: world.as_str(),
                        reason: format!("the world model must be a teacher, got a {}", spec.kind()),
                    });
                }
                WorldSpec::Teacher(spec)
            }
        };
        Ok(Self { planning, world })
    }
}

/// One finished run of a batch.
#[derive(Debug)]
pub struct RunOutput {
    /// Which run.
    pub spec: RunSpec,
    /// Its record, or why it could not run.
    pub result: Result<RunRecord, SimError>,
    /// Every distinct candidate the planning predictor evaluated, with its prediction (when
    /// recording).
    pub examples: Option<Records>,
}

/// A count of the finished runs of a batch, shared by the runs and whoever shows progress
/// (a progress bar polling [`Progress::done`] from another thread). Clones share the count.
#[derive(Debug, Clone, Default)]
pub struct Progress(Arc<AtomicUsize>);

impl Progress {
    /// A count at zero.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Runs finished so far (ran, failed or cancelled).
    #[must_use]
    pub fn done(&self) -> usize {
        self.0.load(Ordering::Relaxed)
    }

    /// Counts one more finished run.
    fn finish_one(&self) {
        self.0.fetch_add(1, Ordering::Relaxed);
    }
}

/// Builds the planning predictor of one run (called once per run, on the run's thread).
pub type PlanningFactory<'a> = dyn Fn() -> Box<dyn Predictor> + Sync + 'a;

/// Builds the policy that drives the ego in one run of a batch, given the run's scene and seed
/// (called once per run, on the run's thread): a planner implemented outside nudge, e.g. a
/// Python object. Without one, every run plans with nudge's [`nudge_planner::Planner`].
pub type PolicyFactory<'a> = dyn Fn(&Scenario, u64) -> Box<dyn Policy> + Sync + 'a;

/// What the runs of a batch keep besides their records' columns (both off by default).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Keep {
    /// Every candidate the planning predictor evaluated, with its prediction
    /// ([`RunOutput::examples`]; the planning predictor wrapped in a [`Recording`]).
    pub examples: bool,
    /// Every step's plan and predicted reaction ([`crate::StepRecord::trace`]).
    pub traces: bool,
}

/// Runs every spec of `specs` on `scenes` in parallel on the current rayon pool (each planner
/// call stays single-threaded), with fresh predictors per run, keeping what `keep` asks for.
/// Every run checks `cancel` before each closed-loop step. Outputs come back in the order of
/// `specs`.
pub fn simulate_many(
    scenes: &[Scenario],
    specs: &[RunSpec],
    settings: &PlannerSettings,
    cfg: &SimConfig,
    predictors: &Predictors,
    keep: Keep,
    cancel: &Cancel,
) -> Vec<RunOutput> {
    let planning = || predictors.planning.build();
    let runs = Runs {
        scenes,
        settings,
        cfg,
        world: &predictors.world,
        planning: &planning,
        keep,
        cancel,
        progress: None,
        policy: None,
    };
    runs.simulate(specs)
}

/// What every run of a batch shares, its planning predictor built per run by `planning`
/// (one implemented outside nudge, e.g. a Python object, as well as a [`PredictorSpec`]).
pub struct Runs<'a> {
    /// The scenes the specs index.
    pub scenes: &'a [Scenario],
    /// Planner settings.
    pub settings: &'a PlannerSettings,
    /// Closed-loop settings.
    pub cfg: &'a SimConfig,
    /// The world model.
    pub world: &'a WorldSpec,
    /// Builds each run's planning predictor.
    pub planning: &'a PlanningFactory<'a>,
    /// What the runs keep besides their records' columns.
    pub keep: Keep,
    /// Checked before every closed-loop step.
    pub cancel: &'a Cancel,
    /// Counts every finished run (`None`: not counted).
    pub progress: Option<&'a Progress>,
    /// Builds each run's policy (`None`: nudge's planner from `settings`).
    pub policy: Option<&'a PolicyFactory<'a>>,
}

impl Runs<'_> {
    /// [`simulate_many`] with these parts: every spec in parallel on the current rayon pool,
    /// outputs in the order of `specs`.
    #[must_use]
    pub fn simulate(&self, specs: &[RunSpec]) -> Vec<RunOutput> {
        specs
            .par_iter()
            .map(|&spec| {
                let out = self.run(spec);
                if let Some(p) = self.progress {
                    p.finish_one();
                }
                out
            })
            .collect()
    }

    /// One run.
    fn run(&self, spec: RunSpec) -> RunOutput {
        let sc = &self.scenes[spec.scene];
        if self.cancel.is_cancelled() {
            // Not started: no predictor is built for it.
            return RunOutput {
                spec,
                result: Err(SimError::Cancelled {
                    scene: sc.name.clone(),
                    step: 0,
                }),
                examples: None,
            };
        }
        let control = RunControl {
            cancel: self.cancel,
            trace: self.keep.traces,
        };
        let simulate = |p: &mut dyn Predictor, w: WorldModel<'_>| match self.policy {
            Some(make) => {
                let mut policy = make(sc, spec.seed);
                simulate_policy(
                    sc,
                    self.settings,
                    self.cfg,
                    spec.seed,
                    policy.as_mut(),
                    p,
                    w,
                    control,
                )
            }
            None => simulate_with(sc, self.settings, self.cfg, spec.seed, p, w, control),
        };
        let mut teacher = match self.world {
            WorldSpec::Teacher(t) => Some(t.build()),
            _ => None,
        };
        let world = match (self.world, teacher.as_deref_mut()) {
            (WorldSpec::Teacher(_), Some(t)) => WorldModel::Teacher(t as &mut dyn Predictor),
            (WorldSpec::Idm(p), _) => WorldModel::Idm(p),
            _ => WorldModel::LogReplay,
        };
        let planning = (self.planning)();
        let (result, examples) = if self.keep.examples {
            let mut rec = Recording::new(planning);
            let r = simulate(&mut rec, world);
            (r, Some(rec.records))
        } else {
            let mut p = planning;
            (simulate(p.as_mut(), world), None)
        };
        RunOutput {
            spec,
            result,
            examples,
        }
    }
}
