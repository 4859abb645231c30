//! Long runs (issue 49 class 10): `max_steps` accepts up to 1000, and a run that long stays
//! finite and recorded in every world even when vehicles drift more than the predictors'
//! accepted span (`nudge_predictor::limits::MAX_AGENT_OFFSET`, 1 km) apart. Before, the
//! observed history of every agent was handed to the predictors, which refused it once two
//! vehicles were 1 km apart, and the whole run was dropped (0 steps recorded).
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use nudge_planner::{PlannerSettings, Scenario};
use nudge_predictor::ConstantVelocity;
use nudge_predictor::limits::MAX_AGENT_OFFSET;
use nudge_sim::{SimConfig, World, WorldModel, simulate};

fn scene(name: &str) -> Scenario {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../assets/scenes")
        .join(format!("{name}.safetensors"));
    Scenario::from_file(p).unwrap()
}

/// The largest distance (m) between two agents' positions after the last recorded step.
fn spread(rec: &nudge_sim::RunRecord) -> f64 {
    let t = rec.steps.last().unwrap().trace.as_ref().unwrap();
    let mut worst: f64 = 0.0;
    for a in &t.agents {
        for b in &t.agents {
            worst = worst.max((a[0] - b[0]).hypot(a[1] - b[1]));
        }
    }
    worst
}

#[test]
fn a_thousand_step_log_replay_run_is_recorded_past_the_predictors_span() {
    let sc = scene("us101-8_1-t02.1-ego56");
    let settings = PlannerSettings::default();
    let cfg = SimConfig {
        world: World::LogReplay,
        max_steps: 1000,
        settle_steps: 1000,
        ..SimConfig::default()
    };
    let cancel = nudge_sim::Cancel::new();
    let control = nudge_sim::RunControl {
        cancel: &cancel,
        trace: true,
    };
    let mut cv = ConstantVelocity::default();
    let rec = nudge_sim::simulate_with(
        &sc,
        &settings,
        &cfg,
        8,
        &mut cv,
        WorldModel::LogReplay,
        control,
    )
    .unwrap();
    assert!(rec.steps.len() > 400, "{} steps", rec.steps.len());
    assert!(
        spread(&rec) > MAX_AGENT_OFFSET,
        "the vehicles stayed within {} m",
        spread(&rec)
    );
    for s in &rec.steps {
        assert!(s.ego.iter().all(|v| v.is_finite()), "step {}", s.step);
        let t = s.trace.as_ref().unwrap();
        assert!(t.agents.iter().flatten().all(|v| v.is_finite()));
        assert_eq!(t.agents.len(), sc.n_agents);
        assert_eq!(t.predicted.len(), sc.n_agents - 1);
    }
    // Untraced, the same run.
    let mut cv = ConstantVelocity::default();
    let plain = simulate(&sc, &settings, &cfg, 8, &mut cv, WorldModel::LogReplay).unwrap();
    assert_eq!(plain.steps.len(), rec.steps.len());
    for (a, b) in plain.steps.iter().zip(&rec.steps) {
        assert_eq!(a.ego, b.ego);
    }
}
