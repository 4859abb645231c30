//! The simulator drives the ego through a [`Policy`]: nudge's planner wrapped in another policy
//! gives the records of [`simulate`] (timings aside), one plan per step after one reset.

use std::path::Path;

use nudge_planner::{Plan, Planner, PlannerError, PlannerSettings, PlanningProblem, Scenario};
use nudge_predictor::{ConstantVelocity, Predictor};
use nudge_sim::{
    Cancel, Policy, RunControl, RunRecord, SimConfig, World, WorldModel, simulate, simulate_policy,
};

/// The planner, counting the calls it receives.
struct Counting {
    inner: Planner,
    resets: usize,
    plans: usize,
}

impl Policy for Counting {
    fn reset(&mut self) {
        self.resets += 1;
        self.inner.reset();
    }

    fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        self.plans += 1;
        self.inner.plan(problem, predictor)
    }
}

fn strip(mut r: RunRecord) -> RunRecord {
    for st in &mut r.steps {
        st.mpc_s = 0.0;
        st.z_updates_s.clear();
    }
    r
}

#[test]
fn a_wrapped_planner_drives_the_same_run_as_the_planner() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../assets/scenes/us101-11_1-t02.1-ego144.safetensors");
    let sc = Scenario::from_file(&scene).expect("scene");
    let settings = PlannerSettings::default();
    let cfg = SimConfig {
        world: World::LogReplay,
        ..SimConfig::default()
    };
    let mut cv = ConstantVelocity::default();
    let direct = simulate(&sc, &settings, &cfg, 0, &mut cv, WorldModel::LogReplay).expect("run");
    let mut policy = Counting {
        inner: Planner::new(settings.clone()).expect("planner"),
        resets: 0,
        plans: 0,
    };
    let never = Cancel::new();
    let control = RunControl {
        cancel: &never,
        trace: false,
    };
    let driven = simulate_policy(
        &sc,
        &settings,
        &cfg,
        0,
        &mut policy,
        &mut cv,
        WorldModel::LogReplay,
        control,
    )
    .expect("run");
    assert_eq!((policy.resets, policy.plans), (1, driven.steps.len()));
    assert_eq!(strip(direct), strip(driven));
}

/// A batch run with a policy factory (the hook `nudge.simulate(planner=...)` uses) gives the
/// records of the batch planned by nudge's planner when the policy is that planner, builds one
/// policy per run with the run's scene and seed, and counts every run.
#[test]
fn a_batch_with_a_policy_factory_gives_the_batch_records() {
    use nudge_sim::{BatchRequest, Keep, PolicyFactory, Progress};
    use std::sync::Mutex;

    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let paths = Scenario::paths_in(repo.join("assets/scenes")).expect("scenes")[..3].to_vec();
    let settings = PlannerSettings::default();
    let cfg = SimConfig {
        world: World::Idm,
        max_steps: 6,
        ..SimConfig::default()
    };
    let assets = repo.join("assets");
    let batch = BatchRequest {
        scene_paths: &paths,
        predictor: Path::new("constant_velocity"),
        world_predictor: None,
        idm: None,
        assets: &assets,
        seed: 4,
        runs_per_scene: 2,
        scene_seeds: None,
        threads: Some(2),
        settings: &settings,
        config: &cfg,
    }
    .prepare()
    .expect("batch");
    let built = Mutex::new(Vec::new());
    let make = |sc: &Scenario, seed: u64| -> Box<dyn Policy> {
        built.lock().expect("lock").push((sc.name.clone(), seed));
        Box::new(Counting {
            inner: Planner::new(settings.clone()).expect("planner"),
            resets: 0,
            plans: 0,
        })
    };
    let progress = Progress::new();
    let cancel = Cancel::new();
    let with_policy = batch.run_counted(
        Keep::default(),
        &cancel,
        None,
        Some(&make as &PolicyFactory<'_>),
        &progress,
    );
    let plain = batch.run(Keep::default(), &cancel);
    assert_eq!(progress.done(), 6);
    let mut built = built.into_inner().expect("lock");
    built.sort();
    let mut expected: Vec<(String, u64)> = batch
        .specs
        .iter()
        .map(|s| (batch.scenes[s.scene].name.clone(), s.seed))
        .collect();
    expected.sort();
    assert_eq!(built, expected);
    for (a, b) in with_policy.into_iter().zip(plain) {
        assert_eq!(strip(a.result.expect("run")), strip(b.result.expect("run")));
    }
}
