//! A planning horizon of 10 steps (3 s) through the public planner: with the teacher (rolled out
//! 10 steps) the plan has 10 states, and its safety verdict is the one under the teacher's own
//! 10-step prediction of that plan (computed here by calling the teacher directly); the 6-step
//! student is refused with a typed error naming both horizons. (The PyTorch truth of the 10-step
//! roll-out: `crates/predictor/tests/predictor_parity.rs` and `python/train/tests/test_horizon.py`.)
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

mod common;

use nudge_planner::{Planner, PlannerError, PlannerSettings, PlanningProblem, SafetyConstraint};
use nudge_predictor::{History, PredictorSpec};

const HORIZON: usize = 10;

fn assets() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets")
}

/// Agents `(x, y, speed)` along +x, agent 0 the ego; a gap in the target lane (y = 3.7 m).
fn scene() -> (History, Vec<[f64; 2]>) {
    common::scene(&[
        (0.0, 0.0, 12.0),
        (-25.0, 3.7, 12.0),
        (20.0, 0.0, 10.0),
        (30.0, 3.7, 13.0),
    ])
}

fn problem<'a>(h: &'a History, sizes: &'a [[f64; 2]]) -> PlanningProblem<'a> {
    common::problem(h, sizes, 3.7)
}

fn settings() -> PlannerSettings {
    {
        let mut s = PlannerSettings::default();
        s.model.horizon = HORIZON;
        s
    }
}

#[test]
fn teacher_planner_at_10_steps_judges_its_plan_by_the_10_step_roll_out() {
    let (h, sizes) = scene();
    let p = problem(&h, &sizes);
    let spec = PredictorSpec::resolve("teacher", &assets(), HORIZON).unwrap();
    let mut planning = spec.build();
    assert_eq!(planning.horizon(), HORIZON);
    let plan = Planner::new(settings())
        .unwrap()
        .plan(&p, planning.as_mut())
        .unwrap();
    assert_eq!(
        (plan.states.len(), plan.delta.len(), plan.accel.len()),
        (10, 10, 10)
    );
    assert!(plan.predictor_calls > 0);
    // The teacher's 10-step prediction of the plan, by a direct call.
    let candidate: Vec<f64> = plan.states.iter().flat_map(|s| [s[0], s[1]]).collect();
    let mut direct = spec.build();
    direct.set_scene(&h).unwrap();
    let mut prediction = vec![f64::NAN; 3 * HORIZON * 2];
    direct.predict(&candidate, &mut prediction).unwrap();
    assert!(prediction.iter().all(|v| v.is_finite()));
    let b = SafetyConstraint::new(&p, &settings())
        .binding(&plan.states, &prediction)
        .unwrap()
        .b;
    assert_eq!(plan.min_safety.map(f64::to_bits), Some(b.to_bits()));
}

#[test]
fn the_6_step_student_cannot_plan_10_steps() {
    let (h, sizes) = scene();
    let mut student = PredictorSpec::resolve("student", &assets(), HORIZON)
        .unwrap()
        .build();
    assert_eq!(student.horizon(), 6);
    let err = Planner::new(settings())
        .unwrap()
        .plan(&problem(&h, &sizes), student.as_mut())
        .unwrap_err();
    assert!(
        matches!(
            err,
            PlannerError::HorizonMismatch {
                predictor: 6,
                planner: 10
            }
        ),
        "{err}"
    );
}
