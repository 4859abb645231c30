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
