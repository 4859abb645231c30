//! Closed-loop lane changes on the real shipped scenes (assets/scenes).
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};

use nudge::planner::{PlannerSettings, Scenario};
use nudge::predictor::{ConstantVelocity, ModelKind, load_predictor, model_path};
use nudge::sim::SimError;
use nudge::sim::idm_path;
use nudge::sim::{
    IdmPopulation, RunRecord, SimConfig, StepRecord, World, WorldModel, simulate, target_lane,
};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn teacher_path() -> PathBuf {
    model_path(&repo().join("assets"), ModelKind::Teacher)
}

fn scene(name: &str) -> Scenario {
    Scenario::from_file(
        repo()
            .join("assets/scenes")
            .join(format!("{name}.safetensors")),
    )
    .unwrap()
}

fn check(rec: &RunRecord) {
    assert!(
        !rec.collision,
        "collision in {}: {:?}",
        rec.scenario,
        rec.steps.iter().map(|s| s.collision).collect::<Vec<_>>()
    );
    assert!(
        rec.success,
        "{} did not settle in lane {}",
        rec.scenario, rec.target_lane
    );
    let s = rec.steps_to_target.unwrap();
    // 2–5 s lane change (steps of 0.3 s).
    assert!((7..=17).contains(&s), "lane change took {s} steps");
    for st in &rec.steps {
        assert!(st.iterations >= 1 && st.mpc_s > 0.0);
    }
}

#[test]
fn constant_velocity_lane_change_on_real_scene() {
    let sc = scene("us101-11_1-t02.1-ego144");
    let cfg = SimConfig {
        world: World::LogReplay,
        ..SimConfig::default()
    };
    for seed in 0..2 {
        let mut cv = ConstantVelocity::default();
        let rec = simulate(
            &sc,
            &PlannerSettings::default(),
            &cfg,
            seed,
            &mut cv,
            WorldModel::LogReplay,
        )
        .unwrap();
        check(&rec);
    }
}

#[test]
fn constant_velocity_lane_change_in_dense_real_scene() {
    let sc = scene("us101-11_1-t02.1-ego132");
    let cfg = SimConfig {
        world: World::LogReplay,
        ..SimConfig::default()
    };
    let mut cv = ConstantVelocity::default();
    let rec = simulate(
        &sc,
        &PlannerSettings::default(),
        &cfg,
        0,
        &mut cv,
        WorldModel::LogReplay,
    )
    .unwrap();
    check(&rec);
}

/// One seeded lane change on a real scene, `plan_weights` planning and the shipped teacher moving
/// the other vehicles (they react to the ego as the teacher predicts).
fn lane_change_in_teacher_world(plan_weights: &Path) -> RunRecord {
    let mut plan = load_predictor(plan_weights).unwrap();
    let mut world = load_predictor(teacher_path()).unwrap();
    let cfg = SimConfig {
        world: World::Teacher,
        ..SimConfig::default()
    };
    let sc = scene("us101-20_1-t04.5-ego462");
    let rec = simulate(
        &sc,
        &PlannerSettings::default(),
        &cfg,
        3,
        plan.as_mut(),
        WorldModel::Teacher(world.as_mut()),
    )
    .unwrap();
    assert_eq!(rec.world, World::Teacher);
    assert!(rec.steps.iter().all(|s| s.iterations >= 1 && s.mpc_s > 0.0));
    rec
}

/// The shipped trained teacher as planning predictor and as world model: the lane change must
/// settle without collision.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "teacher-in-the-loop is slow without optimisation; run with --release"
)]
fn teacher_lane_change_on_real_scene() {
    let rec = lane_change_in_teacher_world(&teacher_path());
    assert!(!rec.collision, "collision with the teacher world");
    assert!(rec.success, "lane change with the teacher did not settle");
}

/// The shipped (trained) student plans, the teacher moves the world (the paper's set-up after
/// distillation): the lane change must settle without collision.
#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "predictor-in-the-loop is slow without optimisation; run with --release"
)]
fn student_lane_change_with_teacher_world() {
    let student = model_path(&repo().join("assets"), ModelKind::Student);
    let weights = nudge::predictor::ModelWeights::from_file(&student).unwrap();
    assert_eq!(
        weights.trained(),
        Some(true),
        "{} is not trained",
        student.display()
    );
    let rec = lane_change_in_teacher_world(&student);
    assert!(
        !rec.collision,
        "collision with the student planning in a teacher world"
    );
    assert!(rec.success, "lane change with the student did not settle");
}

/// The world model must match the world: a teacher world needs a teacher (not a student, not
/// none), an idm world its population, a log-replay world none.
#[test]
fn world_models_are_checked_against_the_world() {
    let sc = scene("us101-11_1-t02.1-ego144");
    let s = PlannerSettings::default();
    let teacher_world = SimConfig::default();
    assert_eq!(teacher_world.world, World::Teacher);
    let replay = SimConfig {
        world: World::LogReplay,
        ..teacher_world
    };
    let mut cv = ConstantVelocity::default();
    let mut student =
        load_predictor(model_path(&repo().join("assets"), ModelKind::Student)).unwrap();
    let mut other_cv = ConstantVelocity::default();
    let idm_world = SimConfig {
        world: World::Idm,
        ..teacher_world
    };
    let population = IdmPopulation::from_file(idm_path(&repo().join("assets"))).unwrap();
    let errors = [
        simulate(&sc, &s, &teacher_world, 0, &mut cv, WorldModel::LogReplay).unwrap_err(),
        simulate(
            &sc,
            &s,
            &teacher_world,
            0,
            &mut cv,
            WorldModel::Teacher(student.as_mut()),
        )
        .unwrap_err(),
        simulate(
            &sc,
            &s,
            &replay,
            0,
            &mut cv,
            WorldModel::Teacher(&mut other_cv),
        )
        .unwrap_err(),
        simulate(&sc, &s, &replay, 0, &mut cv, WorldModel::Idm(&population)).unwrap_err(),
        simulate(&sc, &s, &idm_world, 0, &mut cv, WorldModel::LogReplay).unwrap_err(),
    ];
    for err in errors {
        assert!(matches!(err, SimError::WorldModel { .. }), "{err}");
    }
}

/// Lane changes in the idm world on a shipped real scene: the run completes, the other
/// vehicles move by IDM (they keep their lateral positions, unlike the log), and the same seed
/// gives the same run bit for bit.
#[test]
fn lane_change_in_idm_world_on_real_scene() {
    let sc = scene("us101-11_1-t02.1-ego144");
    let population = IdmPopulation::from_file(idm_path(&repo().join("assets"))).unwrap();
    let cfg = SimConfig {
        world: World::Idm,
        ..SimConfig::default()
    };
    let run = |seed: u64| {
        let mut cv = ConstantVelocity::default();
        simulate(
            &sc,
            &PlannerSettings::default(),
            &cfg,
            seed,
            &mut cv,
            WorldModel::Idm(&population),
        )
        .unwrap()
    };
    for seed in 0..2 {
        let rec = run(seed);
        assert_eq!(rec.world, World::Idm);
        check(&rec);
        assert_eq!(rec.metrics.collisions_at_fault, 0);
        assert_eq!(rec.metrics.off_road_steps, 0);
        assert!(rec.metrics.score > 0.5, "score {}", rec.metrics.score);
        assert_eq!(rec, {
            let mut again = run(seed);
            for (a, b) in again.steps.iter_mut().zip(&rec.steps) {
                a.mpc_s = b.mpc_s;
                a.z_updates_s.clone_from(&b.z_updates_s);
            }
            again
        });
    }
}

/// The real scene `base` (its road, lanes and ego size) with the ego at its last observed x,
/// lateral position `ego.0` and speed `ego.1` (m, m/s), and in place of every other vehicle
/// `others`: 4.5 m × 1.8 m vehicles at (dx from the ego, y, speed) (m, m, m/s), all driving
/// straight at constant speed over the 8 observed steps, with no logged future (in log
/// replay they keep their speed).
fn synthetic_scene(
    base: &Scenario,
    name: &str,
    ego: (f64, f64),
    others: &[(f64, f64, f64)],
) -> Scenario {
    let x0 = base.position(0, 7)[0];
    let n = 1 + others.len();
    let mut history = Vec::with_capacity(n * 16);
    for &(dx, y, v) in std::iter::once(&(0.0, ego.0, ego.1)).chain(others) {
        for t in 0..8 {
            let back = f64::from(7 - t) * 0.3 * v;
            history.extend_from_slice(&[x0 + dx - back, y]);
        }
    }
    let mut size = vec![base.size[0]];
    size.extend(std::iter::repeat_n([4.5, 1.8], others.len()));
    let mut speed = vec![ego.1];
    speed.extend(others.iter().map(|o| o.2));
    Scenario {
        name: name.to_string(),
        n_agents: n,
        history,
        heading: vec![0.0; n],
        speed,
        size,
        n_future: base.n_future,
        future: vec![0.0; n * base.n_future * 2],
        future_valid: vec![false; n * base.n_future],
        agent_ids: (0..n as i64).collect(),
        ..base.clone()
    }
}

/// The centres of the seeded target lane and of the ego's own lane of scene `base` (m).
fn target_and_own(base: &Scenario, seed: u64) -> (f64, f64) {
    let lane = target_lane(
        base,
        seed,
        &PlannerSettings::default(),
        &SimConfig::default(),
    )
    .unwrap();
    (base.lane_centres[lane], base.lane_centres[base.ego_lane])
}

/// One log-replay run of `sc` under `settings` and `cfg` (its world set to log replay) with
/// the constant-velocity predictor, seed 0.
fn log_replay_run(sc: &Scenario, settings: &PlannerSettings, cfg: SimConfig) -> RunRecord {
    let cfg = SimConfig {
        world: World::LogReplay,
        ..cfg
    };
    let mut cv = ConstantVelocity::default();
    simulate(sc, settings, &cfg, 0, &mut cv, WorldModel::LogReplay).unwrap()
}

/// The real scene `name` with every other vehicle replaced by a convoy in the seeded target
/// lane: vehicles of 4.5 m every `spacing` metres alongside the ego at the ego's speed, no
/// logged future (they keep their speed).
fn convoy_scene(name: &str, seed: u64, spacing: f64) -> (Scenario, f64, f64) {
    let base = scene(name);
    let (y_lane, y_own) = target_and_own(&base, seed);
    let v = base.speed[0];
    let convoy: Vec<(f64, f64, f64)> = (-3..=3)
        .map(|k| (f64::from(k) * spacing, y_lane, v))
        .collect();
    let ego_y = base.position(0, 7)[1];
    let sc = synthetic_scene(&base, &format!("{name}-convoy"), (ego_y, v), &convoy);
    (sc, y_lane, y_own)
}

/// With the default settings the lane change finds no admissible plan in front of the convoy
/// and the abort fires; without aborts the goal stays the target lane.
#[test]
fn blocked_target_lane_aborts_instead_of_idling_across_the_boundary() {
    let (sc, y_target, y_own) = convoy_scene("us101-11_1-t02.1-ego144", 0, 11.0);
    let arms = [
        (2, PlannerSettings::default(), 0.0),
        (0, PlannerSettings::default(), 0.0),
    ];
    for (abort_after, settings, stall_progress) in arms {
        let cfg = SimConfig {
            abort_after,
            stall_progress,
            ..SimConfig::default()
        };
        let rec = log_replay_run(&sc, &settings, cfg);
        assert!(!rec.collision, "collision with abort_after {abort_after}");
        assert!(!rec.success, "a lane change through a closed convoy");
        if abort_after == 0 {
            assert_eq!(rec.aborts, 0);
            assert!(rec.steps.iter().all(|s| s.y_goal == y_target));
        } else {
            // The lane change finds no safe plan, aborts, returns to the own lane's centre
            // while the abort holds and retries afterwards.
            assert!(rec.aborts >= 1, "no abort");
            let held: Vec<&StepRecord> = rec.steps.iter().filter(|s| s.y_goal == y_own).collect();
            assert!(held.len() >= cfg.abort_hold);
            let closest = held
                .iter()
                .map(|s| (s.ego[1] - y_own).abs())
                .fold(f64::INFINITY, f64::min);
            if stall_progress == 0.0 {
                assert!(
                    closest < 0.1,
                    "back to within {closest} m of the own lane's centre"
                );
            } else {
                // The stalled change aborts later, from further across (its box over the
                // line): during the hold the box is back wholly inside the own lane.
                let to_line = 0.5 * (y_target - y_own).abs();
                let half_width = 0.5 * sc.size[0][1];
                assert!(
                    closest + half_width < to_line,
                    "back to {closest} m of the own lane's centre: still across the line"
                );
            }
            let first_hold = rec.steps.iter().position(|s| s.y_goal == y_own).unwrap();
            assert!(first_hold >= cfg.abort_after);
            assert!(rec.steps[first_hold..].iter().any(|s| s.y_goal == y_target));
        }
    }
}

/// An ego that starts with its box 0.4 m across the line into a closed target-lane convoy
/// (its centre still in its own lane) finds no admissible plan from the first step. With
/// `start_abort_after` = 1 the change is aborted after that first step and the next
/// `abort_hold` steps aim at the own lane's centre; without it the goal stays the target lane
/// for `abort_after` steps (the fallbacks' retreat brings the box back into the own lane
/// either way: the own lane is offered to them before the crossing).
#[test]
fn an_ego_starting_across_the_line_aborts_at_once() {
    let (mut sc, y_target, y_own) = convoy_scene("us101-11_1-t02.1-ego144", 0, 11.0);
    let towards = (y_target - y_own).signum();
    let half_width = 0.5 * sc.size[0][1];
    let to_line = 0.5 * (y_target - y_own).abs();
    let y0 = y_own + towards * (to_line - half_width + 0.4);
    for t in 0..8 {
        sc.history[2 * t + 1] = y0;
    }
    let run = |start_abort_after: usize| {
        let cfg = SimConfig {
            start_abort_after,
            ..SimConfig::default()
        };
        log_replay_run(&sc, &PlannerSettings::default(), cfg)
    };
    let (plain, start) = (run(0), run(1));
    for rec in [&plain, &start] {
        assert!(!rec.collision, "collision");
        assert!(
            rec.steps[0].status.is_unsafe_plan(),
            "{:?}",
            rec.steps[0].status
        );
    }
    let cfg = SimConfig::default();
    assert!(
        plain.steps[..cfg.abort_after]
            .iter()
            .all(|s| s.y_goal == y_target),
        "without the rule the goal stays the target lane for {} steps",
        cfg.abort_after
    );
    assert!(
        start.steps[1..=cfg.abort_hold]
            .iter()
            .all(|s| s.y_goal == y_own),
        "with it the steps after the first aim at the own lane"
    );
    assert!(start.aborts >= 1);
}

/// The real scene `name` with its ego crawling at `v_ego` (m/s) at its own lane's centre and
/// three vehicles in the seeded target lane moving at `v_flow` (m/s), 40–50 m ahead of it, no
/// logged future (they keep their speed and soon leave the 50 m flow range).
fn crawl_scene(name: &str, seed: u64, v_ego: f64, v_flow: f64) -> (Scenario, f64) {
    let base = scene(name);
    let (y_lane, y_own) = target_and_own(&base, seed);
    let flow: Vec<(f64, f64, f64)> = [40.0, 45.0, 50.0]
        .iter()
        .map(|&dx| (dx, y_lane, v_flow))
        .collect();
    let sc = synthetic_scene(&base, &format!("{name}-crawl"), (y_own, v_ego), &flow);
    (sc, y_lane)
}

/// An ego that starts at 1.5 m/s beside a target lane moving at 10 m/s: with the crawl
/// reference off it plans that crawl for the whole run and ends it slow in a live lane; with
/// the default (`crawl_fraction` 0.5) it changes lanes and ends near the lane's flow, after
/// the traffic that set the flow has left the 50 m range (the remembered flow).
#[test]
fn a_crawling_ego_keeps_up_with_the_target_lanes_flow() {
    let (sc, y_target) = crawl_scene("us101-11_1-t02.1-ego144", 0, 1.5, 10.0);
    let run = |crawl_fraction: f64| {
        let cfg = SimConfig {
            crawl_fraction,
            ..SimConfig::default()
        };
        log_replay_run(&sc, &PlannerSettings::default(), cfg)
    };
    assert_eq!(SimConfig::default().crawl_fraction, 0.5);
    let (off, on) = (run(0.0), run(SimConfig::default().crawl_fraction));
    let last_v = |rec: &RunRecord| rec.steps.last().unwrap().ego[3];
    for rec in [&off, &on] {
        assert!(!rec.collision, "collision");
    }
    assert!(last_v(&off) < 3.0, "off: ends at {} m/s", last_v(&off));
    assert!(off.metrics.slow_planned_steps > 0);
    assert!(on.success, "on: did not settle in the target lane");
    assert!(last_v(&on) > 8.0, "on: ends at {} m/s", last_v(&on));
    // The 10 m/s vehicles leave the 50 m range steps before the end: from then on the
    // reference is the remembered flow, and the ego keeps it.
    let out_of_range = on
        .steps
        .iter()
        .position(|st| {
            let t = 0.3 * (st.step + 1) as f64;
            sc.position(1, 7)[0] + 10.0 * t - st.ego[0] > 50.0
        })
        .unwrap();
    assert!(
        out_of_range + 3 <= on.steps.len(),
        "{out_of_range} of {}",
        on.steps.len()
    );
    for st in &on.steps[out_of_range..] {
        assert!(
            st.v_planned > 8.0,
            "step {}: plans {} m/s",
            st.step,
            st.v_planned
        );
    }
    assert!((on.steps.last().unwrap().ego[1] - y_target).abs() < 0.5);
}
