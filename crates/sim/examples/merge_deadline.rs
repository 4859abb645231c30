//! The measurement behind the default deadline weight of a merge (`w_deadline`) and the
//! lane-end stopping rule (`stop_decel`, `stop_margin`, see `nudge_planner::extents`): an ego at 20 m/s in an acceleration lane that ends at x = 120 m,
//! beside a main lane with a platoon at 25 m/s, 9 m apart, with one 30 m gap whose front starts
//! 20, 60 or 100 m behind the ego; closed loop (constant-velocity planning predictor, 40 steps)
//! in the `idm` world (the platoon reacts) and the `log_replay` world (it does not), with the
//! deadline weight off and at its default. Prints the outcome, where the ego's centre
//! crossed into the main lane, and where the ego was at the end with its speed.
//!
//! `cargo run --release -p nudge-sim --example merge_deadline`
#![allow(clippy::unwrap_used, clippy::print_stdout)]

use std::collections::HashMap;

use nudge_planner::scenario::LaneExtent;
use nudge_planner::{PlannerSettings, Scenario};
use nudge_predictor::{ConstantVelocity, T_OBS};
use nudge_sim::{IdmPopulation, SimConfig, World, WorldModel, simulate};

const DT: f64 = 0.3;

/// The scene with the gap's front `gap_back` m behind the ego.
fn scene(gap_back: f64) -> Scenario {
    let mut agents = vec![(0.0, 0.0, 20.0)];
    let mut x: f64 = 60.0;
    while x > -260.0 && agents.len() < 45 {
        agents.push((x, 3.7, 25.0));
        x -= if (x + gap_back).abs() < 4.5 {
            30.0
        } else {
            9.0
        };
    }
    let n = agents.len();
    let nf = 45;
    let mut history = Vec::new();
    let mut future = Vec::new();
    for &(x, y, v) in &agents {
        for t in 0..T_OBS {
            history.extend([x - v * DT * (T_OBS - 1 - t) as f64, y]);
        }
        for k in 1..=nf {
            future.extend([x + v * DT * k as f64, y]);
        }
    }
    let extent = |end, ends| LaneExtent {
        begin: -500.0,
        end,
        begins: false,
        ends,
    };
    Scenario {
        name: format!("merge-gap{gap_back}"),
        n_agents: n,
        history,
        heading: vec![0.0; n],
        speed: agents.iter().map(|a| a.2).collect(),
        size: vec![[4.5, 1.9]; n],
        n_future: nf,
        future,
        future_valid: vec![true; n * nf],
        lane_centres: vec![0.0, 3.7],
        lane_bounds: vec![-1.85, 1.85, 5.55],
        ego_lane: 0,
        agent_ids: (0..n as i64).collect(),
        lane_extents: Some(vec![extent(120.0, true), extent(2000.0, false)]),
        metadata: HashMap::new(),
    }
}

fn main() {
    let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets");
    let pop = IdmPopulation::from_file(nudge_sim::idm_path(&assets)).unwrap();
    for world in [World::Idm, World::LogReplay] {
        for w in [0.0, PlannerSettings::default().lane_ends.w_deadline] {
            for gap_back in [20.0, 60.0, 100.0] {
                let sc = scene(gap_back);
                let s = {
                    let mut s = PlannerSettings::default();
                    s.lane_ends.w_deadline = w;
                    s
                };
                let cfg = SimConfig {
                    world,
                    max_steps: 40,
                    ..SimConfig::default()
                };
                let model = match world {
                    World::Idm => WorldModel::Idm(&pop),
                    _ => WorldModel::LogReplay,
                };
                let mut cv = ConstantVelocity::default();
                let run = simulate(&sc, &s, &cfg, 0, &mut cv, model).unwrap();
                let crossed = run.steps.iter().find(|s| s.ego[1] > 1.85).map(|s| s.ego[0]);
                let last = run.steps.last().unwrap().ego;
                println!(
                    "world {:<10} w_deadline {w:>5}: gap {gap_back:>5} m behind: {} (crossed at x = {}, {} steps, last x = {:.0} m at {:.1} m/s)",
                    world.as_str(),
                    run.outcome,
                    crossed.map_or_else(|| "-".to_string(), |x| format!("{x:.0} m")),
                    run.steps.len(),
                    last[0],
                    last[3]
                );
            }
        }
    }
}
