//! `fallback_nonreactive`: inadmissible candidates ranked by the worse of the planning
//! predictor's and a constant-velocity prediction, each measured on its own.

#![allow(clippy::unwrap_used)]

use nudge_predictor::{ConstantVelocity, History, Predictor, T_OBS};

use super::repair::{Candidate, Repairer, simple_inputs};
use super::tests::{model, problem};
use super::*;

/// Predicts every other agent from its last observed position driving along +x at its last
/// observed longitudinal speed, its lateral position held: a merging car the planning model
/// expects to stay in its lane.
struct Straight {
    last: Vec<[[f64; 2]; 2]>,
}

impl Predictor for Straight {
    fn name(&self) -> &'static str {
        "straight"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.last = (1..history.n_agents())
            .map(|i| [history.at(i, T_OBS - 2), history.at(i, T_OBS - 1)])
            .collect();
        Ok(())
    }
    fn predict(&mut self, _: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        for (i, [prev, last]) in self.last.iter().enumerate() {
            let dx = last[0] - prev[0];
            for k in 0..6 {
                let o = (i * 6 + k) * 2;
                out[o] = last[0] + dx * (k + 1) as f64;
                out[o + 1] = last[1];
            }
        }
        Ok(())
    }
}

/// The ego at 20 m/s in its lane (y = 0) and the `others` (x, y m; v_x, v_y m/s, observed
/// over the history); all 4.5 m × 1.9 m.
fn scene_of(others: &[(f64, f64, f64, f64)]) -> (History, Vec<[f64; 2]>) {
    let n = 1 + others.len();
    let mut pos = Vec::with_capacity(n * T_OBS * 2);
    for &(x, y, vx, vy) in std::iter::once(&(0.0, 0.0, 20.0, 0.0)).chain(others) {
        for t in 0..T_OBS {
            let back = (T_OBS - 1 - t) as f64 * 0.3;
            pos.extend([x - vx * back, y - vy * back]);
        }
    }
    (History::new(pos, n).unwrap(), vec![[4.5, 1.9]; n])
}

/// The repairs alone (no refinement, loose heading and corridor bounds), with the rule on or
/// off.
fn settings(on: bool) -> PlannerSettings {
    PlannerSettings {
        refine_iters: 0,
        heading_max: 3.0,
        overshoot_max: 100.0,
        brake_decel: 0.0,
        fallback_nonreactive: on,
        ..PlannerSettings::default()
    }
}

/// Every fallback candidate of the call on `p` (its simple inputs), checked by a repairer
/// whose planning predictor is `planning` and, when given, whose non-reactive predictor is
/// `nonreactive`; and the planning predictor calls made.
fn candidates<P: Predictor>(
    s: &PlannerSettings,
    p: &PlanningProblem<'_>,
    planning: &mut P,
    nonreactive: Option<&mut ConstantVelocity>,
) -> (Vec<Candidate>, usize) {
    let m = model(s);
    let lp = LinearisedProblem::new(s, &m, None, p);
    let constraint = SafetyConstraint::new(p, s);
    let mut safety = SafetyEval::new(
        &constraint,
        lp.origin,
        6,
        p.history.n_agents(),
        s.safety_min,
    );
    safety.count_overlap = s.contact_first;
    let mut r = Repairer {
        s,
        model: &m,
        lp: &lp,
        safety: &mut safety,
        predictor: planning,
        contingency: None,
        follower_gap: None,
        nonreactive: nonreactive.map(|cv| cv as &mut dyn Predictor),
    };
    let out: Vec<Candidate> = simple_inputs(s, &m, &lp)
        .into_iter()
        .map(|(d, a)| r.check(d, a).unwrap())
        .collect();
    let calls = r.safety.calls;
    (out, calls)
}

#[test]
fn an_inadmissible_candidate_ranks_by_the_worse_of_the_two_predictions() {
    let on = settings(true);
    let off = settings(false);
    let (mut cv_worse, mut learned_worse) = (0, 0);
    // A car in the target lane 3 m ahead drifting towards the ego at 2 m/s (the constant
    // velocity sees it come in, the planning predictor keeps it in its lane); a car 2.6 m to
    // the other side drifting away at 2 m/s (the planning predictor keeps it beside the ego).
    for others in [[(3.0, 3.7, 20.0, -2.0)], [(0.0, -2.6, 20.0, -2.0)]] {
        let (h, sizes) = scene_of(&others);
        let p = problem(&h, &sizes, 20.0);
        let mut straight = Straight { last: Vec::new() };
        straight.set_scene(&h).unwrap();
        let mut cv = ConstantVelocity::new(6).unwrap();
        cv.set_scene(&h).unwrap();
        // Each prediction alone, as the planning predictor with the rule off.
        let (learned, learned_calls) = candidates(&off, &p, &mut straight, None);
        let (cv_only, _) = candidates(&off, &p, &mut cv, None);
        let (both, both_calls) = candidates(&on, &p, &mut straight, Some(&mut cv));
        assert_eq!(
            both_calls, learned_calls,
            "the constant-velocity calls are not counted"
        );
        for (i, ((l, c), b)) in learned.iter().zip(&cv_only).zip(&both).enumerate() {
            assert_eq!(
                b.rank.safe, l.rank.safe,
                "candidate {i}: admissibility is unchanged"
            );
            assert_eq!(b.rollout, l.rollout);
            assert_eq!(
                b.min_b, l.min_b,
                "candidate {i}: the plan keeps its own prediction"
            );
            if l.rank.safe {
                assert_eq!(b.rank, l.rank, "candidate {i}");
                continue;
            }
            let value = l.rank.value.max(c.rank.value);
            assert!(
                (b.rank.value - value).abs() < 1e-9,
                "candidate {i}: {b:?} vs {l:?}, {c:?}"
            );
            let contact = l.rank.contact.max(c.rank.contact);
            assert!((b.rank.contact - contact).abs() < 1e-12, "candidate {i}");
            cv_worse += usize::from(c.rank.value > l.rank.value + 1e-9);
            learned_worse += usize::from(l.rank.value > c.rank.value + 1e-9);
        }
    }
    assert!(
        cv_worse > 0 && learned_worse > 0,
        "{cv_worse} {learned_worse}"
    );
}
