//! The reaction ablation inside the safety evaluation: with `ablate_reaction` every candidate
//! is checked against one prediction, the teacher's for the ego's keep-lane path (computed
//! here by hand and by calling the teacher directly); without it the teacher's prediction for
//! a lane change differs from the keep-lane one.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use nudge_predictor::{History, Predictor, PredictorSpec, T_OBS};

use super::constraint::SafetyEval;
use super::*;
use crate::model::State;

const V: f64 = 12.0;

/// A dense scene: the ego at (0, 0) at 12 m/s, a target-lane (y = 3.7 m) follower alongside
/// its rear and a leader alongside its front, a car ahead in the ego's lane.
fn dense() -> (History, Vec<[f64; 2]>) {
    let agents = [
        (0.0, 0.0, V),
        (-4.0, 3.7, 12.5),
        (6.0, 3.7, 11.5),
        (22.0, 0.0, 11.0),
    ];
    let mut pos = Vec::new();
    for (x, y, v) in agents {
        for t in 0..T_OBS {
            pos.extend([x - v * (T_OBS - 1 - t) as f64 * 0.3, y]);
        }
    }
    (
        History::new(pos, agents.len()).unwrap(),
        vec![[4.5, 1.9]; agents.len()],
    )
}

/// A lane change from y = 0 to y = 3.7 at `V` on a two-lane road.
fn problem<'a>(h: &'a History, sizes: &'a [[f64; 2]]) -> PlanningProblem<'a> {
    super::tests::problem(h, sizes, V)
}

fn teacher() -> Box<dyn Predictor> {
    let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets");
    PredictorSpec::resolve("teacher", &assets, 6)
        .unwrap()
        .build()
}

/// Candidate states (this call's frame: the ego starts at the origin): a lane change reaching
/// `dy` metres sideways at 1.8 s at speed `v`.
fn candidate(dy: f64, v: f64) -> Vec<State> {
    (1..=6)
        .map(|k| {
            let f = k as f64 / 6.0;
            State::new(v * 0.3 * k as f64, dy * f * f * (3.0 - 2.0 * f), 0.0, v)
        })
        .collect()
}

/// The flat `[T, 2]` candidate the predictor sees for `states` (frame origin at the ego).
fn flat(states: &[State]) -> Vec<f64> {
    states.iter().flat_map(|z| [z[0], z[1]]).collect()
}

/// The teacher's prediction `[n − 1, 6, 2]` for the flat candidate `c`.
fn predict(h: &History, c: &[f64]) -> Vec<f64> {
    let mut t = teacher();
    let mut out = vec![0.0; (h.n_agents() - 1) * 12];
    t.set_scene(h).unwrap();
    t.predict(c, &mut out).unwrap();
    out
}

#[test]
fn ablated_evaluation_checks_every_candidate_against_the_keep_lane_prediction() {
    let (h, sizes) = dense();
    let p = problem(&h, &sizes);
    let s = {
        let mut s = PlannerSettings::default();
        s.safety.ablate_reaction = true;
        s
    };
    let constraint = SafetyConstraint::new(&p, &s);
    assert_eq!(constraint.vehicles().len(), 3);
    // The keep-lane path by hand: 12 m/s along the road at y = 0.
    let keep: Vec<f64> = (1..=6).flat_map(|k| [3.6 * k as f64, 0.0]).collect();
    let want = predict(&h, &keep);
    let mut model = teacher();
    model.set_scene(&h).unwrap();
    let mut safety = SafetyEval::new(&constraint, [0.0, 0.0], 6, 4, 0.0);
    safety.ablate_reaction(crate::keep_lane_path(&p.ego, 6, s.model.dt));
    let lane_change = candidate(3.7, V);
    let braking = candidate(0.0, 10.0);
    assert_ne!(flat(&lane_change), flat(&braking));
    let b_change = safety.eval(model.as_mut(), &lane_change).unwrap().min_b;
    assert_eq!(safety.prediction(), want.as_slice());
    let b_brake = safety.eval(model.as_mut(), &braking).unwrap().min_b;
    assert_eq!(safety.prediction(), want.as_slice());
    assert_eq!(safety.calls, 1, "the keep-lane prediction is made once");
    assert_ne!(
        b_change, b_brake,
        "two different candidates, one prediction"
    );
    // The lane change's own prediction differs: the ablation changed what was checked.
    assert_ne!(predict(&h, &flat(&lane_change)), want);
}

#[test]
fn without_ablation_the_teachers_prediction_answers_a_lane_change() {
    let (h, sizes) = dense();
    let p = problem(&h, &sizes);
    let s = PlannerSettings::default();
    let constraint = SafetyConstraint::new(&p, &s);
    let mut model = teacher();
    model.set_scene(&h).unwrap();
    let mut safety = SafetyEval::new(&constraint, [0.0, 0.0], 6, 4, 0.0);
    let lane_change = candidate(3.7, V);
    safety.eval(model.as_mut(), &lane_change).unwrap();
    let seen = safety.prediction().to_vec();
    assert_eq!(seen, predict(&h, &flat(&lane_change)));
    let keep = predict(&h, &flat(&candidate(0.0, V)));
    let largest = seen
        .iter()
        .zip(&keep)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(largest > 1e-4, "the teacher reacts: {largest} m");
    assert_eq!(safety.calls, 1);
}
