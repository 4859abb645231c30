//! The planner's own input checks: predictions of any predictor (a custom `Predictor`
//! implementation included) that are non-finite or physically absurd never yield a safe plan,
//! b evaluated on a NaN is unsafe, and problems with targets off the road or absurd reference
//! speeds are refused naming the field.
#![allow(clippy::unwrap_used)]

mod common;

use nudge_planner::{
    PlanStatus, Planner, PlannerError, PlannerSettings, PlanningProblem, SafetyConstraint,
};
use nudge_predictor::{ConstantVelocity, History, Predictor, PredictorError};

/// Ego at (0, 0) at 12 m/s on a two-lane road, a slower car 15 m ahead in its lane and one
/// 5 m behind in the left lane: both within `check_range`.
fn scene() -> (History, Vec<[f64; 2]>) {
    common::scene(&[(0.0, 0.0, 12.0), (15.0, 0.0, 9.0), (-5.0, 3.7, 12.0)])
}

fn problem<'a>(h: &'a History, sizes: &'a [[f64; 2]]) -> PlanningProblem<'a> {
    common::problem(h, sizes, 3.7)
}

/// How a [`Foreign`] predictor corrupts the constant-velocity prediction.
#[derive(Debug, Clone, Copy)]
enum Corruption {
    /// Every value NaN.
    AllNan,
    /// One value NaN: agent 2 (index 1 of the output), step 4, y.
    OneNan,
    /// One value +∞.
    OneInf,
    /// Every position shifted by 2e39 m (finite, absurd).
    Huge,
    /// Agent 1 teleports 500 m ahead at step 3 (finite, implausible for a road vehicle).
    Teleport,
}

/// A predictor from outside nudge-predictor: constant velocity, corrupted. It does not run
/// the predictor crate's output checks, so the planner must check its predictions itself.
struct Foreign {
    inner: ConstantVelocity,
    corruption: Corruption,
}

impl Predictor for Foreign {
    fn name(&self) -> &'static str {
        "foreign"
    }
    fn horizon(&self) -> usize {
        self.inner.horizon()
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.inner.set_scene(history)
    }
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        self.inner.predict(candidates, out)?;
        let t = self.inner.horizon();
        let per_candidate = 2 * t * 2; // two other agents
        for cand in out.chunks_exact_mut(per_candidate) {
            match self.corruption {
                Corruption::AllNan => cand.fill(f64::NAN),
                Corruption::OneNan => cand[2 * t + 2 * 3 + 1] = f64::NAN,
                Corruption::OneInf => cand[2 * t + 2 * 3 + 1] = f64::INFINITY,
                Corruption::Huge => cand.iter_mut().for_each(|v| *v += 2e39),
                Corruption::Teleport => cand[2 * 2] += 500.0,
            }
        }
        Ok(())
    }
}

/// Nothing non-finite or absurd is ever safe: the plan is a typed predictor error naming the
/// problem (or, at the very least, status `Unsafe`), never `Converged`/`MaxIterations` with a
/// safety value computed from garbage.
#[test]
fn corrupted_predictions_of_a_foreign_predictor_never_give_a_safe_plan() {
    let (h, sizes) = scene();
    for corruption in [
        Corruption::AllNan,
        Corruption::OneNan,
        Corruption::OneInf,
        Corruption::Huge,
        Corruption::Teleport,
    ] {
        let mut planner = Planner::new(PlannerSettings::default()).unwrap();
        let mut p = Foreign {
            inner: ConstantVelocity::new(6).unwrap(),
            corruption,
        };
        match planner.plan(&problem(&h, &sizes), &mut p) {
            Err(PlannerError::Predictor(
                PredictorError::NonFiniteOutput {
                    predictor: "foreign",
                    ..
                }
                | PredictorError::ImplausibleOutput {
                    predictor: "foreign",
                    ..
                },
            )) => {}
            Ok(plan) => assert_eq!(
                plan.status,
                PlanStatus::Unsafe,
                "{corruption:?}: a plan on corrupted predictions is {:?} with min_safety {:?}",
                plan.status,
                plan.min_safety
            ),
            Err(other) => panic!("{corruption:?}: unexpected error {other}"),
        }
    }
    // The same problem with the honest predictor plans normally (the scene is not the cause).
    let mut planner = Planner::new(PlannerSettings::default()).unwrap();
    let plan = planner
        .plan(&problem(&h, &sizes), &mut ConstantVelocity::new(6).unwrap())
        .unwrap();
    assert!(plan.min_safety.is_some_and(f64::is_finite));
}

/// The error a user sees names the predictor, the candidate, the agent and the step.
#[test]
fn the_refusal_of_a_foreign_prediction_names_agent_and_step() {
    let (h, sizes) = scene();
    let mut planner = Planner::new(PlannerSettings::default()).unwrap();
    let mut p = Foreign {
        inner: ConstantVelocity::new(6).unwrap(),
        corruption: Corruption::OneNan,
    };
    let msg = planner
        .plan(&problem(&h, &sizes), &mut p)
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("foreign") && msg.contains("agent 2") && msg.contains("step 4"),
        "{msg}"
    );
}

/// b at the executed step is −∞ (unsafe) when any checked vehicle's position is NaN, not the
/// minimum over the others.
#[test]
fn executed_safety_with_one_nan_position_is_unsafe() {
    let (h, sizes) = scene();
    let c = SafetyConstraint::new(&problem(&h, &sizes), &PlannerSettings::default());
    assert_eq!(c.vehicles().len(), 2);
    let ego = [3.6, 0.0, 0.0, 25.0];
    let fine = [[3.6, 0.0], [17.7, 0.0], [-1.4, 3.7]];
    let b = c.executed_min_b(ego, &fine).unwrap();
    assert!(b.is_finite() && b > 0.0, "{b}");
    for agent in [1, 2] {
        let mut bad = fine;
        bad[agent][1] = f64::NAN;
        assert_eq!(
            c.executed_min_b(ego, &bad),
            Some(f64::NEG_INFINITY),
            "NaN position of agent {agent}"
        );
    }
}

/// An edit of a problem.
type Edit = fn(&mut PlanningProblem<'_>);

/// Targets off the road and reference speeds outside the documented range are refused by
/// `PlanningProblem::check` naming the field (they used to plan to `Converged` with cost ∞).
#[test]
fn absurd_targets_and_reference_speeds_are_refused() {
    let (h, sizes) = scene();
    let mut planner = Planner::new(PlannerSettings::default()).unwrap();
    let mut cv = ConstantVelocity::new(6).unwrap();
    let cases: [(&str, Edit); 9] = [
        ("y_target", |p| p.y_target = 1e300),
        ("y_target", |p| p.y_target = -1e300),
        ("y_target", |p| p.y_target = 5.56),
        ("y_target", |p| p.y_target = -1.86),
        ("v_ref", |p| p.v_ref = -1.0),
        ("v_ref", |p| p.v_ref = 1e300),
        ("v_ref", |p| p.v_ref = 60.01),
        ("road", |p| p.road = [-1e300, 1e300]),
        ("ego.v", |p| p.ego.v = 1e300),
    ];
    for (field, edit) in cases {
        let mut p = problem(&h, &sizes);
        edit(&mut p);
        match planner.plan(&p, &mut cv) {
            Err(PlannerError::BadProblem { field: f, reason }) => {
                assert_eq!(f, field, "{reason}");
            }
            Ok(plan) => panic!(
                "{field}: accepted with status {:?}, cost {}",
                plan.status, plan.cost
            ),
            Err(e) => panic!("{field}: unexpected error {e}"),
        }
    }
    // The edges themselves, and v_ref 0 and 60 m/s, are accepted.
    for edit in [
        (|p: &mut PlanningProblem<'_>| p.y_target = 5.55) as Edit,
        |p| p.y_target = -1.85,
        |p| p.v_ref = 0.0,
        |p| p.v_ref = 60.0,
    ] {
        let mut p = problem(&h, &sizes);
        edit(&mut p);
        p.check().unwrap();
    }
    let msg = planner
        .plan(
            &PlanningProblem {
                y_target: 1e300,
                ..problem(&h, &sizes)
            },
            &mut cv,
        )
        .unwrap_err()
        .to_string();
    assert!(msg.contains("y_target") && msg.contains("road"), "{msg}");
}
