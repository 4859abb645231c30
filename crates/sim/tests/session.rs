//! The closed loop stepped by its caller ([`Session`]) is the batch's loop: nudge's planner
//! stepped through a session (plan and advance as two calls, the observation asked for in
//! between, a throw-away plan replaced before each real one) gives the records of the batch
//! run of the same scene and seed, in all three worlds; a session refuses what it cannot do
//! with typed errors.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use nudge_planner::{Plan, Planner, PlannerError, PlannerSettings, PlanningProblem, Scenario};
use nudge_predictor::{ConstantVelocity, Predictor};
use nudge_sim::{
    Batch, BatchRequest, Cancel, EndReason, Keep, Policy, RunRecord, Session, SimConfig, SimError,
    World, WorldModel, WorldSpec,
};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Timings cleared (wall times differ from run to run).
fn strip(mut r: RunRecord) -> RunRecord {
    for st in &mut r.steps {
        st.mpc_s = 0.0;
        st.z_updates_s.iter_mut().for_each(|z| *z = 0.0);
    }
    r
}

/// Plans to keep the inputs at zero (a plan the session must forget when replaced).
struct Idle;

impl Policy for Idle {
    fn reset(&mut self) {}

    fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        _predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        let _ = problem;
        Err(PlannerError::Foreign {
            policy: "idle".into(),
            source: "never applied".into(),
        })
    }
}

fn batch(world: World, paths: &[PathBuf], settings: &PlannerSettings, cfg: &SimConfig) -> Batch {
    let assets = repo().join("assets");
    BatchRequest {
        scene_paths: paths,
        predictor: Path::new("student"),
        world_predictor: None,
        idm: None,
        assets: &assets,
        seed: 5,
        runs_per_scene: 1,
        scene_seeds: None,
        threads: Some(1),
        settings,
        config: &SimConfig { world, ..*cfg },
    }
    .prepare()
    .expect("batch")
}

#[test]
fn a_stepped_session_gives_the_batch_records_in_every_world() {
    let paths = Scenario::paths_in(repo().join("assets/scenes")).expect("scenes")[..3].to_vec();
    let settings = PlannerSettings::default();
    let cfg = SimConfig::default();
    for world in [World::Teacher, World::Idm, World::LogReplay] {
        let b = batch(world, &paths, &settings, &cfg);
        let outputs = b.run(Keep::default(), &Cancel::new());
        for out in outputs {
            let expected = out.result.expect("batch run");
            let sc = &b.scenes[out.spec.scene];
            let mut planning = b.predictors.planning.build();
            let mut teacher = match &b.predictors.world {
                WorldSpec::Teacher(t) => Some(t.build()),
                _ => None,
            };
            let mut model = match (&b.predictors.world, teacher.as_deref_mut()) {
                (WorldSpec::Teacher(_), Some(t)) => WorldModel::Teacher(t),
                (WorldSpec::Idm(p), _) => WorldModel::Idm(p),
                _ => WorldModel::LogReplay,
            };
            let mut session = Session::new(
                Cow::Borrowed(sc),
                Cow::Borrowed(&b.settings),
                &b.config,
                out.spec.seed,
                planning.as_ref(),
                &model,
                false,
            )
            .expect("session");
            let mut planner = Planner::new(settings.clone()).expect("planner");
            Policy::reset(&mut planner);
            let mut steps = 0;
            while session.ended().is_none() {
                let first = session.problem().expect("problem").v_ref;
                assert_eq!(session.problem().expect("problem").v_ref, first);
                assert!(session.plan(&mut Idle, planning.as_mut()).is_err());
                session.plan(&mut planner, planning.as_mut()).expect("plan");
                let rec = session
                    .advance(planning.as_mut(), &mut model)
                    .expect("advance");
                assert_eq!(rec.step, steps);
                steps += 1;
            }
            let end = session.ended().expect("ended");
            let got = session.finish();
            assert_eq!(got.steps.len(), steps);
            match end {
                EndReason::Settled => assert_eq!(got.steps_to_target, expected.steps_to_target),
                EndReason::MaxSteps => assert_eq!(steps, cfg.max_steps),
                _ => {}
            }
            assert_eq!(strip(got), strip(expected), "{world:?} {}", sc.name);
        }
    }
}

#[test]
fn a_session_refuses_what_it_cannot_do() {
    let paths = Scenario::paths_in(repo().join("assets/scenes")).expect("scenes")[..1].to_vec();
    let sc = Scenario::from_file(&paths[0]).expect("scene");
    let settings = PlannerSettings::default();
    let cfg = SimConfig {
        world: World::LogReplay,
        max_steps: 2,
        ..SimConfig::default()
    };
    let mut cv = ConstantVelocity::default();
    let mut replay = WorldModel::LogReplay;
    let mut session = Session::new(
        Cow::Borrowed(&sc),
        Cow::Borrowed(&settings),
        &cfg,
        0,
        &cv,
        &replay,
        false,
    )
    .expect("session");
    // No plan to apply yet.
    let err = session
        .advance(&mut cv, &mut replay)
        .expect_err("nothing planned");
    assert!(matches!(err, SimError::NoPlan { step: 0, .. }), "{err}");
    // A world model of another world.
    let mut planner = Planner::new(settings.clone()).expect("planner");
    session.plan(&mut planner, &mut cv).expect("plan");
    let pop = nudge_sim::IdmPopulation::from_file(nudge_sim::idm_path(&repo().join("assets")))
        .expect("idm");
    let err = session
        .advance(&mut cv, &mut WorldModel::Idm(&pop))
        .expect_err("another world");
    assert!(
        matches!(
            err,
            SimError::WorldModel {
                world: "log_replay",
                ..
            }
        ),
        "{err}"
    );
    // The plan is still pending: the right world applies it.
    session.advance(&mut cv, &mut replay).expect("advance");
    session
        .step(&mut planner, &mut cv, &mut replay)
        .expect("step");
    assert_eq!(session.ended(), Some(EndReason::MaxSteps));
    assert!(!EndReason::MaxSteps.is_terminal() && EndReason::Settled.is_terminal());
    let err = session
        .step(&mut planner, &mut cv, &mut replay)
        .expect_err("ended");
    assert!(
        matches!(
            err,
            SimError::Ended {
                steps: 2,
                reason: "max_steps",
                ..
            }
        ),
        "{err}"
    );
    assert_eq!(session.result(), session.finish());
}
