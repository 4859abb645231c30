//! Traced closed-loop runs on a shipped real scene: the trace leaves the run unchanged, has
//! the documented shapes and the predictor's own predictions, and animates into a GIF that
//! decodes to one frame per state.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use nudge::animate::{AnimateError, AnimationSettings, Reel, animate};
use nudge::planner::{PlannerSettings, Scenario};
use nudge::predictor::{ConstantVelocity, ModelKind, T_OBS, load_predictor, model_path};
use nudge::sim::{Cancel, RunControl, RunRecord, SimConfig, World, WorldModel, simulate_with};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn scene() -> Scenario {
    Scenario::from_file(repo().join("assets/scenes/us101-11_1-t02.1-ego144.safetensors")).unwrap()
}

/// A run of the shipped scene planned with constant velocity, the log moving the others.
fn log_replay_run(trace: bool) -> RunRecord {
    let cfg = SimConfig {
        world: World::LogReplay,
        ..SimConfig::default()
    };
    let control = RunControl {
        cancel: &Cancel::new(),
        trace,
    };
    let mut cv = ConstantVelocity::default();
    let s = PlannerSettings::default();
    simulate_with(
        &scene(),
        &s,
        &cfg,
        0,
        &mut cv,
        WorldModel::LogReplay,
        control,
    )
    .unwrap()
}

/// A short run planned with the shipped student in the teacher's world.
fn teacher_world_run(trace: bool) -> RunRecord {
    let assets = repo().join("assets");
    let mut plan = load_predictor(model_path(&assets, ModelKind::Student)).unwrap();
    let mut world = load_predictor(model_path(&assets, ModelKind::Teacher)).unwrap();
    let cfg = SimConfig {
        max_steps: 4,
        ..SimConfig::default()
    };
    let control = RunControl {
        cancel: &Cancel::new(),
        trace,
    };
    let w = WorldModel::Teacher(world.as_mut());
    let s = PlannerSettings::default();
    simulate_with(&scene(), &s, &cfg, 0, plan.as_mut(), w, control).unwrap()
}

/// `traced` is `plain` with traces: equal in every field but the wall times.
fn assert_same_run(plain: &RunRecord, traced: &RunRecord) {
    assert!(plain.steps.iter().all(|s| s.trace.is_none()));
    assert!(traced.steps.iter().all(|s| s.trace.is_some()));
    let mut stripped = traced.clone();
    for (s, p) in stripped.steps.iter_mut().zip(&plain.steps) {
        s.trace = None;
        s.mpc_s = p.mpc_s;
        s.z_updates_s.clone_from(&p.z_updates_s);
    }
    assert_eq!(&stripped, plain);
    let json = serde_json::to_string(plain).unwrap();
    assert!(!json.contains("\"trace\""));
    assert!(serde_json::to_string(traced).unwrap().contains("\"trace\""));
}

#[test]
fn tracing_leaves_the_run_unchanged() {
    assert_same_run(&log_replay_run(false), &log_replay_run(true));
    assert_same_run(&teacher_world_run(false), &teacher_world_run(true));
}

#[test]
fn a_trace_holds_the_plan_the_predictions_and_the_agents() {
    let sc = scene();
    let n = sc.n_agents;
    let rec = log_replay_run(true);
    assert!(rec.steps.len() >= 3);
    let mut before: Vec<[f64; 2]> = (0..n).map(|i| sc.position(i, T_OBS - 1)).collect();
    let mut earlier: Vec<[f64; 2]> = (0..n).map(|i| sc.position(i, T_OBS - 2)).collect();
    let mut ego = [before[0][0], before[0][1], sc.heading[0], sc.speed[0]];
    for step in &rec.steps {
        let t = step.trace.as_ref().unwrap();
        // [T + 1] states from the measured one, [n − 1][T] predictions, [n] agents.
        assert_eq!(t.plan.len(), 7);
        assert_eq!(t.plan[0], ego);
        assert_eq!(t.predicted.len(), n - 1);
        assert_eq!(t.agents.len(), n);
        assert_eq!(t.agents[0], [step.ego[0], step.ego[1]]);
        // Constant velocity: every other agent continues its last observed displacement.
        for (i, track) in t.predicted.iter().enumerate() {
            let (p, q) = (before[i + 1], earlier[i + 1]);
            assert_eq!(track.len(), 6);
            for (k, got) in track.iter().enumerate() {
                let s = (k + 1) as f64;
                let want = [p[0] + s * (p[0] - q[0]), p[1] + s * (p[1] - q[1])];
                assert!((got[0] - want[0]).abs() < 1e-9 && (got[1] - want[1]).abs() < 1e-9);
            }
        }
        if let Some(b) = &t.binding {
            assert!((1..n).contains(&b.agent) && b.step < 6 && b.semi_axes.len() == 6);
        }
        earlier = std::mem::replace(&mut before, t.agents.clone());
        ego = step.ego;
    }
}

#[test]
fn a_traced_run_animates_one_frame_per_state() {
    let sc = scene();
    let rec = log_replay_run(true);
    let reel = Reel::from_run(&sc, &rec).unwrap();
    assert_eq!(reel.shots.len(), rec.steps.len() + 1);
    assert!(
        reel.shots[..rec.steps.len()]
            .iter()
            .all(|s| s.planned.is_some())
    );
    assert!(reel.shots[rec.steps.len()].planned.is_none());
    let dir = std::env::temp_dir().join(format!("nudge-anim-run-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let gif = dir.join("run.gif");
    let settings = AnimationSettings::default();
    let w = animate(&reel, &settings, &gif, None).unwrap();
    let mut d = gif::DecodeOptions::new()
        .read_info(std::fs::File::open(&gif).unwrap())
        .unwrap();
    assert_eq!((u32::from(d.width()), u32::from(d.height())), w.size);
    let mut frames = 0;
    while d.read_next_frame().unwrap().is_some() {
        frames += 1;
    }
    assert_eq!(frames, rec.steps.len() + 1);
    std::fs::remove_dir_all(&dir).unwrap();
    // An untraced run cannot be animated.
    assert!(matches!(
        Reel::from_run(&sc, &log_replay_run(false)),
        Err(AnimateError::NoTrace { step: 0, .. })
    ));
}
