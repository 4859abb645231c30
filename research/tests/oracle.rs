//! The log-replay oracle (`nudge_research::oracle`) against truths known without it: the
//! stopping distance of the jerk-limited brake ramp (written out by hand), the simulator's own
//! log-replay runs (the same states and the same contacts, step for step), and the bounds of
//! every sequence it returns.
#![allow(clippy::unwrap_used)]

use nudge_planner::{Bicycle, PlannerSettings, Scenario, State};
use nudge_predictor::ConstantVelocity;
use nudge_research::oracle::{
    Avoidance, LoggedTraffic, OracleLimits, OracleStart, OracleWorld, Violation, avoid, replay,
};
use nudge_sim::metrics::{contacts, ego_box};
use nudge_sim::{SimConfig, World, WorldModel, simulate};

#[path = "../../crates/sim/tests/logged/mod.rs"]
mod logged;

/// Every vehicle's (length, width) in [`logged::logged_scene`] (m).
const SIZE: [f64; 2] = [4.5, 1.9];

/// Vehicles `(x, y, v)` at the last observed step (agent 0 = the ego) driving along +x at
/// constant speed, on lanes `bounds`.
fn scene(agents: &[(f64, f64, f64)], bounds: &[f64]) -> Scenario {
    logged::logged_scene("oracle", agents, bounds, None)
}

fn bicycle() -> Bicycle {
    let s = PlannerSettings::default();
    Bicycle {
        l_f: s.model.l_f,
        l_r: s.model.l_r,
        dt: s.model.dt,
    }
}

/// The oracle's world for an ego of [`SIZE`] on lanes `bounds` among `traffic`, 0.1 m of
/// off-road tolerance.
fn world<'a>(traffic: &'a LoggedTraffic, bounds: &'a [f64]) -> OracleWorld<'a> {
    OracleWorld {
        bicycle: bicycle(),
        size: SIZE,
        bounds,
        road_tolerance: 0.1,
        traffic,
    }
}

/// The ego at the origin, heading along the road at `v` (m/s), before step 0 with last
/// inputs `inputs`.
fn start(v: f64, inputs: (f64, f64)) -> OracleStart {
    OracleStart {
        step: 0,
        ego: [0.0, 0.0, 0.0, v],
        inputs,
    }
}

/// The distance (m) the ego covers from `v0` (m/s) under the hardest brake ramp the bounds
/// allow from a = 0: a_k = max(a_min, −(k + 1)·da_max), the speed never below 0, one explicit
/// Euler step of `dt` per step (the bicycle going straight).
fn ramp_stopping_distance(v0: f64, s: &PlannerSettings) -> (f64, usize) {
    let (mut v, mut x, mut k) = (v0, 0.0, 0);
    while v > 0.0 {
        let a = (-(k as f64 + 1.0) * s.bounds.da_max).max(s.bounds.a_min);
        x += s.model.dt * v;
        v = (v + s.model.dt * a).max(0.0);
        k += 1;
    }
    (x, k)
}

/// An ego at 10 m/s on a one-lane road too narrow to pass a car stopped ahead: the collision
/// is avoidable exactly when the car's rear lies beyond the ramp's stopping distance, for
/// blocks of one and of two steps.
#[test]
fn a_car_stopped_ahead_is_avoidable_exactly_beyond_the_stopping_distance() {
    let s = PlannerSettings::default();
    let v0 = 10.0;
    let (d, k_stop) = ramp_stopping_distance(v0, &s);
    assert!(
        d > 10.0 && d < 25.0 && k_stop < 12,
        "{d} m in {k_stop} steps"
    );
    let bounds = [-1.75, 1.75];
    for hold in [1, 2] {
        let mut limits = OracleLimits::of(&s);
        limits.hold = hold;
        for (slack, avoidable) in [(0.05, true), (-0.05, false)] {
            // Ego front at 2.25 m; the stopped car's rear at 2.25 + d + slack.
            let xo = 2.25 + d + slack + 2.25;
            let sc = scene(&[(0.0, 0.0, v0), (xo, 0.0, 0.0)], &bounds);
            let traffic = LoggedTraffic::new(&sc, 20, SimConfig::default().replay_lateral_decay);
            let world = world(&traffic, &bounds);
            let start = start(v0, (0.0, 0.0));
            let found = avoid(&world, &limits, &start, 14);
            match (&found, avoidable) {
                (Avoidance::Avoidable(inputs), true) => {
                    assert_eq!(inputs.len(), 15);
                    let (states, violation) = replay(&world, &limits, &start, inputs);
                    assert_eq!(violation, None);
                    // It stopped short of the car's rear.
                    let last = states.last().unwrap();
                    assert_eq!(last[3], 0.0);
                    assert!(last[0] + 2.25 <= xo - 2.25);
                }
                (Avoidance::Unavoidable { nodes }, false) => assert!(*nodes > 1),
                _ => panic!("hold {hold}, slack {slack}: {found:?}"),
            }
        }
    }
}

/// Every sequence the oracle returns keeps the planner's box and rate bounds from the inputs
/// it starts from, and replays without a violation.
#[test]
fn a_found_sequence_keeps_the_input_bounds_and_replays_clean() {
    let s = PlannerSettings::default();
    let limits = OracleLimits::of(&s);
    let bounds = [-1.75, 1.75, 5.25];
    // A car stopped 30 m ahead in the ego's lane, room beside it in lane 1.
    let sc = scene(&[(0.0, 0.0, 12.0), (32.0, 0.0, 0.0)], &bounds);
    let traffic = LoggedTraffic::new(&sc, 12, SimConfig::default().replay_lateral_decay);
    let world = world(&traffic, &bounds);
    let start = start(12.0, (0.05, 1.0));
    let Avoidance::Avoidable(inputs) = avoid(&world, &limits, &start, 10) else {
        panic!("a free lane beside a stopped car leaves room");
    };
    let mut prev = start.inputs;
    for &(d, a) in &inputs {
        assert!(d.abs() <= s.bounds.delta_max && (s.bounds.a_min..=s.bounds.a_max).contains(&a));
        assert!((d - prev.0).abs() <= s.bounds.ddelta_max + 1e-12);
        assert!((a - prev.1).abs() <= s.bounds.da_max + 1e-12);
        prev = (d, a);
    }
    let (states, violation) = replay(&world, &limits, &start, &inputs);
    assert_eq!(violation, None);
    assert!(
        states
            .iter()
            .all(|z| z[2].abs() <= s.bounds.heading_max + 1e-12)
    );
}

/// A search cut short says so.
#[test]
fn a_search_past_its_node_limit_is_undecided() {
    let s = PlannerSettings::default();
    let mut limits = OracleLimits::of(&s);
    limits.max_nodes = 3;
    let bounds = [-1.75, 1.75];
    let sc = scene(&[(0.0, 0.0, 10.0), (60.0, 0.0, 0.0)], &bounds);
    let traffic = LoggedTraffic::new(&sc, 20, SimConfig::default().replay_lateral_decay);
    let world = world(&traffic, &bounds);
    let start = start(10.0, (0.0, 0.0));
    // Ten blocks are needed; holding the inputs reaches the car at 60 m after 5 s (17 steps).
    assert_eq!(
        avoid(&world, &limits, &start, 19),
        Avoidance::Undecided { nodes: 3 }
    );
    limits.max_nodes = OracleLimits::DEFAULT_MAX_NODES;
    assert!(matches!(
        avoid(&world, &limits, &start, 19),
        Avoidance::Avoidable(_)
    ));
}

/// The oracle's world is the simulator's: replaying a log-replay run's executed inputs from its
/// start gives its recorded states bit for bit, and the logged traffic touches the ego at
/// exactly the steps the run recorded a collision (here a run that is rear-ended by faster
/// cars in both lanes).
#[test]
fn replaying_a_log_replay_run_gives_its_states_and_its_collisions() {
    let bounds = [-1.75, 1.75, 5.25];
    let sc = scene(
        &[(0.0, 0.0, 10.0), (-22.0, 0.0, 24.0), (-20.0, 3.5, 24.0)],
        &bounds,
    );
    let cfg = SimConfig {
        world: World::LogReplay,
        max_steps: 14,
        ..SimConfig::default()
    };
    let s = PlannerSettings::default();
    let mut cv = ConstantVelocity::default();
    let run = simulate(&sc, &s, &cfg, 0, &mut cv, WorldModel::LogReplay).unwrap();
    assert!(run.collision, "the fast cars catch the ego");
    let traffic = LoggedTraffic::new(&sc, run.steps.len(), cfg.replay_lateral_decay);
    let b = bicycle();
    let mut z = State::new(0.0, 0.0, 0.0, 10.0);
    for (k, st) in run.steps.iter().enumerate() {
        z = b.advance(&z, st.delta, st.accel);
        assert_eq!([z[0], z[1], z[2], z[3]], st.ego, "step {k}");
        let touching = !contacts(&ego_box(st.ego, SIZE), &traffic.steps[k]).is_empty();
        assert_eq!(touching, st.collision, "step {k}");
    }
    // The first contact is where a replay of the executed inputs stops.
    let first = run.steps.iter().position(|st| st.collision).unwrap();
    let world = OracleWorld {
        bicycle: b,
        size: SIZE,
        bounds: &bounds,
        road_tolerance: f64::INFINITY,
        traffic: &traffic,
    };
    let mut limits = OracleLimits::of(&s);
    limits.heading_max = std::f64::consts::PI;
    let start = start(10.0, (0.0, 0.0));
    let executed: Vec<(f64, f64)> = run.steps.iter().map(|st| (st.delta, st.accel)).collect();
    let (_, violation) = replay(&world, &limits, &start, &executed);
    assert!(
        matches!(violation, Some(Violation::Contact { step, .. }) if step == first),
        "{violation:?}, first collision at step {first}"
    );
}

/// What the ego could know: extrapolating a log whose vehicles keep their velocity gives the
/// log itself, from any step; where a vehicle changes its velocity after step k, the
/// extrapolation from k keeps the log up to k − 1 and the old velocity after.
#[test]
fn the_constant_velocity_extrapolation_of_a_steady_log_is_the_log() {
    let bounds = [-1.75, 1.75, 5.25];
    let steady = scene(
        &[(0.0, 0.0, 10.0), (20.0, 3.5, 12.0), (-15.0, 0.0, 8.0)],
        &bounds,
    );
    let log = LoggedTraffic::new(&steady, 12, SimConfig::default().replay_lateral_decay);
    let close = |a: &nudge_sim::metrics::Vehicle, b: &nudge_sim::metrics::Vehicle| {
        (a.bbox.x - b.bbox.x).abs() < 1e-9
            && (a.bbox.y - b.bbox.y).abs() < 1e-9
            && (a.bbox.heading - b.bbox.heading).abs() < 1e-12
            && (a.vx - b.vx).abs() < 1e-9
    };
    for k in [0, 1, 2, 5, 11, 12] {
        let guess = log.extrapolated(&steady, k);
        assert_eq!(guess.steps.len(), 12);
        for (s, (g, l)) in guess.steps.iter().zip(&log.steps).enumerate() {
            assert!(g.iter().zip(l).all(|(a, b)| close(a, b)), "k {k}, step {s}");
        }
    }
    // Agent 1 moves 1 m to the left at step 4 (its logged future step 5) and on.
    let mut turning = steady.clone();
    for step in 4..turning.n_future {
        turning.future[(turning.n_future + step) * 2 + 1] += 1.0;
    }
    let log = LoggedTraffic::new(&turning, 12, SimConfig::default().replay_lateral_decay);
    let guess = log.extrapolated(&turning, 4);
    for s in 0..12 {
        let (g, l) = (&guess.steps[s][0], &log.steps[s][0]);
        assert_eq!(close(g, l), s < 4, "step {s}");
        // From step 4 on the guess keeps lane 1's centre line.
        if s >= 4 {
            assert!((g.bbox.y - 3.5).abs() < 1e-9);
        }
    }
}

/// Past the end of a vehicle's log the oracle's traffic moves it as the simulator's log-replay
/// world does (speed along the road held, sideways motion fading by `replay_lateral_decay` per
/// step; the simulator against the closed form: `crates/sim/tests/log_replay.rs`), for
/// decays from none to full.
#[test]
fn past_the_end_of_a_log_the_logged_traffic_is_the_simulators() {
    let sc = logged::drifting_at_log_end(5, -0.1);
    let s = PlannerSettings::default();
    for rho in [0.0, 0.5, SimConfig::default().replay_lateral_decay, 1.0] {
        let cfg = SimConfig {
            world: World::LogReplay,
            max_steps: 20,
            settle_steps: SimConfig::MAX_STEPS,
            replay_lateral_decay: rho,
            ..SimConfig::default()
        };
        let mut cv = ConstantVelocity::default();
        let run = simulate(&sc, &s, &cfg, 0, &mut cv, WorldModel::LogReplay).unwrap();
        assert_eq!(run.steps.len(), 20, "rho {rho}: the run goes the distance");
        let traffic = LoggedTraffic::new(&sc, run.steps.len(), rho);
        for (k, st) in run.steps.iter().enumerate() {
            let (agent, dx, dy) = st.nearest.unwrap();
            assert_eq!(agent, 1);
            let simulated = [st.ego[0] + dx, st.ego[1] + dy];
            let oracle = &traffic.steps[k][0].bbox;
            assert!(
                (oracle.x - simulated[0]).abs() < 1e-9 && (oracle.y - simulated[1]).abs() < 1e-9,
                "rho {rho}, step {k}: oracle ({}, {}) vs simulator {simulated:?}",
                oracle.x,
                oracle.y
            );
        }
    }
}
