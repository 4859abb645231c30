//! The contingency rule: the retreat manoeuvre on the nonlinear model, and the rule in the
//! execution check (the same nudge admitted with a safe retreat, refused with a blocked one).
#![allow(clippy::unwrap_used)]

use nudge_predictor::{History, Predictor};

use super::constraint::{SafetyConstraint, SafetyEval};
use super::contingency::Contingency;
use super::linearised::LinearisedProblem;
use super::repair::Repairer;
use super::tests::{last_two, problem, scene};
use crate::model::{Bicycle, State};
use crate::settings::{PlannerSettings, SafetyGeometry};

/// Every other vehicle at constant velocity from its last observed motion, except agent 1
/// when `blocking` and the candidate ends nearer the own lane than the nudge below (its last
/// y below 1.6 m): then it
/// closes up from its place behind the candidate's path to sit right behind the candidate's
/// last state at step 6 (about 20 m/s, a plausible motion): a follower in the own lane that
/// fills the gap the ego left, so going back is unsafe while going on is not.
struct Backstop {
    blocking: bool,
    last: Vec<[[f64; 2]; 2]>,
    calls: usize,
}

impl Predictor for Backstop {
    fn name(&self) -> &'static str {
        "backstop"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.last = last_two(history);
        Ok(())
    }
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        self.calls += 1;
        let back = self.blocking && candidates[11] < 1.6;
        for (i, [prev, now]) in self.last.iter().enumerate().skip(1) {
            for k in 0..6 {
                let o = ((i - 1) * 6 + k) * 2;
                let p = if back && i == 1 {
                    let gap = 15.0 * (1.0 - (k + 1) as f64 / 6.0) + 4.6;
                    [candidates[2 * k] - gap, 0.0]
                } else {
                    let n = (k + 1) as f64;
                    [
                        now[0] + n * (now[0] - prev[0]),
                        now[1] + n * (now[1] - prev[1]),
                    ]
                };
                out[o] = p[0];
                out[o + 1] = p[1];
            }
        }
        Ok(())
    }
}

fn settings(contingency: bool) -> PlannerSettings {
    PlannerSettings {
        contingency,
        safety_geometry: SafetyGeometry::Boxes,
        ..PlannerSettings::default()
    }
}

fn model(s: &PlannerSettings) -> Bicycle {
    Bicycle {
        l_f: s.l_f,
        l_r: s.l_r,
        dt: s.dt,
    }
}

/// A nudge to the left: steering that takes the ego's box across the line at y = 1.85 m.
fn nudge() -> (Vec<f64>, Vec<f64>) {
    (vec![0.03, 0.04, 0.02, 0.0, -0.02, -0.03], vec![0.0; 6])
}

/// The retreat branches at the plan's first state across the line (no later than
/// T − `contingency_steps`), keeps the plan's states before it bit for bit, and from there
/// brakes at `contingency_accel` within the jerk bound and steers back towards the own lane
/// within the steering box and rate bound, on the nonlinear model.
#[test]
fn the_retreat_steers_back_and_brakes_from_the_branch_state() {
    let s = settings(true);
    let m = model(&s);
    let (h, sizes) = scene(12.0, 0.0, &[(-15.0, 0.0, 12.0)]);
    let mut p = problem(&h, &sizes, 12.0);
    assert!(Contingency::new(&s, &LinearisedProblem::new(&s, &m, None, &p)).is_none());
    p.y_retreat = Some(0.0);
    let lp = LinearisedProblem::new(&s, &m, None, &p);
    assert!(
        Contingency::new(&settings(false), &lp).is_none(),
        "off by default"
    );
    let c = Contingency::new(&s, &lp).expect("a lane change with a retreat lane");
    let (d, a) = nudge();
    let mut plan = vec![State::zeros(); 6];
    m.rollout(&lp.start, &d, &a, &mut plan);
    // Across: the box's half extent across the road (0.95 m at ψ ≈ 0) past the line at 1.85.
    let k = c
        .first_across(lp.ego_size, &plan)
        .expect("the nudge crosses");
    for (i, z) in plan.iter().enumerate() {
        let edge = z[1] + 0.5 * (4.5 * z[2].sin().abs() + 1.9 * z[2].cos().abs());
        assert_eq!(i + 1 >= k, edge > 1.85 || i + 1 > k, "step {}", i + 1);
    }
    assert_eq!(c.branch(k, 6), k.min(3));
    assert_eq!(c.branch(1, 6), 1);
    assert_eq!(c.branch(5, 6), 3);
    for j in 0..=3 {
        let path = c.path(&m, &lp, (&d, &a, &plan), j, -2.0);
        assert_eq!(path.len(), 6);
        assert_eq!(&path[..j], &plan[..j], "the plan up to the branch");
        // The manoeuvre, recomputed: from the branch state with the plan's inputs there.
        let from = if j == 0 { lp.start } else { plan[j - 1] };
        let prev = if j == 0 {
            [0.0, 0.0]
        } else {
            [d[j - 1], a[j - 1]]
        };
        let (rd, ra) = c.manoeuvre(&m, &lp, &from, prev, 6 - j, -2.0);
        let mut tail = vec![State::zeros(); 6 - j];
        m.rollout(&from, &rd, &ra, &mut tail);
        assert_eq!(&path[j..], &tail[..], "the retreat rolled out on the model");
        // Braking: −2 m/s² reached within the jerk bound da_max from the previous value.
        let mut before = prev[1];
        for &x in &ra {
            assert!((x - before).abs() <= s.da_max + 1e-12 && x >= -2.0 - 1e-12);
            before = x;
        }
        assert_eq!(*ra.last().unwrap(), -2.0);
        let mut before = prev[0];
        for &x in &rd {
            assert!((x - before).abs() <= s.ddelta_max + 1e-12 && x.abs() <= s.delta_max);
            before = x;
        }
        assert!(path[5][3] < from[3], "slower at the end");
        if j > 0 {
            // From a state moving left, the retreat turns right: ends with a lower heading,
            // and from a state across the line it ends nearer the own lane than the plan.
            assert!(path[5][2] < plan[5][2]);
            assert!(
                path[5][1] < plan[5][1] - 0.3,
                "{} vs {}",
                path[5][1],
                plan[5][1]
            );
        }
    }
}

/// The same nudge is admitted when its retreat is safe and refused when the predictor says
/// the own lane's follower closes the gap behind the retreating ego; without the rule it is
/// admitted either way. The retreats are predicted (one call each, counted).
#[test]
fn a_nudge_is_admissible_only_with_a_safe_retreat() {
    let (h, sizes) = scene(12.0, 0.0, &[(-15.0, 0.0, 12.0)]);
    let mut p = problem(&h, &sizes, 12.0);
    p.y_retreat = Some(0.0);
    let (d, a) = nudge();
    let verdict = |contingency: bool, blocking: bool| {
        let s = settings(contingency);
        let m = model(&s);
        let lp = LinearisedProblem::new(&s, &m, None, &p);
        let constraint = SafetyConstraint::new(&p, &s);
        let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, 0.0);
        let mut predictor = Backstop {
            blocking,
            last: Vec::new(),
            calls: 0,
        };
        predictor.set_scene(&h).unwrap();
        let mut r = Repairer {
            s: &s,
            model: &m,
            lp: &lp,
            safety: &mut safety,
            predictor: &mut predictor,
            contingency: Contingency::new(&s, &lp),
            follower_gap: None,
            nonreactive: None,
        };
        let c = r.check(d.clone(), a.clone()).unwrap();
        let calls = r.safety.calls;
        (c, calls)
    };
    // The plan itself is safe under either prediction (it ends in the target lane).
    for blocking in [false, true] {
        let (c, calls) = verdict(false, blocking);
        assert!(
            c.rank.safe && !c.retreat_blocked,
            "blocking {blocking}: {:?} {:?} {:?}",
            c.rank,
            c.min_b,
            c.rollout
        );
        assert_eq!(calls, 1);
        assert!(c.rollout[5][1] > 1.6);
    }
    let (free, calls) = verdict(true, false);
    assert!(free.rank.safe && free.predicted_safe && !free.retreat_blocked);
    assert_eq!(calls, 2, "the plan and its first retreat");
    let (blocked, calls) = verdict(true, true);
    assert!(!blocked.rank.safe && !blocked.predicted_safe && blocked.retreat_blocked);
    assert!(
        blocked.rank.value > 0.0,
        "ranked by the retreat's violation"
    );
    assert_eq!(
        calls, 3,
        "the plan and both retreats (braking, then holding)"
    );
    assert_eq!(blocked.min_b, free.min_b, "the plan's own b is unchanged");
}
