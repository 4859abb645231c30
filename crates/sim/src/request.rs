//! One validation of a batch of closed-loop runs for both front ends: [`BatchRequest`] holds
//! what the `nudge simulate` CLI and `nudge.simulate` are asked for, [`BatchRequest::prepare`]
//! checks all of it before any run starts and returns a [`Batch`] ready to run. The two front
//! ends only parse their arguments into a request and format the outputs, so the same bad
//! arguments get the same refusal, word for word, in both.

use std::path::{Path, PathBuf};

use crate::error::SimError;
use nudge_planner::fit;
use nudge_planner::scenario::Scenario;
use nudge_planner::settings::PlannerSettings;

use super::batch::{
    Keep, PlanningFactory, PolicyFactory, Predictors, Progress, RunOutput, RunSpec, Runs,
    WorldSpec, run_specs, thread_pool,
};
use super::config::SimConfig;
use super::run::Cancel;

/// What a front end asks of one batch, unchecked.
#[derive(Debug, Clone, Copy)]
pub struct BatchRequest<'a> {
    /// Scenario files, run in this order (the CLI passes its directory sorted,
    /// [`Scenario::paths_in`]).
    pub scene_paths: &'a [PathBuf],
    /// Planning predictor: a [`nudge_predictor::PredictorKind`] name or a weights path.
    pub predictor: &'a Path,
    /// World model of a `teacher` world (default: the shipped teacher); must be `None` for
    /// `log_replay`.
    pub world_predictor: Option<&'a Path>,
    /// Driver population of an `idm` world (default: the fitted one among the assets, see
    /// [`super::idm_path`]); must be `None` for the other worlds.
    pub idm: Option<&'a Path>,
    /// Directory of the named models.
    pub assets: &'a Path,
    /// Base seed of the run-spec rule ([`run_specs`]).
    pub seed: u64,
    /// Runs per scene.
    pub runs_per_scene: usize,
    /// Per-scene seeds, one per scene.
    pub scene_seeds: Option<&'a [u64]>,
    /// Worker threads (`None`: one per core).
    pub threads: Option<usize>,
    /// Planner settings.
    pub settings: &'a PlannerSettings,
    /// Closed-loop settings.
    pub config: &'a SimConfig,
}

/// A checked batch: every run laid out, the predictors loaded, the scenes read, the pool
/// started. Nothing has run yet.
#[derive(Debug)]
pub struct Batch {
    /// The scenes, in the request's order.
    pub scenes: Vec<Scenario>,
    /// The runs (scene-major).
    pub specs: Vec<RunSpec>,
    /// The predictors, loaded once.
    pub predictors: Predictors,
    /// Planner settings (validated, fitting the predictors and scenes).
    pub settings: PlannerSettings,
    /// Closed-loop settings (validated).
    pub config: SimConfig,
    pool: rayon::ThreadPool,
}

impl BatchRequest<'_> {
    /// Checks everything, cheapest first, and loads what the runs need:
    ///
    /// 1. the planner settings and the closed-loop settings each validate;
    /// 2. at least one scene, at least one run per scene, one per-scene seed per scene, at most
    ///    [`super::MAX_RUNS`] runs, seeds within `u64` ([`run_specs`]);
    /// 3. 1..=[`super::MAX_THREADS`] threads ([`thread_pool`]);
    /// 4. `dt` equal to the 0.3 s of the scenes ([`fit::check_closed_loop`]);
    /// 5. the predictors load and the world model matches the world ([`Predictors::resolve`]),
    ///    and their horizons equal the planner's;
    /// 6. every scene reads and validates ([`Scenario::from_file`]).
    ///
    /// # Errors
    /// The first failing check: [`SimError::Settings`], [`SimError::Config`],
    /// [`SimError::Runs`] (naming the argument), [`SimError::Model`],
    /// [`SimError::WorldModel`], [`SimError::Scenario`].
    pub fn prepare(&self) -> Result<Batch, SimError> {
        self.settings.validate()?;
        self.config.validate()?;
        if self.scene_paths.is_empty() {
            return Err(SimError::Runs {
                field: "scene_paths",
                reason: "no scenario given".into(),
            });
        }
        let specs = run_specs(
            self.scene_paths.len(),
            self.runs_per_scene,
            self.seed,
            self.scene_seeds,
        )?;
        let pool = thread_pool(self.threads)?;
        fit::check_closed_loop(self.settings, &[])?;
        let predictors = Predictors::resolve(
            self.predictor,
            self.config.world,
            self.world_predictor,
            self.idm,
            self.assets,
            self.settings.model.horizon,
        )?;
        let mut fits = vec![(
            predictors.planning.kind().as_str(),
            predictors.planning.horizon(),
        )];
        if let WorldSpec::Teacher(w) = &predictors.world {
            fits.push((w.kind().as_str(), w.horizon()));
        }
        fit::check_closed_loop(self.settings, &fits)?;
        let scenes = self
            .scene_paths
            .iter()
            .map(Scenario::from_file)
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Batch {
            scenes,
            specs,
            predictors,
            settings: self.settings.clone(),
            config: *self.config,
            pool,
        })
    }

    /// [`BatchRequest::prepare`] for a planning predictor the caller builds for every run
    /// itself (one implemented outside nudge, e.g. a Python object), named `name` and
    /// predicting `horizon` steps: `self.predictor` is not read (the batch's
    /// [`Predictors::planning`] is a constant-velocity placeholder, which fits any horizon), and
    /// the settings are checked to fit `name`'s horizon instead ([`fit::check_closed_loop`]).
    /// Run the batch with [`Batch::run_with`].
    ///
    /// # Errors
    /// As [`BatchRequest::prepare`].
    pub fn prepare_foreign(&self, name: &str, horizon: usize) -> Result<Batch, SimError> {
        let placeholder = Path::new(nudge_predictor::PredictorKind::ConstantVelocity.as_str());
        let batch = BatchRequest {
            predictor: placeholder,
            ..*self
        }
        .prepare()?;
        fit::check_closed_loop(self.settings, &[(name, horizon)])?;
        Ok(batch)
    }
}

impl Batch {
    /// Runs every run on the batch's pool ([`crate::simulate_many`]), checking `cancel` before every
    /// closed-loop step and keeping what `keep` asks for (the planning predictor's examples,
    /// the steps' traces). Outputs in the order of [`Batch::specs`].
    #[must_use]
    pub fn run(&self, keep: Keep, cancel: &Cancel) -> Vec<RunOutput> {
        self.run_counted(keep, cancel, None, None, &Progress::new())
    }

    /// [`Batch::run`] with each run's planning predictor built by `planning` (see
    /// [`BatchRequest::prepare_foreign`]).
    #[must_use]
    pub fn run_with(
        &self,
        keep: Keep,
        cancel: &Cancel,
        planning: &PlanningFactory<'_>,
    ) -> Vec<RunOutput> {
        self.run_counted(keep, cancel, Some(planning), None, &Progress::new())
    }

    /// [`Batch::run`] (or [`Batch::run_with`] when `planning` is given) counting every
    /// finished run in `progress`, for a progress display polling it from another thread; the
    /// ego driven by the policy `policy` builds for each run when given (a planner implemented
    /// outside nudge; the settings still give the ego's model, the safety check the records
    /// judge by and the planning horizon), else by nudge's planner. The outputs are those of
    /// the uncounted call.
    #[must_use]
    pub fn run_counted(
        &self,
        keep: Keep,
        cancel: &Cancel,
        planning: Option<&PlanningFactory<'_>>,
        policy: Option<&PolicyFactory<'_>>,
        progress: &Progress,
    ) -> Vec<RunOutput> {
        let build = || self.predictors.planning.build();
        let runs = Runs {
            scenes: &self.scenes,
            settings: &self.settings,
            cfg: &self.config,
            world: &self.predictors.world,
            planning: planning.unwrap_or(&build),
            keep,
            cancel,
            progress: Some(progress),
            policy,
        };
        self.pool.install(|| runs.simulate(&self.specs))
    }

    /// Worker threads of the batch's pool.
    #[must_use]
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::World;
    use nudge_planner::SettingsError;

    fn repo() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    fn scene_paths() -> Vec<PathBuf> {
        Scenario::paths_in(repo().join("assets/scenes")).unwrap()[..2].to_vec()
    }

    fn request<'a>(
        paths: &'a [PathBuf],
        settings: &'a PlannerSettings,
        config: &'a SimConfig,
        assets: &'a Path,
    ) -> BatchRequest<'a> {
        BatchRequest {
            scene_paths: paths,
            predictor: Path::new("constant_velocity"),
            world_predictor: None,
            idm: None,
            assets,
            seed: 0,
            runs_per_scene: 1,
            scene_seeds: None,
            threads: Some(1),
            settings,
            config,
        }
    }

    /// Each request is refused by `prepare` (before anything runs) with an error whose
    /// message contains its expected text.
    fn assert_refused(cases: Vec<(BatchRequest<'_>, &str)>) {
        for (req, want) in cases {
            let msg = req.prepare().err().map(|e| e.to_string());
            assert!(
                msg.as_deref().is_some_and(|m| m.contains(want)),
                "expected {want:?} in {msg:?}"
            );
        }
    }

    /// Every check of the batch's own arguments refuses before anything runs, naming the
    /// argument or file.
    #[test]
    fn every_bad_argument_is_refused_before_any_run() {
        let paths = scene_paths();
        let assets = repo().join("assets");
        let ok = PlannerSettings::default();
        let log = SimConfig {
            world: World::LogReplay,
            ..SimConfig::default()
        };
        let missing = [repo().join("nope.safetensors")];
        let base = request(&paths, &ok, &log, &assets);
        assert_refused(vec![
            (
                BatchRequest {
                    scene_paths: &[],
                    ..base
                },
                "invalid argument `scene_paths`: no scenario given",
            ),
            (
                BatchRequest {
                    runs_per_scene: 0,
                    ..base
                },
                "invalid argument `runs`",
            ),
            (
                BatchRequest {
                    runs_per_scene: 1 << 40,
                    ..base
                },
                "exceeds 1000000 runs",
            ),
            (
                BatchRequest {
                    scene_seeds: Some(&[1]),
                    ..base
                },
                "invalid argument `scene_seeds`",
            ),
            (
                BatchRequest {
                    threads: Some(0),
                    ..base
                },
                "invalid argument `threads`",
            ),
            (
                BatchRequest {
                    scene_paths: &missing,
                    ..base
                },
                "nope.safetensors",
            ),
        ]);
    }

    /// Settings, closed-loop config and world model are checked against each other and the
    /// predictors before anything runs, naming the setting.
    #[test]
    fn every_bad_setting_is_refused_before_any_run() {
        let paths = scene_paths();
        let assets = repo().join("assets");
        let ok = PlannerSettings::default();
        let log = SimConfig {
            world: World::LogReplay,
            ..SimConfig::default()
        };
        let teacher = SimConfig::default();
        let h7 = {
            let mut s = PlannerSettings::default();
            s.model.horizon = 7;
            s
        };
        let slow = {
            let mut s = PlannerSettings::default();
            s.model.dt = 0.5;
            s
        };
        let bad_cfg = SimConfig {
            max_steps: 0,
            ..SimConfig::default()
        };
        let base = request(&paths, &ok, &log, &assets);
        assert_refused(vec![
            (
                BatchRequest {
                    config: &bad_cfg,
                    ..base
                },
                "`max_steps`",
            ),
            (
                BatchRequest {
                    settings: &slow,
                    ..base
                },
                "planner setting `model.dt` = 0.5 does not fit",
            ),
            (
                BatchRequest {
                    settings: &h7,
                    predictor: Path::new("student"),
                    ..base
                },
                "planner setting `model.horizon` = 7 does not fit: the student predicts 6 steps",
            ),
            (
                BatchRequest {
                    world_predictor: Some(Path::new("teacher")),
                    ..base
                },
                "world log_replay",
            ),
            (
                BatchRequest {
                    config: &teacher,
                    world_predictor: Some(Path::new("student")),
                    ..base
                },
                "the world model must be a teacher",
            ),
        ]);
        // Constant velocity predicts any horizon it is asked for, and so does the teacher (a
        // longer roll-out of its one-step network), as planner and as world model.
        assert!(
            BatchRequest {
                settings: &h7,
                ..base
            }
            .prepare()
            .is_ok()
        );
        let batch = BatchRequest {
            settings: &h7,
            predictor: Path::new("teacher"),
            config: &teacher,
            ..base
        }
        .prepare()
        .unwrap();
        assert_eq!(batch.predictors.planning.horizon(), 7);
        // A student decodes 6 steps in one pass: any other horizon is refused, naming it.
        let h10 = {
            let mut s = PlannerSettings::default();
            s.model.horizon = 10;
            s
        };
        assert!(matches!(
            BatchRequest {
                settings: &h10,
                predictor: Path::new("student"),
                ..base
            }
            .prepare(),
            Err(SimError::Settings(SettingsError::Incompatible {
                field: "model.horizon",
                value,
                ..
            })) if value == 10.0
        ));
    }

    /// The shipped scenes and assets, default planner settings, and a log-replay closed loop
    /// of at most 3 steps.
    fn three_log_replay_steps() -> (Vec<PathBuf>, PathBuf, PlannerSettings, SimConfig) {
        let config = SimConfig {
            world: World::LogReplay,
            max_steps: 3,
            ..SimConfig::default()
        };
        (
            scene_paths(),
            repo().join("assets"),
            PlannerSettings::default(),
            config,
        )
    }

    /// A prepared batch runs; a cancelled one stops every run before its next step.
    #[test]
    fn a_cancelled_batch_stops_at_the_next_step() {
        let (paths, assets, settings, config) = three_log_replay_steps();
        let batch = request(&paths, &settings, &config, &assets)
            .prepare()
            .unwrap();
        let outputs = batch.run(Keep::default(), &Cancel::new());
        assert_eq!(outputs.len(), 2);
        assert!(outputs.iter().all(|o| o.result.is_ok()));
        let cancel = Cancel::new();
        cancel.cancel();
        for o in batch.run(Keep::default(), &cancel) {
            assert!(
                matches!(o.result, Err(SimError::Cancelled { step: 0, .. })),
                "{:?}",
                o.result.map(|r| r.steps.len())
            );
        }
    }

    /// Cancels its own run during the first planning step; counts its calls.
    struct CancelDuring {
        inner: nudge_predictor::ConstantVelocity,
        cancel: Cancel,
        calls: usize,
    }

    impl nudge_predictor::Predictor for CancelDuring {
        fn name(&self) -> &'static str {
            "constant_velocity"
        }
        fn horizon(&self) -> usize {
            6
        }
        fn set_scene(&mut self, h: &nudge_predictor::History) -> nudge_predictor::Result<()> {
            self.inner.set_scene(h)
        }
        fn predict(&mut self, c: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
            self.cancel.cancel();
            self.calls += 1;
            self.inner.predict(c, out)
        }
    }

    /// A run cancelled while it plans stops within that step: the planner makes no predictor
    /// call after the flag is set (issue 49: it used to finish the step, however long).
    #[test]
    fn a_run_cancelled_while_it_plans_stops_within_that_step() {
        let sc = Scenario::from_file(&scene_paths()[0]).unwrap();
        let config = SimConfig {
            world: World::LogReplay,
            ..SimConfig::default()
        };
        let cancel = Cancel::new();
        let mut p = CancelDuring {
            inner: nudge_predictor::ConstantVelocity::new(6).unwrap(),
            cancel: cancel.clone(),
            calls: 0,
        };
        let control = crate::RunControl {
            cancel: &cancel,
            trace: false,
        };
        let r = crate::simulate_with(
            &sc,
            &PlannerSettings::default(),
            &config,
            0,
            &mut p,
            crate::WorldModel::LogReplay,
            control,
        );
        assert!(
            matches!(r, Err(SimError::Cancelled { step: 0, .. })),
            "{:?} after {} calls",
            r.map(|r| r.steps.len()),
            p.calls
        );
        assert_eq!(p.calls, 1, "a predictor call after the flag was set");
    }

    /// Constant velocity under another name: a predictor implemented outside nudge.
    struct Foreign(nudge_predictor::ConstantVelocity);

    impl nudge_predictor::Predictor for Foreign {
        fn name(&self) -> &'static str {
            "foreign"
        }
        fn horizon(&self) -> usize {
            self.0.horizon()
        }
        fn set_scene(&mut self, h: &nudge_predictor::History) -> nudge_predictor::Result<()> {
            self.0.set_scene(h)
        }
        fn predict(&mut self, c: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
            self.0.predict(c, out)
        }
    }

    /// A batch prepared for a predictor built by the caller runs each run with a fresh one
    /// and gives the runs of the built-in predictor it mirrors, step for step; its horizon is
    /// checked against the settings, naming `horizon`.
    #[test]
    fn a_foreign_planning_predictor_runs_as_the_built_in_one_it_mirrors() {
        let (paths, assets, settings, config) = three_log_replay_steps();
        let req = request(&paths, &settings, &config, &assets);
        let built = std::sync::atomic::AtomicUsize::new(0);
        let make = || -> Box<dyn nudge_predictor::Predictor> {
            built.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            Box::new(Foreign(nudge_predictor::ConstantVelocity::new(6).unwrap()))
        };
        let foreign = req.prepare_foreign("foreign", 6).unwrap();
        let got = foreign.run_with(Keep::default(), &Cancel::new(), &make);
        let want = req.prepare().unwrap().run(Keep::default(), &Cancel::new());
        assert_eq!(built.into_inner(), paths.len(), "one predictor per run");
        for (g, w) in got.iter().zip(&want) {
            let (g, w) = (g.result.as_ref().unwrap(), w.result.as_ref().unwrap());
            assert_eq!(
                (g.predictor.as_str(), w.predictor.as_str()),
                ("foreign", "constant_velocity")
            );
            let states =
                |r: &crate::RunRecord| -> Vec<[f64; 4]> { r.steps.iter().map(|s| s.ego).collect() };
            assert_eq!(states(g), states(w));
            assert!(!g.steps.is_empty());
        }
        assert!(matches!(
            req.prepare_foreign("foreign", 7),
            Err(SimError::Settings(SettingsError::Incompatible {
                field: "model.horizon",
                ..
            }))
        ));
    }
}
