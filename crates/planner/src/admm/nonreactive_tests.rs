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
pub(super) struct Straight {
    pub(super) last: Vec<[[f64; 2]; 2]>,
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
pub(super) fn scene_of(others: &[(f64, f64, f64, f64)]) -> (History, Vec<[f64; 2]>) {
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

/// Runs `f` on a repairer of the call on `p` under `s` whose planning predictor is `planning`
/// and, when given, whose non-reactive predictor is `nonreactive` (no contingency or
/// follower-gap rule), with `f` getting the call's linearisation too.
fn with_repairer<R>(
    s: &PlannerSettings,
    p: &PlanningProblem<'_>,
    planning: &mut dyn Predictor,
    nonreactive: Option<&mut ConstantVelocity>,
    f: impl FnOnce(&mut Repairer<'_, '_>, &LinearisedProblem) -> R,
) -> R {
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
    f(&mut r, &lp)
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
    with_repairer(s, p, planning, nonreactive, |r, lp| {
        let out: Vec<Candidate> = simple_inputs(s, r.model, lp)
            .into_iter()
            .map(|(d, a)| r.check(d, a).unwrap())
            .collect();
        (out, r.safety.calls)
    })
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

/// Predicts agent 1 from its last observed position driving along +x at `vx` m/s, its lateral
/// position held: a driver the planning model expects to slow down in its lane.
struct Slowing {
    last: [f64; 2],
    vx: f64,
}

impl Predictor for Slowing {
    fn name(&self) -> &'static str {
        "slowing"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.last = history.at(1, T_OBS - 1);
        Ok(())
    }
    fn predict(&mut self, _: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        for k in 0..6 {
            out[2 * k] = self.last[0] + self.vx * 0.3 * (k + 1) as f64;
            out[2 * k + 1] = self.last[1];
        }
        Ok(())
    }
}

/// [`super::tests::hits_drifting_car`] for a roll-out in the call's frame (the ego starts at
/// the origin, so it is the world frame).
fn hits_drifting_car(z: &[State], car: (f64, f64, f64, f64)) -> bool {
    let world: Vec<[f64; 4]> = z.iter().map(|s| [s[0], s[1], s[2], s[3]]).collect();
    super::tests::hits_drifting_car(&world, car)
}

/// `fallback_avoid_nonreactive`: the ego keeps its lane at 20 m/s; a car 6 m ahead, 2.8 m to
/// the side (beside: the boxes cannot touch where it is) drives at 18 m/s and drifts towards
/// the ego at 1 m/s. The planning model expects it to slow to 12 m/s in its lane, so every
/// fallback is inadmissible (the car sits inside the ellipse) and accelerating past it is
/// the least violating. Off, that is the fallback, and at constant velocity (drift included)
/// its box meets the car's (the separating-axis test). On, the fallback is one that meets
/// nobody at constant velocity, the least violating of those; each candidate's
/// `hits_nonreactive` is the independent box check. With `avoid_min_speed` above the ego's
/// 20 m/s the rule does not apply, and the fallback is the one without it.
#[test]
fn with_nothing_admissible_the_fallback_keeps_clear_of_a_driver_drifting_in() {
    let car = (6.0, 2.8, 18.0, -1.0);
    let (h, sizes) = scene_of(&[car]);
    let mut p = problem(&h, &sizes, 20.0);
    p.y_target = 0.0;
    let mut best_of = Vec::new();
    for (rule, floor) in [(false, 0.0), (true, 0.0), (true, 20.0), (true, 20.5)] {
        let on = rule && p.ego.v >= floor;
        let s = PlannerSettings {
            fallback_avoid_nonreactive: rule,
            avoid_min_speed: floor,
            fallback_lattice: false,
            ..settings(false)
        };
        s.validate().unwrap();
        let mut planning = Slowing {
            last: [0.0; 2],
            vx: 12.0,
        };
        planning.set_scene(&h).unwrap();
        let mut cv = ConstantVelocity::new(6).unwrap();
        cv.set_scene(&h).unwrap();
        let (all, _) = candidates(&s, &p, &mut planning, Some(&mut cv));
        for c in &all {
            assert!(!c.rank.safe, "{:?}", c.accel);
            let hits = hits_drifting_car(&c.rollout, car);
            assert_eq!(c.rank.hits_nonreactive, on && hits, "{:?}", c.accel);
        }
        // The rule can choose: some candidates meet the car, some do not.
        assert!(all.iter().any(|c| hits_drifting_car(&c.rollout, car)));
        assert!(all.iter().any(|c| !hits_drifting_car(&c.rollout, car)));
        let best = best_fallback(&s, &p, &mut planning, &mut cv);
        assert!(!best.rank.safe);
        assert_eq!(
            hits_drifting_car(&best.rollout, car),
            !on,
            "{:?}",
            best.accel
        );
        let least = |pick: &dyn Fn(&Candidate) -> bool| {
            all.iter()
                .filter(|c| pick(c))
                .map(|c| c.rank.value)
                .fold(f64::INFINITY, f64::min)
        };
        let want = if on {
            least(&|c| !hits_drifting_car(&c.rollout, car))
        } else {
            least(&|_| true)
        };
        assert!((best.rank.value - want).abs() < 1e-12, "{on}: {best:?}");
        best_of.push(best.accel);
    }
    assert!(best_of[0][0] > 0.0 && best_of[1][0] < 0.0, "{best_of:?}");
    assert_eq!(best_of[2], best_of[1]);
    assert_eq!(best_of[3], best_of[0]);
}

/// [`Repairer::best_fallback`] of the call on `p` under `s`, with the planning predictor
/// `planning` and the constant-velocity one `cv`.
fn best_fallback<P: Predictor>(
    s: &PlannerSettings,
    p: &PlanningProblem<'_>,
    planning: &mut P,
    cv: &mut ConstantVelocity,
) -> Candidate {
    with_repairer(s, p, planning, Some(cv), |r, _| r.best_fallback().unwrap())
}
