//! `lateral_drift`: checked vehicles drifting across the road are checked at least as far along
//! their drift as their observed lateral speed carries them.

#![allow(clippy::unwrap_used)]

use nudge_predictor::{History, Predictor, T_OBS};

use super::nonreactive_tests::{Straight, scene_of};
use super::tests::problem;
use super::*;

/// The rule on or off, everything else at its default.
fn settings(on: bool) -> PlannerSettings {
    PlannerSettings {
        lateral_drift: on,
        ..PlannerSettings::default()
    }
}

/// The ego at 20 m/s keeping its lane (y = 0) of the two-lane road of [`problem`].
fn keep_lane<'a>(h: &'a History, sizes: &'a [[f64; 2]]) -> PlanningProblem<'a> {
    let mut p = problem(h, sizes, 20.0);
    p.y_target = 0.0;
    p
}

#[test]
fn the_drift_is_the_mean_lateral_speed_over_the_last_steps_from_the_threshold() {
    // (x, y, v_x, v_y) observed over the whole history, and whether it drifts: in from the
    // left, away to the left, in from the right, below the threshold, exactly at it, none.
    let others = [
        ((10.0, 3.7, 20.0, -0.5), true),
        ((-10.0, 3.7, 20.0, 1.0), true),
        ((-10.0, -3.7, 20.0, 1.0), true),
        ((20.0, 3.7, 20.0, -0.2), false),
        ((30.0, 3.7, 20.0, -0.25), true),
        ((40.0, 3.7, 20.0, 0.0), false),
    ];
    let (h, _) = scene_of(&others.map(|(car, _)| car));
    let on = settings(true);
    for (i, &((_, _, _, vy), drifts)) in others.iter().enumerate() {
        let want = if drifts { vy * 0.3 } else { 0.0 };
        let got = lateral_drift(&h, i + 1, &on);
        assert!(
            (got - want).abs() < 1e-9,
            "agent {}: {got} vs {want}",
            i + 1
        );
        assert_eq!(lateral_drift(&h, i + 1, &settings(false)), 0.0);
    }
    // Only the last DRIFT_STEPS steps count: a driver that drifted in earlier and has kept
    // its lateral position since does not drift, one that began to drift then does.
    let mut pos = Vec::new();
    for (x, v) in [(0.0, 20.0), (10.0, 20.0)] {
        pos.extend((0..T_OBS).flat_map(|t| [x + v * 0.3 * t as f64, 3.7]));
    }
    for t in 0..T_OBS - DRIFT_STEPS {
        pos[2 * T_OBS + 2 * t + 1] = 3.7 + 0.3 * (T_OBS - DRIFT_STEPS - 1 - t) as f64;
    }
    let mut late = pos.clone();
    for t in T_OBS - DRIFT_STEPS..T_OBS {
        late[2 * T_OBS + 2 * t + 1] = 3.7 - 0.3 * (t + 1 + DRIFT_STEPS - T_OBS) as f64;
    }
    assert_eq!(lateral_drift(&History::new(pos, 2).unwrap(), 1, &on), 0.0);
    let got = lateral_drift(&History::new(late, 2).unwrap(), 1, &on);
    assert!((got + 0.3).abs() < 1e-9, "{got}");
}

/// The planning predictor keeps a car drifting in at 1 m/s in its lane; with the rule its
/// checked positions are y_last + k·drift along the road where the network put it; so are a
/// car drifting away from the ego beyond where the network puts it, and not a car that does
/// not drift.
#[test]
fn a_drifting_car_is_checked_where_its_drift_takes_it() {
    let others = [
        (5.0, 3.4, 20.0, -1.0),
        (-8.0, -3.4, 18.0, -0.6),
        (30.0, 3.7, 20.0, 0.0),
    ];
    let (h, sizes) = scene_of(&others);
    let p = keep_lane(&h, &sizes);
    let z: Vec<State> = (1..=6)
        .map(|k| State::new(6.0 * k as f64, 0.0, 0.0, 20.0))
        .collect();
    let mut predictions = Vec::new();
    for on in [false, true] {
        let s = settings(on);
        let constraint = SafetyConstraint::new(&p, &s);
        assert_eq!(constraint.vehicles().len(), 3);
        let mut straight = Straight { last: Vec::new() };
        straight.set_scene(&h).unwrap();
        let mut safety = SafetyEval::new(&constraint, [0.0, 0.0], 6, 4, s.safety_min);
        let e = safety.eval(&mut straight, &z).unwrap();
        predictions.push((safety.prediction().to_vec(), e));
    }
    let ((off, off_eval), (on, on_eval)) = (&predictions[0], &predictions[1]);
    for (i, &(_, y, _, vy)) in others.iter().enumerate() {
        for k in 0..6 {
            let o = (i * 6 + k) * 2;
            assert_eq!(
                on[o],
                off[o],
                "agent {} step {k}: x is the network's",
                i + 1
            );
            assert_eq!(
                off[o + 1],
                y,
                "the network keeps agent {} in its lane",
                i + 1
            );
            let want = y + vy * 0.3 * (k + 1) as f64;
            assert!(
                (on[o + 1] - want).abs() < 1e-9,
                "agent {} step {k}: {} vs {want}",
                i + 1,
                on[o + 1]
            );
        }
    }
    assert!(off_eval.min_b.unwrap() > 0.0, "{off_eval:?}");
    assert!(on_eval.min_b.unwrap() < 0.0, "{on_eval:?}");
}

/// Predicts NaN for every agent.
struct Nan;

impl Predictor for Nan {
    fn name(&self) -> &'static str {
        "nan"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, _: &History) -> nudge_predictor::Result<()> {
        Ok(())
    }
    fn predict(&mut self, _: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        out.fill(f64::NAN);
        Ok(())
    }
}

/// A non-finite prediction of a drifting car is never replaced by its drift.
#[test]
fn a_non_finite_prediction_stays_unsafe_under_the_drift() {
    let (h, sizes) = scene_of(&[(5.0, 3.4, 20.0, -1.0)]);
    let p = keep_lane(&h, &sizes);
    let s = settings(true);
    let constraint = SafetyConstraint::new(&p, &s);
    assert!(constraint.vehicles()[0].drift < 0.0);
    let z: Vec<State> = (1..=6)
        .map(|k| State::new(6.0 * k as f64, 0.0, 0.0, 20.0))
        .collect();
    let mut safety = SafetyEval::new(&constraint, [0.0, 0.0], 6, 2, s.safety_min);
    let e = safety.eval(&mut Nan, &z).unwrap();
    assert!(safety.prediction().iter().all(|y| y.is_nan()));
    assert_eq!(e.min_b, Some(f64::NEG_INFINITY));
    assert_eq!(e.violation, f64::INFINITY);
}

/// The whole planner: a car 8 m ahead and 3.4 m to the side drives at 18 m/s and drifts in
/// at 1 m/s while the planning predictor keeps it in its lane. Off, the plan holds the ego's
/// 20 m/s, and at constant velocity (drift included) their boxes meet (the separating-axis
/// test); on, the plan brakes behind it, admissible, and keeps clear of it.
#[test]
fn the_plan_keeps_clear_of_a_driver_cutting_in_that_the_network_keeps_in_its_lane() {
    let car = (8.0, 3.4, 18.0, -1.0);
    let (h, sizes) = scene_of(&[car]);
    let p = keep_lane(&h, &sizes);
    let mut hits = Vec::new();
    for on in [false, true] {
        let mut straight = Straight { last: Vec::new() };
        let plan = Planner::new(settings(on))
            .unwrap()
            .plan(&p, &mut straight)
            .unwrap();
        hits.push(super::tests::hits_drifting_car(&plan.states, car));
        if on {
            assert!(plan.min_safety.unwrap() >= 0.0, "{:?}", plan.status);
            assert!(plan.accel[0] < 0.0, "{:?}", plan.accel);
            assert_ne!(plan.status, PlanStatus::Unsafe);
            assert_ne!(plan.status, PlanStatus::Fallback);
        }
    }
    assert_eq!(hits, [true, false]);
}
