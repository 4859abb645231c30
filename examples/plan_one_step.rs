//! Plan one step from Rust on a shipped real scene: load the scene and the distilled student,
//! set up the planning problem the closed-loop simulator would, and print the plan.
//!
//! Run from the repository root: `cargo run --release --example plan_one_step`.
#![allow(clippy::print_stdout)]

use nudge::planner::{Planner, PlannerSettings, PlanningProblem, Scenario};
use nudge::predictor::{History, PredictorSpec, default_assets_dir};
use nudge::sim::{SimConfig, target_lane};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let assets = default_assets_dir();
    let sc = Scenario::from_file(assets.join("scenes/us101-11_1-t02.1-ego144.safetensors"))?;
    // The student, resolved by name under the assets directory.
    let mut student = PredictorSpec::resolve("student", &assets, 6)?.build();

    // The ego at its last observed position, aiming at the centre of the lane seed 0 draws.
    let lane = target_lane(&sc, 0, &PlannerSettings::default(), &SimConfig::default())?;
    let history = History::new(sc.history.clone(), sc.n_agents)?; // [n, 8, 2] m
    let problem = PlanningProblem::at_scenario_start(&sc, &history, sc.lane_centres[lane]);
    let mut planner = Planner::new(PlannerSettings::default())?;
    let plan = planner.plan(&problem, student.as_mut())?;

    println!(
        "{}: {} vehicles, target lane {lane} at y = {:.2} m",
        sc.name, sc.n_agents, problem.y_target
    );
    println!(
        "status {}, {} iterations, {} predictor calls, {} vehicles checked, cost {:.2}",
        plan.status.name(),
        plan.iterations,
        plan.predictor_calls,
        plan.checked,
        plan.cost
    );
    println!(" k  delta(rad)  accel(m/s²)      x(m)     y(m)   psi(rad)  v(m/s)");
    for (k, ((d, a), z)) in plan
        .delta
        .iter()
        .zip(&plan.accel)
        .zip(&plan.states)
        .enumerate()
    {
        println!(
            "{k:>2} {d:>10.4} {a:>12.3} {:>9.2} {:>8.2} {:>9.4} {:>7.2}",
            z[0], z[1], z[2], z[3]
        );
    }
    // The plan's first state is where the vehicle goes under the first input.
    assert_eq!(plan.states.len(), 6);
    assert!(plan.min_safety.is_none_or(|b| b > 0.0), "the plan is safe");
    Ok(())
}
