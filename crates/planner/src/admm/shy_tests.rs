//! `fallback_shy`: fallback sequences that move the ego across its own lane, away from a
//! vehicle hugging the line, instead of braking beside it.

#![allow(clippy::unwrap_used)]

use super::constraint::SafetyEval;
use super::linearised::LinearisedProblem;
use super::repair::{shy_goals, shy_inputs};
use super::tests::{Gate, model, plain_repairer, problem, scene};
use super::*;
use crate::extents::Lanes;
use crate::scenario::LaneExtent;
use nudge_predictor::{History, Predictor};

/// Two endless lanes, [−1.85, 1.85] and [1.85, 5.55] m.
const BOUNDS: [f64; 3] = [-1.85, 1.85, 5.55];
const OPEN: [LaneExtent; 2] = [
    LaneExtent {
        begin: -1000.0,
        end: 5000.0,
        begins: false,
        ends: false,
    },
    LaneExtent {
        begin: -1000.0,
        end: 5000.0,
        begins: false,
        ends: false,
    },
];

/// The problem of the tests: the ego at `v` m/s in the right lane at `y0`, keeping its lane
/// (goal y = 0), with the vehicles `others` (x, y, speed).
fn lane_keeping<'a>(
    h: &'a History,
    sizes: &'a [[f64; 2]],
    v: f64,
    lanes: Option<Lanes<'a>>,
) -> PlanningProblem<'a> {
    PlanningProblem {
        y_target: 0.0,
        lanes,
        ..problem(h, sizes, v)
    }
}

fn two_lanes() -> Option<Lanes<'static>> {
    Some(Lanes {
        bounds: &BOUNDS,
        extents: &OPEN,
    })
}

/// The goals by hand: the box (1.9 m wide) 0.1 m from the right line at y = −1.85 + 0.95 +
/// 0.1 = −0.8 and from the left one at +0.8, clamped into the call's lateral bounds: the
/// corridor of a plan keeping its lane (±`overshoot_max`), and the road's right edge less the
/// box's half extent across the road at the heading bound (0.2 rad): −1.85 + ½(4.5 sin 0.2 +
/// 1.9 cos 0.2). None without a layout or in a lane too narrow; none where the ego already is.
#[test]
fn the_shy_goals_are_the_lane_sides_within_the_bounds() {
    let (h, sizes) = scene(12.0, 0.0, &[]);
    let s = PlannerSettings {
        fallback_shy: true,
        ..PlannerSettings::default()
    };
    let m = model(&s);
    let goals = |s: &PlannerSettings, p: &PlanningProblem<'_>| {
        shy_goals(&LinearisedProblem::new(s, &m, None, p))
    };
    let p = lane_keeping(&h, &sizes, 12.0, two_lanes());
    let near = |got: Vec<f64>, want: &[f64]| {
        got.len() == want.len() && got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-9)
    };
    assert!(near(goals(&s, &p), &[-0.3, 0.3]), "{:?}", goals(&s, &p));
    let wide = PlannerSettings {
        overshoot_max: 100.0,
        ..s.clone()
    };
    let right_edge = -1.85 + 0.5 * (4.5 * 0.2_f64.sin() + 1.9 * 0.2_f64.cos());
    assert!(
        near(goals(&wide, &p), &[right_edge, 0.8]),
        "{:?}",
        goals(&wide, &p)
    );
    assert!(goals(&s, &lane_keeping(&h, &sizes, 12.0, None)).is_empty());
    let narrow = [-1.0, 1.0, 5.55];
    let p_narrow = lane_keeping(
        &h,
        &sizes,
        12.0,
        Some(Lanes {
            bounds: &narrow,
            extents: &OPEN,
        }),
    );
    assert!(goals(&s, &p_narrow).is_empty());
    // The ego already 0.1 m from its lane's right line: only the left goal (in its frame).
    let (h_right, _) = scene(12.0, -0.8, &[]);
    let mut p_right = lane_keeping(&h_right, &sizes, 12.0, two_lanes());
    p_right.ego.y = -0.8;
    p_right.y_target = -0.8;
    assert!(
        near(goals(&wide, &p_right), &[1.6]),
        "{:?}",
        goals(&wide, &p_right)
    );
    // Off: no shy sequence.
    let off = PlannerSettings::default();
    assert!(!off.fallback_shy);
    let lp = LinearisedProblem::new(&off, &m, None, &p);
    assert!(shy_inputs(&off, &m, &lp).is_empty());
    let lp = LinearisedProblem::new(&s, &m, None, &p);
    assert_eq!(shy_inputs(&s, &m, &lp).len(), 8);
}

/// A slow car (4 m/s) 12 m ahead in the next lane on the left, its box 0.05 m from the line,
/// and the ego at 12 m/s keeping its lane, the others predicted at constant velocity: passing
/// it in the lane's centre, at any of the fallbacks' speeds, is inside its safety ellipse, so
/// without the setting no fallback is admissible. With it the fallback takes the sequence
/// that moves right at its speed: admissible, it keeps 12 m/s, and its box stays wholly
/// inside its lane at every step (checked on the roll-out's corners, independently of the
/// bounds the planner checked it against).
#[test]
fn the_fallback_moves_over_in_its_lane_to_pass_a_car_hugging_the_line() {
    let (h, sizes) = scene(12.0, 0.0, &[(12.0, 1.85 + 0.95 + 0.05, 4.0)]);
    let p = lane_keeping(&h, &sizes, 12.0, two_lanes());
    let best = |s: &PlannerSettings| {
        let m = model(s);
        let lp = LinearisedProblem::new(s, &m, None, &p);
        let constraint = SafetyConstraint::new(&p, s);
        let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, s.safety_min);
        let mut cv = Gate::ahead(f64::INFINITY);
        cv.set_scene(&h).unwrap();
        let mut r = plain_repairer(s, &m, &lp, &mut safety, &mut cv);
        r.best_fallback().unwrap()
    };
    let off = best(&PlannerSettings::default());
    assert!(!off.rank.safe, "{:?}", off.rank);
    let on = best(&PlannerSettings {
        fallback_shy: true,
        ..PlannerSettings::default()
    });
    assert!(on.rank.safe, "{:?}", on.rank);
    assert!(on.accel.iter().all(|&a| a == 0.0), "{:?}", on.accel);
    let end = on.rollout.last().unwrap();
    assert!((end[3] - 12.0).abs() < 1e-9);
    assert!(end[1] < -0.15, "it moves right: {end:?}");
    for z in &on.rollout {
        let (sin, cos) = z[2].sin_cos();
        for (dx, dy) in [(2.25, 0.95), (2.25, -0.95), (-2.25, 0.95), (-2.25, -0.95)] {
            let y = z[1] + dx * sin + dy * cos;
            assert!((-1.85..=1.85).contains(&y), "corner y {y} at {z:?}");
        }
    }
}
