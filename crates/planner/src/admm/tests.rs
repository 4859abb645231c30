//! Unit tests that force each branch of the ADMM call (feasibility restoration, descent,
//! backtracking, fallback, a QP failure) with small custom predictors and crafted problems, and
//! check what each returns.
#![allow(clippy::unwrap_used)]

use nudge_predictor::{ConstantVelocity, History, Predictor, T_OBS};

use super::constraint::{Evaluation, SafetyEval};
use super::inputs::{Input, InputQps};
use super::lagrangian::Lagrangian;
use super::linearised::LinearisedProblem;
use super::repair::{Repairer, fallback_accels, lattice_inputs, retreat_inputs, simple_inputs};
use super::restoration::restore;
use super::workspace::{CurrentSafety, Iterates, Workspace, mat_vec};
use super::*;
use crate::qp::{BoxRateQp, QpName, QpStatus, RateBox};

/// (steering, acceleration) sequences.
type Inputs = (Vec<f64>, Vec<f64>);

/// Ego at (0, y0) with speed v; others `(x, y, speed)`; all driving along +x.
pub(super) fn scene(v: f64, y0: f64, others: &[(f64, f64, f64)]) -> (History, Vec<[f64; 2]>) {
    let n = 1 + others.len();
    let mut pos = Vec::with_capacity(n * T_OBS * 2);
    for &(x, y, s) in std::iter::once(&(0.0, y0, v)).chain(others) {
        for t in 0..T_OBS {
            pos.extend([x - s * (T_OBS - 1 - t) as f64 * 0.3, y]);
        }
    }
    (History::new(pos, n).unwrap(), vec![[4.5, 1.9]; n])
}

/// A lane change from y = 0 to y = 3.7 at `v` on a two-lane road.
pub(super) fn problem<'a>(h: &'a History, sizes: &'a [[f64; 2]], v: f64) -> PlanningProblem<'a> {
    PlanningProblem {
        ego: EgoState {
            x: 0.0,
            y: 0.0,
            psi: 0.0,
            v,
        },
        last_delta: 0.0,
        last_accel: 0.0,
        history: h,
        sizes,
        y_target: 3.7,
        v_ref: v,
        road: [-1.85, 5.55],
        y_retreat: None,
        lanes: None,
    }
}

/// Predicts every other agent at constant velocity from its last observed motion (always safe
/// for the car 40 m behind at the ego's speed) until `strict_from` calls have been made; from
/// then on, whenever the candidate's last lateral position (longitudinal with
/// [`Gate::ahead`]) exceeds `limit`, it predicts
/// agent 1 chasing the candidate at 29 m per step (a plausible prediction: the planner refuses
/// motions beyond 30 m per step), so that it sits on top of the candidate (b = −1) from the
/// step it catches up.
pub(super) struct Gate {
    strict_from: usize,
    limit: f64,
    /// The coordinate of the candidate's last position that is gated: 0 (x) or 1 (y).
    axis: usize,
    /// Gate the candidates that end below the limit instead of beyond it.
    below: bool,
    /// Last two observed positions of every agent.
    last: Vec<[[f64; 2]; 2]>,
    calls: usize,
}

impl Gate {
    fn new(strict_from: usize, y_limit: f64) -> Self {
        Self {
            strict_from,
            limit: y_limit,
            axis: 1,
            below: false,
            last: Vec::new(),
            calls: 0,
        }
    }

    /// Gated on the candidate's last longitudinal position beyond `x_limit` from the first
    /// call.
    pub(super) fn ahead(x_limit: f64) -> Self {
        Self {
            axis: 0,
            ..Self::new(0, x_limit)
        }
    }

    /// Gated on the candidate's last longitudinal position short of `x_limit` from the first
    /// call: a vehicle closing from behind catches every candidate that does not get that far.
    fn behind(x_limit: f64) -> Self {
        Self {
            below: true,
            ..Self::ahead(x_limit)
        }
    }
}

impl Predictor for Gate {
    fn name(&self) -> &'static str {
        "gate"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.last = last_two(history);
        Ok(())
    }
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        let last = candidates[10 + self.axis];
        let gated = if self.below {
            last < self.limit
        } else {
            last > self.limit
        };
        let blocked = self.calls >= self.strict_from && gated;
        self.calls += 1;
        let chase = |k: usize| [candidates[2 * k], candidates[2 * k + 1]];
        predict_others(
            &self.last,
            blocked.then_some(&chase as &dyn Fn(usize) -> [f64; 2]),
            out,
        );
        Ok(())
    }
}

/// The start of one call under `s` on the linearised problem `lp`, as the call makes it: the
/// evaluator of `constraint` (6 steps, the ego and one other agent) at `threshold`, the safety
/// of the start's Z under `predictor`, the workspace from that start and the input QPs.
pub(super) fn call_start<'c>(
    s: &PlannerSettings,
    lp: &LinearisedProblem,
    constraint: &'c SafetyConstraint,
    threshold: f64,
    predictor: &mut dyn Predictor,
) -> (SafetyEval<'c>, Evaluation, Workspace, InputQps) {
    let mut safety = SafetyEval::new(constraint, lp.origin, 6, 2, threshold);
    let iterates = Iterates::start(lp);
    let first = safety.eval(predictor, &iterates.z).unwrap();
    let ws = Workspace::new(s, lp, iterates, CurrentSafety::new(first, &safety));
    let qps = InputQps::new(s, lp).unwrap();
    (safety, first, ws, qps)
}

/// The last two observed positions `[n][2]` (m) of every agent.
pub(super) fn last_two(history: &History) -> Vec<[[f64; 2]; 2]> {
    (0..history.n_agents())
        .map(|i| [history.at(i, T_OBS - 2), history.at(i, T_OBS - 1)])
        .collect()
}

/// Predictions `[n − 1, 6, 2]` into `out`: every other agent at constant velocity from its
/// `last` two positions, except agent 1 when `chase` is given: it moves towards `chase(k)` at
/// step k at 29 m per step (a plausible prediction: the planner refuses motions beyond 30 m
/// per step) and sits on it once it caught up.
fn predict_others(
    last: &[[[f64; 2]; 2]],
    chase: Option<&dyn Fn(usize) -> [f64; 2]>,
    out: &mut [f64],
) {
    for (i, [prev, now]) in last.iter().enumerate().skip(1) {
        let mut p = *now;
        for k in 0..6 {
            let o = ((i - 1) * 6 + k) * 2;
            p = match chase {
                Some(target) if i == 1 => {
                    let c = target(k);
                    let (dx, dy) = (c[0] - p[0], c[1] - p[1]);
                    let d = dx.hypot(dy);
                    if d <= 29.0 {
                        c
                    } else {
                        [p[0] + 29.0 * dx / d, p[1] + 29.0 * dy / d]
                    }
                }
                _ => [p[0] + now[0] - prev[0], p[1] + now[1] - prev[1]],
            };
            out[o] = p[0];
            out[o + 1] = p[1];
        }
    }
}

/// A lower bound of b for the car behind at constant velocity: at least 35 m behind the ego
/// at the same lateral position, as the constraint sizes it for two road-aligned cars (ψ of
/// the ego's planned state ignored: |sin ψ| ≈ 0 changes a_x by millimetres).
fn far_b_lower_bound(s: &PlannerSettings) -> f64 {
    let a_x = s.safety.ellipse_scale * (4.5 + 1.9) + s.safety.margin_x;
    (35.0 / a_x).powi(2) - 1.0
}

/// The nonlinear roll-out of (δ, a) from the problem's ego state, in the road frame.
pub(super) fn rollout_world(
    s: &PlannerSettings,
    p: &PlanningProblem<'_>,
    d: &[f64],
    a: &[f64],
) -> Vec<[f64; 4]> {
    let model = Bicycle {
        l_f: s.model.l_f,
        l_r: s.model.l_r,
        dt: s.model.dt,
    };
    let z0 = State::new(p.ego.x, p.ego.y, p.ego.psi, p.ego.v);
    let mut out = vec![State::zeros(); d.len()];
    model.rollout(&z0, d, a, &mut out);
    out.iter().map(|z| [z[0], z[1], z[2], z[3]]).collect()
}

/// The defaults with the refinement and the heading and corridor bounds off: the repair
/// branches after the execution check (backtracking, fallbacks) alone, as they are reached
/// when the refinement fails.
pub(super) fn repairs_only() -> PlannerSettings {
    {
        let mut s = PlannerSettings::default();
        s.repair.refine_iters = 0;
        s.bounds.heading_max = 3.0;
        s.bounds.overshoot_max = 100.0;
        s.safety.brake_decel = 0.0;
        s
    }
}

/// A repairer of the call on `lp` without the constant-velocity check of the lattice.
pub(super) fn plain_repairer<'a, 'c>(
    s: &'a PlannerSettings,
    model: &'a Bicycle,
    lp: &'a LinearisedProblem,
    safety: &'a mut SafetyEval<'c>,
    predictor: &'a mut dyn Predictor,
) -> Repairer<'a, 'c> {
    Repairer {
        s,
        model,
        lp,
        safety,
        predictor,
        nonreactive: None,
    }
}

/// The bicycle of the settings `s`.
pub(super) fn model(s: &PlannerSettings) -> Bicycle {
    Bicycle {
        l_f: s.model.l_f,
        l_r: s.model.l_r,
        dt: s.model.dt,
    }
}

/// A car 40 m behind in the target lane: checked, never in the way.
fn car_behind_in_target_lane() -> (History, Vec<[f64; 2]>) {
    scene(12.0, 0.0, &[(-40.0, 3.7, 12.0)])
}

/// A car 8 m ahead in the ego's lane at half the ego's speed: the constant-velocity nominal
/// (the ego keeps its lane and speed) runs into it, so the Z-update starts from an unsafe Z.
fn blocked_start() -> (History, Vec<[f64; 2]>) {
    scene(12.0, 0.0, &[(8.0, 0.0, 6.0)])
}

/// Feasibility restoration from an unsafe Z: it moves Z, the violation it reports is the
/// violation of the new Z (re-evaluated), lower than before, and Z stays within its bounds;
/// with and without Hessian scaling (Newton + pinned push, or gradient + position push).
#[test]
fn restoration_reduces_the_violation_of_an_unsafe_start() {
    for hessian_scaled in [true, false] {
        let s = PlannerSettings::default();
        let (h, sizes) = blocked_start();
        let p = problem(&h, &sizes, 12.0);
        let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
        let constraint = SafetyConstraint::new(&p, &s);
        assert_eq!(constraint.vehicles().len(), 1);
        let mut cv = ConstantVelocity::default();
        cv.set_scene(&h).unwrap();
        let threshold = s.safety.safety_min;
        let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, threshold);
        let iterates = Iterates::start(&lp);
        let first = safety.eval(&mut cv, &iterates.z).unwrap();
        assert!(
            !first.is_safe(threshold) && first.violation > 0.0,
            "{first:?}"
        );
        let current = CurrentSafety::new(first, &safety);
        let mut ws = Workspace::new(&s, &lp, iterates, current);
        if !hessian_scaled {
            // The path taken when H cannot be inverted.
            ws.curvature.newton = None;
            ws.curvature.pinned = None;
        }
        // The gradient and steps at Z, as the Z-update prepares them.
        let Workspace {
            iterates,
            curvature,
            scratch,
            current,
            ..
        } = &mut ws;
        let g = Lagrangian {
            s: &s,
            lp: &lp,
            delta: &iterates.delta,
            accel: &iterates.accel,
            duals: &iterates.duals,
        };
        g.value(&iterates.z, &mut scratch.residual);
        g.gradient(
            &iterates.z,
            &scratch.residual,
            &mut scratch.weighted,
            &mut scratch.gradient,
        );
        assert_eq!(curvature.newton.is_some(), hessian_scaled);
        if let (Some(hn), Some(hp)) = (curvature.newton.as_ref(), curvature.pinned.as_ref()) {
            mat_vec(hn, &scratch.gradient, &mut scratch.newton_step);
            mat_vec(hp, &scratch.gradient, &mut scratch.pinned_step);
        }
        let before = iterates.z.clone();
        let moved = restore(
            &g,
            curvature,
            &mut iterates.z,
            scratch,
            current,
            &mut safety,
            &mut cv,
        )
        .unwrap();
        assert!(
            moved,
            "restoration did not move Z (hessian_scaled {hessian_scaled})"
        );
        assert_ne!(iterates.z, before);
        let again = safety.eval(&mut cv, &iterates.z).unwrap();
        assert_eq!(again.violation, current.violation);
        assert_eq!(again.min_b, current.min_b);
        assert!(
            current.violation < first.violation,
            "violation {} not below {}",
            current.violation,
            first.violation
        );
        for (k, z) in iterates.z.iter().enumerate() {
            assert!(
                z[1] >= lp.lower[k][1] && z[1] <= lp.upper[k][1] && z[3] >= 0.0,
                "{z}"
            );
        }
    }
}

/// Whole Z-updates from the unsafe start: the first restores (the violation falls), and once
/// safe, descent accepts only safe trials that lower G (so min b stays above the threshold).
#[test]
fn z_updates_restore_then_descend_safely() {
    let s = PlannerSettings::default();
    let (h, sizes) = blocked_start();
    let p = problem(&h, &sizes, 12.0);
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let constraint = SafetyConstraint::new(&p, &s);
    let mut cv = ConstantVelocity::default();
    cv.set_scene(&h).unwrap();
    let threshold = s.safety.safety_min;
    let (mut safety, first, mut ws, mut qps) = call_start(&s, &lp, &constraint, threshold, &mut cv);
    let mut timings = PhaseTimings::default();
    let mut violations = vec![first.violation];
    let mut safe_since = None;
    for it in 0..s.admm.max_iter {
        let mut t = 0.0;
        qps.update(Input::Steering, &s, &lp, &mut ws, it, &mut t)
            .unwrap();
        qps.update(Input::Acceleration, &s, &lp, &mut ws, it, &mut t)
            .unwrap();
        ws.update_z(&s, &lp, &mut safety, &mut cv, &mut timings)
            .unwrap();
        violations.push(ws.current.violation);
        let now = safety.eval(&mut cv, &ws.iterates.z).unwrap();
        assert_eq!(now.min_b, ws.current.min_b, "bookkeeping at iteration {it}");
        if now.is_safe(threshold) {
            safe_since.get_or_insert(it);
        } else {
            assert!(
                safe_since.is_none(),
                "Z unsafe again at iteration {it} after being safe"
            );
        }
        ws.update_duals(&s, &lp);
    }
    assert!(
        violations[1] < violations[0],
        "the first Z-update did not restore: {violations:?}"
    );
    assert!(safe_since.is_some(), "never safe: {violations:?}");
    assert_eq!(timings.z_updates_s.len(), s.admm.max_iter);
}

/// The predictor calls of a whole plan with an always-safe [`Gate`].
fn reference_plan(s: &PlannerSettings, p: &PlanningProblem<'_>) -> Plan {
    let mut planner = Planner::new(s.clone()).unwrap();
    let plan = planner.plan(p, &mut Gate::new(usize::MAX, 0.0)).unwrap();
    assert!(matches!(
        plan.status,
        PlanStatus::Converged | PlanStatus::MaxIterations
    ));
    assert_eq!(plan.checked, 1);
    assert!(plan.predictor_calls > 1);
    assert!(
        plan.states[5][1] > 0.5,
        "the lane change barely starts: {:?}",
        plan.states
    );
    plan
}

/// Lateral position after 6 steps of the reference inputs scaled by θ (cold start: the
/// nominal is zero, so backtracking towards it scales the inputs).
fn y_end(s: &PlannerSettings, p: &PlanningProblem<'_>, plan: &Plan, theta: f64) -> f64 {
    let d: Vec<f64> = plan.delta.iter().map(|d| theta * d).collect();
    let a: Vec<f64> = plan.accel.iter().map(|a| theta * a).collect();
    rollout_world(s, p, &d, &a)[5][1]
}

/// A roll-out that turns unsafe after ADMM (the gate closes for the execution check) and is
/// safe again with the inputs halved: `Backtracked`, with inputs exactly θ = 1/2 of the ADMM
/// inputs, the states their roll-out, and min b that of the car behind (not the blocked −1).
#[test]
fn unsafe_rollout_is_backtracked_to_the_first_safe_pull() {
    let s = repairs_only();
    let (h, sizes) = car_behind_in_target_lane();
    let p = problem(&h, &sizes, 12.0);
    let admm = reference_plan(&s, &p);
    let admm_calls = admm.predictor_calls - 1;
    let limit = 0.5 * (y_end(&s, &p, &admm, 0.75) + y_end(&s, &p, &admm, 0.5));
    let mut planner = Planner::new(s.clone()).unwrap();
    let plan = planner.plan(&p, &mut Gate::new(admm_calls, limit)).unwrap();
    assert_eq!(plan.status, PlanStatus::Backtracked);
    let half: Vec<f64> = admm.delta.iter().map(|d| 0.5 * d).collect();
    let half_a: Vec<f64> = admm.accel.iter().map(|a| 0.5 * a).collect();
    assert_eq!(plan.delta, half);
    assert_eq!(plan.accel, half_a);
    assert_eq!(plan.states, rollout_world(&s, &p, &half, &half_a));
    // The roll-out check, θ = 3/4 (unsafe), θ = 1/2 (safe).
    assert_eq!(plan.predictor_calls, admm_calls + 3);
    let b = plan.min_safety.unwrap();
    assert!(b > far_b_lower_bound(&s), "min b {b}");
    assert_eq!(plan.rollout_min_safety, plan.min_safety);
    assert_eq!(plan.iterations, admm.iterations);
}

/// A gate so tight that no backtracking step passes: `Fallback`, with the cheapest safe simple
/// sequence (safe = ending below the gate), checked on its roll-out.
#[test]
fn unsafe_rollout_falls_back_to_the_cheapest_safe_simple_sequence() {
    let s = repairs_only();
    let (h, sizes) = car_behind_in_target_lane();
    let p = problem(&h, &sizes, 12.0);
    let admm = reference_plan(&s, &p);
    let admm_calls = admm.predictor_calls - 1;
    let limit = 0.5 * y_end(&s, &p, &admm, 0.25);
    let mut planner = Planner::new(s.clone()).unwrap();
    let plan = planner.plan(&p, &mut Gate::new(admm_calls, limit)).unwrap();
    assert_eq!(plan.status, PlanStatus::Fallback);
    // Independent choice: every candidate rolled out; safe iff it ends below the gate; the
    // cheapest safe one by J (the nominal is zero on a cold start).
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let mut candidates = vec![(vec![0.0; 6], vec![0.0; 6])];
    candidates.extend(simple_inputs(&s, &model(&s), &lp));
    let mut best: Option<(f64, &Inputs)> = None;
    for c in &candidates {
        let states = rollout_world(&s, &p, &c.0, &c.1);
        if states[5][1] > limit {
            continue;
        }
        let local: Vec<State> = states
            .iter()
            .map(|z| State::new(z[0], z[1], z[2], z[3]))
            .collect();
        let cost = lp.cost(&s, &c.0, &c.1, &local);
        if best.is_none_or(|(b, _)| cost < b) {
            best = Some((cost, c));
        }
    }
    let (cost, (d, a)) = best.unwrap();
    assert_eq!(&plan.delta, d);
    assert_eq!(&plan.accel, a);
    assert_eq!(plan.states, rollout_world(&s, &p, d, a));
    assert!(
        (plan.cost - cost).abs() <= 1e-9 * cost.max(1.0),
        "{} vs {cost}",
        plan.cost
    );
    assert!(plan.states[5][1] <= limit);
    // Roll-out check, 3 backtracking steps, the nominal and two simple sequences per
    // acceleration profile (the four constants).
    assert_eq!(plan.predictor_calls, admm_calls + 1 + 3 + 1 + 2 * 4);
    assert!(plan.min_safety.unwrap() > 0.0);
    assert_eq!(plan.rollout_min_safety, plan.min_safety);
}

/// Through the whole call: an ego whose measured state lies 1,040 m ahead of its last
/// observed position (beside a car 995 m ahead, within the check range) gets a plan whose
/// every candidate the predictors would refuse. None is passed to the predictor; each is
/// counted in `refused_candidates` and none is safe, where the predictor's error used to end
/// the call.
#[test]
fn a_call_whose_candidates_the_predictors_refuse_returns_an_unsafe_plan() {
    let s = PlannerSettings::default();
    let (h, sizes) = scene(12.0, 0.0, &[(995.0, 0.0, 12.0)]);
    let p = PlanningProblem {
        ego: EgoState {
            x: 1040.0,
            y: 0.0,
            psi: 0.0,
            v: 12.0,
        },
        ..problem(&h, &sizes, 12.0)
    };
    let mut cv = ConstantVelocity::default();
    let plan = Planner::new(s).unwrap().plan(&p, &mut cv).unwrap();
    assert_eq!(plan.predictor_calls, 0, "{plan:?}");
    assert!(plan.refused_candidates > 0, "{plan:?}");
    assert_eq!(plan.status, PlanStatus::Unsafe);
    assert_eq!(plan.min_safety, Some(f64::NEG_INFINITY));
}

/// A candidate the predictors would refuse (a step longer than
/// `nudge_predictor::limits::MAX_CANDIDATE_STEP` from the ego's last observed position, or a
/// non-finite state) is never passed to the predictor and is not safe; one in range is
/// predicted; without `ego_last` the predictor gets every candidate and refuses that one with
/// its typed error (what ended a closed-loop run whose ADMM overshot by 1 km in one step).
#[test]
fn a_candidate_the_predictors_refuse_is_unsafe_and_never_predicted() {
    let s = PlannerSettings::default();
    let (h, sizes) = car_behind_in_target_lane();
    let p = problem(&h, &sizes, 12.0);
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let constraint = SafetyConstraint::new(&p, &s);
    let mut cv = ConstantVelocity::default();
    cv.set_scene(&h).unwrap();
    let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, s.safety.safety_min);
    safety.ego_last = Some(h.at(0, T_OBS - 1));
    let near: Vec<State> = (1..=6)
        .map(|k| State::new(3.6 * k as f64, 0.0, 0.0, 12.0))
        .collect();
    let e = safety.eval(&mut cv, &near).unwrap();
    assert!(e.is_safe(s.safety.safety_min), "{e:?}");
    assert_eq!((safety.calls, safety.refused), (1, 0));

    let mut far = near.clone();
    far[3][0] = far[2][0] + nudge_predictor::limits::MAX_CANDIDATE_STEP + 1.0;
    let world: Vec<f64> = far
        .iter()
        .flat_map(|z| [z[0] + lp.origin[0], z[1] + lp.origin[1]])
        .collect();
    assert!(
        cv.predict(&world, &mut [0.0; 12]).is_err(),
        "the predictor refuses it"
    );
    let e = safety.eval(&mut cv, &far).unwrap();
    assert!(!e.is_safe(s.safety.safety_min), "{e:?}");
    assert_eq!(e, Evaluation::not_evaluated());
    assert_eq!((safety.calls, safety.refused), (1, 1));

    let mut nan = near.clone();
    nan[2][1] = f64::NAN;
    assert!(
        !safety
            .eval(&mut cv, &nan)
            .unwrap()
            .is_safe(s.safety.safety_min)
    );
    assert_eq!((safety.calls, safety.refused), (1, 2));

    safety.ego_last = None;
    let refused = safety.eval(&mut cv, &far);
    assert!(
        matches!(refused, Err(PlannerError::Predictor(_))),
        "{refused:?}"
    );
}

/// The repairs alone: backtracking returns the first safe pull towards the nominal, the
/// fallback the best by rank, both checked on their roll-outs.
#[test]
fn repairer_checks_every_candidate_on_its_rollout() {
    let s = repairs_only();
    let (h, sizes) = car_behind_in_target_lane();
    let p = problem(&h, &sizes, 12.0);
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let constraint = SafetyConstraint::new(&p, &s);
    let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, s.safety.safety_min);
    // Steering left within the box and rate bounds; the gate closes between where θ = 3/4
    // and θ = 1/2 of it end.
    let steer: Vec<f64> = (1..=6)
        .map(|k| (0.9 * k as f64 * s.bounds.ddelta_max).min(0.9 * s.bounds.delta_max))
        .collect();
    let end = |theta: f64| {
        let d: Vec<f64> = steer.iter().map(|d| theta * d).collect();
        rollout_world(&s, &p, &d, &[0.0; 6])[5][1]
    };
    let limit = 0.5 * (end(0.75) + end(0.5));
    assert!(end(1.0) > limit && end(0.5) < limit);
    let mut gate = Gate::new(0, limit);
    gate.set_scene(&h).unwrap();
    let m = model(&s);
    let mut r = plain_repairer(&s, &m, &lp, &mut safety, &mut gate);
    let c = r.check(steer.clone(), vec![0.0; 6]).unwrap();
    assert!(!c.rank.safe && c.min_b == Some(-1.0), "{:?}", c.min_b);
    assert!(
        c.rank.value > 0.0,
        "an unsafe candidate ranks by its violation"
    );
    let back = r.backtrack(&steer, &[0.0; 6]).unwrap().unwrap();
    let want: Vec<f64> = steer.iter().map(|d| 0.5 * d).collect();
    assert_eq!(back.delta, want);
    assert!(back.rank.safe);
    let mut states = vec![State::zeros(); 6];
    m.rollout(&lp.start, &back.delta, &back.accel, &mut states);
    assert_eq!(back.rollout, states);
    let best = r.best_fallback().unwrap();
    assert!(best.rank.safe && best.rollout[5][1] <= limit);
    // No safe candidate is cheaper; the nominal (zero) comes first among them.
    let mut all = vec![(vec![0.0; 6], vec![0.0; 6])];
    all.extend(simple_inputs(&s, &m, &lp));
    for (d, a) in all {
        let c = r.check(d, a).unwrap();
        assert_eq!(c.rank.safe, c.rollout[5][1] <= limit);
        if c.rank.safe {
            assert!(
                best.rank.value <= c.rank.value,
                "{} > {}",
                best.rank.value,
                c.rank.value
            );
        }
    }
}

/// A Clarabel failure of an input QP inside `plan` is a status, not an error: the ADMM
/// iterates are dropped and the plan is the cheapest safe simple sequence, checked on its
/// roll-out, with the failing QP named.
#[test]
fn qp_failure_ends_in_a_checked_fallback_plan() {
    // w_a = 1e308 overflows the α-QP's Hessian to ∞: Clarabel stops with a numerical error.
    // Validation refuses such a weight, so the planner is built without it (the failure
    // stands for any Clarabel failure on valid settings).
    let s = {
        let mut s = PlannerSettings::default();
        s.cost.w_a = 1e308;
        s
    };
    assert!(s.validate().is_err());
    let (h, sizes) = scene(12.0, 0.0, &[(6.0, 3.7, 12.0)]);
    let p = problem(&h, &sizes, 12.0);
    let mut planner = Planner {
        model: Planner::new(PlannerSettings::default()).unwrap().model,
        settings: s.clone(),
        warm: None,
        cancel: None,
    };
    let mut cv = ConstantVelocity::default();
    let plan = planner.plan(&p, &mut cv).unwrap();
    match plan.status {
        PlanStatus::SolverFailed { qp, status } => {
            assert_eq!(qp, QpName::Alpha);
            assert!(!matches!(status, QpStatus::Solved | QpStatus::AlmostSolved));
        }
        other => panic!("expected SolverFailed, got {other:?}"),
    }
    assert_eq!(plan.iterations, 1);
    assert_eq!(plan.states, rollout_world(&s, &p, &plan.delta, &plan.accel));
    assert_eq!(plan.rollout_min_safety, plan.min_safety);
    assert!(
        plan.min_safety.unwrap() > s.safety.safety_min,
        "the fallback is safe"
    );
    assert!(
        plan.accel.iter().all(|a| *a == 0.0),
        "any acceleration costs 1e308"
    );
    assert_eq!(plan.checked, 1);
    // The next call starts from the fallback plan shifted (and fails the same way).
    let again = planner.plan(&p, &mut cv).unwrap();
    assert!(matches!(again.status, PlanStatus::SolverFailed { .. }));
}

/// The input QP reports a failure with its name and iteration.
#[test]
fn input_qp_failure_names_the_qp_and_iteration() {
    let bounds = RateBox {
        lo: -0.1,
        hi: 0.1,
        rate: 0.05,
        prev: 0.0,
    };
    let hessian = vec![f64::NAN; 9];
    let failure = match BoxRateQp::new(QpName::Delta, &hessian, 3, bounds) {
        Err(f) => f,
        Ok(mut qp) => qp.solve(&[0.0; 3], &mut [0.0; 3], 7).unwrap_err(),
    };
    assert_eq!(failure.qp, QpName::Delta);
    assert!(failure.iteration == 7 || failure.status == QpStatus::Setup);
    assert!(!matches!(
        failure.status,
        QpStatus::Solved | QpStatus::AlmostSolved
    ));
}

/// Predicts fixed positions at step 1 (`[n − 1]`) and every agent 500 m away afterwards.
struct StepOne(Vec<[f64; 2]>);

impl Predictor for StepOne {
    fn name(&self) -> &'static str {
        "step_one"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, _: &History) -> nudge_predictor::Result<()> {
        Ok(())
    }
    fn predict(&mut self, _: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        for (agent, p) in self.0.iter().enumerate() {
            for k in 0..6 {
                let o = (agent * 6 + k) * 2;
                let far = if k == 0 { 0.0 } else { 500.0 };
                out[o] = p[0] + far;
                out[o + 1] = p[1];
            }
        }
        Ok(())
    }
}

/// The simulator's `executed_min_b` is the constraint the planner evaluates at step 1 of a
/// candidate equal to the executed motion: the same value, bit for bit, for vehicles that
/// moved forward (heading from their motion) and one that stood still (its last observed
/// heading); vehicles out of range are not checked.
#[test]
fn executed_min_b_is_the_planners_step_one_constraint() {
    let s = PlannerSettings::default();
    // A car ahead drifting left, a car beside that stopped, one out of range.
    let (h, sizes) = scene(
        12.0,
        0.0,
        &[(10.0, 3.5, 11.0), (-3.0, -3.6, 0.0), (90.0, 0.0, 12.0)],
    );
    let p = problem(&h, &sizes, 12.0);
    let constraint = SafetyConstraint::new(&p, &s);
    let checked: Vec<usize> = constraint.vehicles().iter().map(|v| v.index).collect();
    assert_eq!(checked, [1, 2]);
    let moved = vec![[13.4, 3.2], [-3.0, -3.6], [93.6, 0.0]];
    let ego_next = [3.6, 0.05, 0.03, 12.0];
    let mut positions = vec![[ego_next[0], ego_next[1]]];
    positions.extend_from_slice(&moved);
    let executed = constraint.executed_min_b(ego_next, &positions).unwrap();
    // The planner's evaluation of a candidate whose first state is the executed one.
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 4, s.safety.safety_min);
    let mut z = vec![State::new(-1000.0, 0.0, 0.0, 12.0); 6];
    z[0] = State::new(ego_next[0], ego_next[1], ego_next[2], ego_next[3]);
    let planned = safety
        .eval(&mut StepOne(moved.clone()), &z)
        .unwrap()
        .min_b
        .unwrap();
    assert_eq!(executed.to_bits(), planned.to_bits());
    // Independent geometry: ellipses at the headings in radians (the moving car's from its
    // displacement, the stopped car's 0), equal up to the trigonometry's rounding; no
    // closing-speed margin at step 1 (it is the horizon's terminal condition).
    let b = |other: [f64; 2], heading: f64, margin: f64| {
        let mut e = crate::Ellipse::with_headings(
            sizes[0],
            ego_next[2],
            [4.5, 1.9],
            heading,
            s.safety.ellipse_scale,
            s.safety.margin_x,
            s.safety.margin_y,
        );
        e.a_x += margin;
        e.value([ego_next[0], ego_next[1]], other)
    };
    let want = b(positions[1], (-0.3f64).atan2(3.4), 0.0).min(b(positions[2], 0.0, 0.0));
    // The terminal margin of the car ahead: it drives 3.4 m in 0.3 s, slower than the ego's
    // 12 m/s, so the ego needs its extra braking distance at brake_decel; none for the
    // stopped car behind the ego.
    let v = constraint.vehicles()[0];
    let ahead_speed: f64 = 3.4 / 0.3;
    let margin = (12.0f64.powi(2) - ahead_speed.powi(2)) / (2.0 * s.safety.brake_decel);
    let terminal = constraint.b(&v, ego_next, [10.0, 3.5], moved[0], true).0;
    assert!((terminal - b(positions[1], (-0.3f64).atan2(3.4), margin)).abs() < 1e-12);
    let behind = constraint.vehicles()[1];
    assert_eq!(
        constraint.closing_margin([3.6, 0.05], 12.0, [-3.0, -3.6], moved[1]),
        0.0
    );
    assert!(
        constraint
            .b(&behind, ego_next, [-3.0, -3.6], moved[1], true)
            .0
            > 0.0
    );
    assert!((executed - want).abs() < 1e-12, "{executed} vs {want}");
    assert_eq!(
        SafetyConstraint::new(&problem(&h, &sizes[..], 12.0), &{
            let mut s = s;
            s.safety.check_range = 1.0;
            s
        })
        .executed_min_b(ego_next, &positions),
        None
    );
}

/// From call `from` on, predicts agent 1 moving to a fixed road position `at` at 29 m per step
/// (a plausible prediction: the planner refuses motions beyond 30 m per step) and staying
/// there; before that, and every other agent always, at constant velocity from its last
/// observed motion (always safe for the car 40 m behind at the ego's speed). A smooth obstacle
/// that appears only for the execution check.
struct Obstacle {
    from: usize,
    at: [f64; 2],
    /// Last two observed positions of every agent.
    last: Vec<[[f64; 2]; 2]>,
    calls: usize,
}

impl Obstacle {
    fn new(from: usize, at: [f64; 2]) -> Self {
        Self {
            from,
            at,
            last: Vec::new(),
            calls: 0,
        }
    }
}

impl Predictor for Obstacle {
    fn name(&self) -> &'static str {
        "obstacle"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.last = last_two(history);
        Ok(())
    }
    fn predict(&mut self, _candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        let present = self.calls >= self.from;
        self.calls += 1;
        let at = self.at;
        let stay = move |_k: usize| at;
        predict_others(
            &self.last,
            present.then_some(&stay as &dyn Fn(usize) -> [f64; 2]),
            out,
        );
        Ok(())
    }
}

/// An obstacle that appears for the execution check just beside where the ADMM roll-out
/// ends (b slightly below 0): the refinement moves the inputs until the roll-out is safe,
/// and the plan is that roll-out — admissible, within the bounds, cheaper than what
/// backtracking towards the (zero) nominal gives.
#[test]
fn an_inadmissible_rollout_is_refined_on_the_nonlinear_model() {
    // A loose heading bound: the reference ADMM roll-out is admissible as it is; no
    // closing-speed margin (the obstacle stands still: the ellipse alone is tested here).
    let s = {
        let mut s = PlannerSettings::default();
        s.bounds.heading_max = 0.5;
        s.safety.brake_decel = 0.0;
        s
    };
    let (h, sizes) = car_behind_in_target_lane();
    let p = problem(&h, &sizes, 12.0);
    let admm = reference_plan(&s, &p);
    let admm_calls = admm.predictor_calls - 1;
    let end = admm.states[5];
    // The ellipse's lateral semi-axis for two road-aligned cars, and an obstacle 0.97 of it
    // to the left of the roll-out's last position (b ≈ −0.06 there).
    let a_y = s.safety.ellipse_scale * 1.9 + s.safety.margin_y;
    let at = [end[0], end[1] + 0.97 * a_y];
    let mut obstacle = Obstacle::new(admm_calls, at);
    let mut planner = Planner::new(s.clone()).unwrap();
    let plan = planner.plan(&p, &mut obstacle).unwrap();
    assert_eq!(plan.status, PlanStatus::Refined, "{:?}", plan.status);
    assert_eq!(plan.states, rollout_world(&s, &p, &plan.delta, &plan.accel));
    // Independent check of safety: b of the obstacle at every step of the returned states.
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let constraint = SafetyConstraint::new(&p, &s);
    let v = constraint.vehicles()[0];
    let mut min_b = f64::INFINITY;
    for z in &plan.states {
        let dir = [z[2].cos().abs(), z[2].sin().abs()];
        let b = constraint.ellipse(&v, dir, at, at).value([z[0], z[1]], at);
        min_b = min_b.min(b);
    }
    assert!(
        min_b > s.safety.safety_min,
        "refined plan unsafe: b = {min_b}"
    );
    assert_eq!(
        plan.min_safety,
        Some(min_b).map(|_| plan.min_safety.unwrap())
    );
    assert!((plan.min_safety.unwrap() - min_b).abs() < 1e-9);
    // Within the bounds.
    for (k, z) in plan.states.iter().enumerate() {
        assert!(z[2].abs() <= lp.upper[k][2] + 1e-12, "heading {z:?}");
        assert!(z[1] - p.ego.y <= lp.upper[k][1] + 1e-12, "lateral {z:?}");
    }
    // Away from the obstacle, and no more than needed: cheaper than the backtracked plan.
    assert!(plan.states[5][1] < end[1]);
    let backtracked = {
        let mut o = Obstacle::new(admm_calls, at);
        let mut planner = Planner::new({
            let mut s = s.clone();
            s.repair.refine_iters = 0;
            s
        })
        .unwrap();
        planner.plan(&p, &mut o).unwrap()
    };
    assert!(
        matches!(
            backtracked.status,
            PlanStatus::Backtracked | PlanStatus::Fallback
        ),
        "{:?}",
        backtracked.status
    );
    assert!(
        plan.cost < backtracked.cost,
        "refined {} vs {:?} {}",
        plan.cost,
        backtracked.status,
        backtracked.cost
    );
}

/// The heading bound and the lateral corridor hold on every returned state of a free lane
/// change (constant-velocity predictor, nobody in range), whatever the status; with them off
/// the same problem turns the ego further and overshoots less tightly.
#[test]
fn returned_states_keep_the_heading_bound_and_the_corridor() {
    for heading_max in [0.1, 0.15, 0.2] {
        let s = {
            let mut s = PlannerSettings::default();
            s.bounds.heading_max = heading_max;
            s.bounds.overshoot_max = 0.1;
            s
        };
        let (h, sizes) = scene(12.0, 0.0, &[(200.0, 3.7, 12.0)]);
        let p = problem(&h, &sizes, 12.0);
        let mut planner = Planner::new(s.clone()).unwrap();
        let mut cv = ConstantVelocity::default();
        let mut ego = State::new(0.0, 0.0, 0.0, 12.0);
        let (mut last_delta, mut last_accel) = (0.0, 0.0);
        for step in 0..40 {
            let hist = h.clone();
            let q = PlanningProblem {
                ego: EgoState {
                    x: ego[0],
                    y: ego[1],
                    psi: ego[2],
                    v: ego[3],
                },
                last_delta,
                last_accel,
                history: &hist,
                ..p
            };
            let plan = planner.plan(&q, &mut cv).unwrap();
            assert_ne!(plan.status, PlanStatus::Unsafe, "step {step}");
            for z in &plan.states {
                assert!(z[2].abs() <= heading_max + 1e-9, "{heading_max}: {z:?}");
                assert!(z[1] <= 3.7 + 0.1 + 1e-9 && z[1] >= -0.1 - 1e-9, "{z:?}");
            }
            ego = model(&s).advance(&ego, plan.delta[0], plan.accel[0]);
            (last_delta, last_accel) = (plan.delta[0], plan.accel[0]);
        }
        if heading_max >= 0.1 {
            assert!((ego[1] - 3.7).abs() < 0.3, "{heading_max}: ends at {ego:?}");
        }
    }
}

/// The road-aligning fallback turns the heading back towards 0 as fast as the steering box
/// and rate bounds allow, never past it.
#[test]
fn align_with_road_turns_parallel_to_the_road() {
    let s = PlannerSettings::default();
    let m = model(&s);
    let start = State::new(0.0, 0.0, 0.15, 12.0);
    let bounds = RateBox {
        lo: -s.bounds.delta_max,
        hi: s.bounds.delta_max,
        rate: s.bounds.ddelta_max,
        prev: 0.1,
    };
    let accel = [0.0; 12];
    let d = super::repair::align_with_road(&m, &start, &accel, bounds);
    let mut z = start;
    let mut prev = 0.1;
    for dk in &d {
        // Within the bounds, and never steering further left once the heading is left.
        assert!(
            (dk - prev).abs() <= s.bounds.ddelta_max + 1e-12
                && dk.abs() <= s.bounds.delta_max + 1e-12
        );
        prev = *dk;
        z = m.advance(&z, *dk, 0.0);
        assert!(z[2] > -0.02, "turned past the road's direction: {z:?}");
    }
    assert!(z[2].abs() < 0.01, "still turned: {z:?}");
}

/// Settings at the ends of their ranges that would call the predictor without end (10,000
/// ADMM iterations of 100 descent steps and 30 halvings each, tolerances that are never met,
/// 20 refinement steps) still make at most `PlannerSettings::MAX_CALLS` calls with no
/// `budget.calls` set, and return a checked plan; `budget.calls` beyond the cap is refused.
#[test]
fn every_valid_setting_keeps_the_work_cap() {
    let (h, sizes) = scene(12.0, 0.0, &[(-12.0, 3.7, 12.0), (25.0, 0.0, 11.0)]);
    let p = problem(&h, &sizes, 12.0);
    let mut s = PlannerSettings::default();
    s.admm.max_iter = PlannerSettings::MAX_ITER;
    s.admm.pgd_steps = 100;
    s.admm.pgd_halvings = 30;
    s.admm.eps_primal = 1e-9;
    s.admm.eps_change = 1e-9;
    s.repair.refine_iters = 20;
    let plan = Planner::new(s.clone())
        .unwrap()
        .plan(&p, &mut ConstantVelocity::default())
        .unwrap();
    assert!(
        plan.predictor_calls <= PlannerSettings::MAX_CALLS,
        "{}",
        plan.predictor_calls
    );
    assert!(
        plan.predictor_calls > PlannerSettings::MAX_CALLS / 2,
        "the cap binds here"
    );
    assert_eq!(plan.states, rollout_world(&s, &p, &plan.delta, &plan.accel));
    s.budget.calls = PlannerSettings::MAX_CALLS + 1;
    assert!(s.validate().is_err());
}

/// A predictor-call budget bounds the work of one call deterministically: at most
/// `budget_calls` calls, status `BudgetExhausted` with an admissible plan (or `Unsafe`), the
/// same plan on every run.
#[test]
fn a_call_budget_bounds_the_work_and_returns_an_admissible_plan() {
    let (h, sizes) = scene(12.0, 0.0, &[(-12.0, 3.7, 12.0), (25.0, 0.0, 11.0)]);
    let p = problem(&h, &sizes, 12.0);
    let free = Planner::new(PlannerSettings::default())
        .unwrap()
        .plan(&p, &mut ConstantVelocity::default())
        .unwrap();
    for budget_calls in [3, 5, 8] {
        assert!(free.predictor_calls > budget_calls);
        let s = {
            let mut s = PlannerSettings::default();
            s.budget.calls = budget_calls;
            s
        };
        let run = || {
            Planner::new(s.clone())
                .unwrap()
                .plan(&p, &mut ConstantVelocity::default())
                .unwrap()
        };
        let plan = run();
        assert!(
            plan.predictor_calls <= budget_calls,
            "{}",
            plan.predictor_calls
        );
        assert!(
            matches!(
                plan.status,
                PlanStatus::BudgetExhausted | PlanStatus::Unsafe
            ),
            "{:?}",
            plan.status
        );
        if plan.status == PlanStatus::BudgetExhausted {
            assert!(plan.min_safety.unwrap() > s.safety.safety_min);
        }
        assert_eq!(plan.states, rollout_world(&s, &p, &plan.delta, &plan.accel));
        assert_eq!(
            plan,
            Plan {
                timings: plan.timings.clone(),
                ..run()
            }
        );
    }
}

/// A lane change from y = 0 to y = 3.7 stopped 1.6 m across (the centre still on its own side
/// of the line at 1.85) while a faster car in the target lane comes up alongside: no plan that
/// holds or finishes the change is admissible. With the own lane as the retreat, the fallbacks
/// include steering back to it, and the least-violating plan cancels the change: it ends
/// nearer the own lane and violates less than the best plan without the retreat, which holds
/// the ego across the line.
#[test]
fn without_an_admissible_plan_the_fallback_may_cancel_the_change() {
    let s = PlannerSettings::default();
    let (h, sizes) = scene(12.0, 1.6, &[(-4.0, 3.7, 15.0)]);
    let mut p = problem(&h, &sizes, 12.0);
    p.ego.y = 1.6;
    let hold = Planner::new(s.clone())
        .unwrap()
        .plan(&p, &mut ConstantVelocity::default())
        .unwrap();
    p.y_retreat = Some(0.0);
    let cancel = Planner::new(s.clone())
        .unwrap()
        .plan(&p, &mut ConstantVelocity::default())
        .unwrap();
    assert_eq!(hold.status, PlanStatus::Unsafe, "{hold:?}");
    let (b_hold, b_cancel) = (hold.min_safety.unwrap(), cancel.min_safety.unwrap());
    assert!(b_cancel > b_hold, "min b {b_cancel} vs {b_hold}");
    let (y_hold, y_cancel) = (hold.states[5][1], cancel.states[5][1]);
    assert!(
        y_hold >= 1.55,
        "without a retreat the ego holds across the line: {y_hold}"
    );
    assert!(
        y_cancel < 1.2,
        "with the retreat it steers back: {y_cancel}"
    );
    // The retreat's corridor reaches the own lane (to 0 − overshoot_max).
    assert!(
        cancel
            .states
            .iter()
            .all(|z| z[1] >= -s.bounds.overshoot_max - 1e-9)
    );
}

/// The fallback set steers towards the retreat lane too: for each acceleration profile (the
/// four constants) one sequence that ends nearer the
/// retreat than it starts; none without a retreat lane.
#[test]
fn the_fallback_set_includes_steering_back_to_the_retreat_lane() {
    let s = PlannerSettings::default();
    let (h, sizes) = scene(12.0, 1.6, &[(-40.0, 3.7, 12.0)]);
    let mut p = problem(&h, &sizes, 12.0);
    p.ego.y = 1.6;
    let m = model(&s);
    let lp = LinearisedProblem::new(&s, &m, None, &p);
    assert!(retreat_inputs(&s, &m, &lp).is_empty());
    p.y_retreat = Some(0.0);
    let lp = LinearisedProblem::new(&s, &m, None, &p);
    let back = retreat_inputs(&s, &m, &lp);
    assert_eq!(back.len(), 4);
    for (i, (d, a)) in back.iter().enumerate() {
        let end = rollout_world(&s, &p, d, a)[5][1];
        assert!(
            end < 1.6 - 0.05,
            "sequence {i} towards the retreat ends at {end}"
        );
        // Within the retreat's bounds (its corridor reaches 0 − overshoot_max), not the call's.
        let local = rollout_world(&s, &p, d, a)
            .iter()
            .map(|z| State::new(z[0], z[1] - 1.6, z[2], z[3]))
            .collect::<Vec<_>>();
        let r = lp.retreat.as_ref().unwrap();
        assert!(lp.bound_excess_within(&r.lower, &r.upper, &local) < 1e-9);
        assert!(
            lp.bound_excess(&local) > 0.0,
            "outside the corridor towards the target"
        );
    }
}

/// The binding vehicle of a returned plan is the planner's own minimum: its b equals the
/// minimum the planner's safety evaluation gives the same states under the same prediction,
/// bit for bit, and equals the ellipse value recomputed from the reported semi-axes and
/// positions; a vehicle out of range is never binding.
#[test]
fn binding_vehicle_is_the_planners_minimum_over_the_plan() {
    let s = PlannerSettings::default();
    // A car ahead in the target lane, one behind in the ego's lane, one out of range.
    let (h, sizes) = scene(
        12.0,
        0.0,
        &[(14.0, 3.7, 11.0), (-12.0, 0.0, 12.0), (90.0, 0.0, 12.0)],
    );
    let p = problem(&h, &sizes, 12.0);
    let mut cv = ConstantVelocity::new(6).unwrap();
    let plan = Planner::new(s.clone()).unwrap().plan(&p, &mut cv).unwrap();
    let constraint = SafetyConstraint::new(&p, &s);
    let candidate: Vec<f64> = plan.states.iter().flat_map(|z| [z[0], z[1]]).collect();
    let mut prediction = vec![0.0; 3 * 6 * 2];
    cv.set_scene(&h).unwrap();
    cv.predict(&candidate, &mut prediction).unwrap();
    let b = constraint.binding(&plan.states, &prediction).unwrap();
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 4, s.safety.safety_min);
    let local: Vec<State> = plan
        .states
        .iter()
        .map(|z| State::new(z[0] - lp.origin[0], z[1] - lp.origin[1], z[2], z[3]))
        .collect();
    let min_b = safety.eval(&mut cv, &local).unwrap().min_b.unwrap();
    assert_eq!(b.b.to_bits(), min_b.to_bits());
    assert!(b.agent == 1 || b.agent == 2, "agent {}", b.agent);
    assert_eq!(b.semi_axes.len(), 6);
    let other = &prediction[(b.agent - 1) * 12 + 2 * b.step..][..2];
    let ego = plan.states[b.step];
    let [ax, ay] = b.semi_axes[b.step];
    let value = ((ego[0] - other[0]) / ax).powi(2) + ((ego[1] - other[1]) / ay).powi(2) - 1.0;
    assert!((value - b.b).abs() < 1e-12, "{value} vs {}", b.b);
    // Nothing in range: no binding vehicle.
    let far = SafetyConstraint::new(&p, &{
        let mut s = s;
        s.safety.check_range = 1.0;
        s
    });
    assert_eq!(far.binding(&plan.states, &prediction), None);
}

/// The deadline term of a merge out of a lane that ends: the lateral weight of the call is
/// w_y + w_deadline · φ(d) with d the distance to the end, and the Z-update's gradient of the
/// augmented Lagrangian with it agrees with central finite differences of its value.
#[test]
fn deadline_weight_and_its_gradient_against_finite_differences() {
    use crate::extents::{Lanes, deadline_factor};
    use crate::scenario::LaneExtent;
    let s = PlannerSettings::default();
    let (h, sizes) = scene(20.0, 0.0, &[]);
    let bounds = [-1.85, 1.85, 5.55];
    let extents = [
        LaneExtent {
            begin: -500.0,
            end: 40.0,
            begins: false,
            ends: true,
        },
        LaneExtent {
            begin: -500.0,
            end: 2000.0,
            begins: false,
            ends: false,
        },
    ];
    let p = PlanningProblem {
        lanes: Some(Lanes {
            bounds: &bounds,
            extents: &extents,
        }),
        ..problem(&h, &sizes, 20.0)
    };
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let w =
        s.cost.w_y + s.lane_ends.w_deadline * deadline_factor(40.0, s.lane_ends.deadline_distance);
    assert_eq!(lp.weights[1], w);
    assert!(
        w > 2.0 * s.cost.w_y,
        "the end 40 m ahead at least doubles the weight: {w}"
    );
    // Without the layout, or aiming at the own lane, the weight is w_y.
    let plain = LinearisedProblem::new(&s, &model(&s), None, &problem(&h, &sizes, 20.0));
    assert_eq!(plain.weights[1], s.cost.w_y);
    let own = PlanningProblem { y_target: 0.0, ..p };
    assert_eq!(
        LinearisedProblem::new(&s, &model(&s), None, &own).weights[1],
        s.cost.w_y
    );
    // The gradient at an arbitrary Z with arbitrary inputs and duals.
    let t = s.model.horizon;
    let delta: Vec<f64> = (0..t).map(|k| 0.01 * k as f64 - 0.02).collect();
    let accel: Vec<f64> = (0..t).map(|k| 0.3 - 0.1 * k as f64).collect();
    let duals: Vec<State> = (0..t)
        .map(|k| State::new(0.1 * k as f64, -0.2, 0.05, 0.3))
        .collect();
    let z: Vec<State> = (0..t)
        .map(|k| {
            let k = k as f64 + 1.0;
            State::new(6.0 * k, 0.4 * k, 0.02 * k, 20.0 + 0.1 * k)
        })
        .collect();
    let g = Lagrangian {
        s: &s,
        lp: &lp,
        delta: &delta,
        accel: &accel,
        duals: &duals,
    };
    let mut residual = vec![State::zeros(); t];
    let mut weighted = vec![State::zeros(); t];
    let mut gradient = vec![State::zeros(); t];
    g.value(&z, &mut residual);
    g.gradient(&z, &residual, &mut weighted, &mut gradient);
    let h_fd = 1e-6;
    for k in 0..t {
        for j in 0..4 {
            let (mut zp, mut zm) = (z.clone(), z.clone());
            zp[k][j] += h_fd;
            zm[k][j] -= h_fd;
            let fd = (g.value(&zp, &mut residual) - g.value(&zm, &mut residual)) / (2.0 * h_fd);
            let an = gradient[k][j];
            assert!(
                (fd - an).abs() <= 1e-4 * (1.0 + an.abs()),
                "step {k} component {j}: finite differences {fd}, gradient {an}"
            );
        }
    }
}

/// A wide vehicle passing in the next lane 3.3 m to the side is inside the √2 ellipse (a_y
/// 3.48 m) but its box can never touch the ego's (half widths 0.95 + 1.3 + margin_y 0.3 =
/// 2.55 m): nothing is admissible, and without `fallback_speed_floor` the least total
/// violation brakes the ego at a_min towards a standstill in its own lane; with it the
/// fallback ends at or above the floor. A slower vehicle ahead across the ego's path still
/// makes it brake below the floor.
#[test]
fn a_vehicle_passing_beside_does_not_brake_the_ego_to_a_standstill() {
    let v = 10.0;
    let (h, mut sizes) = scene(v, 0.0, &[(-3.0, 3.3, 14.0)]);
    sizes[1] = [5.0, 2.6];
    let mut p = problem(&h, &sizes, v);
    p.y_target = 0.0;
    let plan_with = |floor: f64, p: &PlanningProblem<'_>| {
        let s = {
            let mut s = PlannerSettings::default();
            s.repair.fallback_speed_floor = floor;
            s
        };
        let mut planner = Planner::new(s).unwrap();
        planner
            .plan(p, &mut ConstantVelocity::new(6).unwrap())
            .unwrap()
    };
    let on = plan_with(0.5, &p);
    let off = plan_with(0.0, &p);
    assert!(
        on.min_safety.is_some_and(|b| b < 0.0) && off.min_safety.is_some_and(|b| b < 0.0),
        "the passing vehicle is inside the ellipse either way: {:?} {:?}",
        on.min_safety,
        off.min_safety
    );
    let v_end = |plan: &Plan| plan.states.last().unwrap()[3];
    assert!(
        v_end(&off) < 0.5 * v,
        "without the floor the ego brakes towards a standstill: {} m/s",
        v_end(&off)
    );
    assert!(
        v_end(&on) >= 0.5 * v,
        "with it the ego keeps at least half its reference speed: {} m/s",
        v_end(&on)
    );
    // A slow vehicle 12 m ahead in the ego's lane on a one-lane road (in its path).
    let (h2, mut sizes2) = scene(v, 0.0, &[(12.0, 0.0, 3.0)]);
    sizes2[1] = [5.0, 2.6];
    let mut p2 = problem(&h2, &sizes2, v);
    p2.y_target = 0.0;
    p2.road = [-1.85, 1.85];
    let ahead = plan_with(0.5, &p2);
    assert!(
        v_end(&ahead) < 0.5 * v,
        "a slower vehicle across the ego's path still brakes it: {} m/s",
        v_end(&ahead)
    );
}

/// The speed floor's path test takes "within the state bounds" as the within-bounds rank key does: up to
/// `bounds_slack`. The ego, changing lanes to the left (its corridor's lower bound is its
/// start y), heads 2 mrad to the right while a wide vehicle passes 3.3 m to its left in the
/// target lane, inside the ellipse but never able to touch it. Holding its speed and
/// realigning with the road dips the ego millimetres below the corridor on the way: within the slack that fallback's path is clear and it beats braking
/// at a_min, which the least total violation prefers. Taken strictly (slack 0, the rule
/// before), its path is not clear and braking wins.
#[test]
fn the_speed_floor_takes_the_bounds_within_their_slack() {
    let v = 10.0;
    let (h, mut sizes) = scene(v, -0.5, &[(-3.0, 2.8, 14.0)]);
    sizes[1] = [5.0, 2.6];
    let mut p = problem(&h, &sizes, v);
    p.ego.y = -0.5;
    p.ego.psi = -0.002;
    let ranks = |slack: f64| {
        let s = {
            let mut s = PlannerSettings::default();
            s.repair.bounds_slack = slack;
            s
        };
        let m = model(&s);
        let lp = LinearisedProblem::new(&s, &m, None, &p);
        let constraint = SafetyConstraint::new(&p, &s);
        let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, s.safety.safety_min);
        let mut cv = ConstantVelocity::default();
        cv.set_scene(&h).unwrap();
        let mut r = plain_repairer(&s, &m, &lp, &mut safety, &mut cv);
        let mut check = |a: f64| {
            let accel = vec![a; 6];
            let delta = super::repair::align_with_road(&m, &lp.start, &accel, lp.delta_box);
            let c = r.check(delta, accel).unwrap();
            let excess = lp.bound_excess(&c.rollout);
            (c, excess)
        };
        let (hold, hold_excess) = check(0.0);
        let (brake, _) = check(s.bounds.a_min);
        (hold, hold_excess, brake, s.repair.bounds_slack)
    };
    let (hold, excess, brake, slack) = ranks(PlannerSettings::default().repair.bounds_slack);
    assert!(
        !hold.predicted_safe && !brake.predicted_safe,
        "both are inside the ellipse"
    );
    assert!(
        excess > 0.0 && excess <= slack,
        "holding leaves the corridor by {excess} (slack {slack})"
    );
    assert!(
        brake.rank.value < hold.rank.value,
        "braking has the smaller total violation: {} vs {}",
        brake.rank.value,
        hold.rank.value
    );
    assert!(hold.rank.clear && !brake.rank.clear);
    assert!(hold.rank.beats(&brake.rank));
    let (hold, _, brake, _) = ranks(0.0);
    assert!(!hold.rank.clear && brake.rank.beats(&hold.rank));
}

/// A 19.8 m truck in its lane's centre at 18.6 m/s, a car 26 m ahead at 10 m/s, and a car
/// beside its tail in the lane to its right (centres 8 m apart along the road, 2.6 m across:
/// 0.3 m between the boxes), changing left. Nothing is admissible.
fn squeezed_truck() -> (History, Vec<[f64; 2]>) {
    let (h, mut sizes) = scene(18.6, 0.0, &[(26.0, 0.0, 10.0), (-8.0, -2.6, 18.6)]);
    sizes[0] = [19.8, 2.59];
    sizes[1] = [4.0, 1.8];
    sizes[2] = [5.3, 2.0];
    (h, sizes)
}

/// The (step, vehicle) pairs at which the plan's box overlaps a vehicle's box at its
/// constant-velocity position (the separating-axis test, [`crate::safety::OrientedBox`]).
fn predicted_contacts(plan: &Plan, h: &History, sizes: &[[f64; 2]]) -> usize {
    use crate::safety::OrientedBox;
    let mut contacts = 0;
    for (k, z) in plan.states.iter().enumerate() {
        let steps = (k + 1) as f64;
        let ego = OrientedBox {
            x: z[0],
            y: z[1],
            heading: z[2],
            length: sizes[0][0],
            width: sizes[0][1],
        };
        for (i, size) in sizes.iter().enumerate().skip(1) {
            let (p, q) = (h.at(i, T_OBS - 2), h.at(i, T_OBS - 1));
            let other = OrientedBox {
                x: q[0] + (q[0] - p[0]) * steps,
                y: q[1] + (q[1] - p[1]) * steps,
                heading: 0.0,
                length: size[0],
                width: size[1],
            };
            if ego.overlaps(&other) {
                contacts += 1;
            }
        }
    }
    contacts
}

/// Nothing is admissible for the squeezed truck, and the least total violation would steer it
/// towards the target lane, away from the slow car ahead, swinging its tail into the car
/// beside it; ranked by predicted contact before the violation ([`RankKey::Contact`]), with
/// one ellipse for the whole truck or with 6 m slices, the fallback touches nobody (the
/// separating-axis test at the constant-velocity positions).
#[test]
fn contact_keeps_a_squeezed_truck_s_tail_off_the_car_beside_it() {
    let (h, sizes) = squeezed_truck();
    let mut p = problem(&h, &sizes, 18.6);
    p.y_target = 3.44;
    p.road = [-5.16, 5.16];
    p.y_retreat = Some(0.0);
    for segment in [0.0, 6.0] {
        let mut s = PlannerSettings::default();
        s.safety.ego_segment_length = segment;
        let plan = Planner::new(s)
            .unwrap()
            .plan(&p, &mut ConstantVelocity::new(6).unwrap())
            .unwrap();
        assert!(
            plan.min_safety.is_some_and(|b| b < 0.0),
            "nothing admissible: {:?}",
            plan.min_safety
        );
        assert_eq!(
            predicted_contacts(&plan, &h, &sizes),
            0,
            "segment {segment}: the fallback touches nobody: {:?}",
            plan.states
        );
    }
}

/// The road-edge excess the road-edge rank key ranks by, against the corners of the ego's box
/// computed by rotation (independent of the half-extent formula): Σ over the states of how
/// far the lowest corner lies below the right edge and the highest above the left one, the
/// edges widened by the start overhang plus its slack.
#[test]
fn edge_excess_is_how_far_the_box_s_corners_leave_the_road() {
    let (h, mut sizes) = scene(12.0, -1.19, &[]);
    sizes[0] = [6.1, 2.56];
    let mut p = problem(&h, &sizes, 12.0);
    p.ego.y = -1.19;
    let s = PlannerSettings::default();
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    // The truck starts 0.62 m over the right edge (−1.85): that edge moves out by 0.67 m.
    let right = -1.85 - 0.62 - super::linearised::START_OVERHANG_SLACK;
    let corners = |z: &State| {
        let (sn, cs) = z[2].sin_cos();
        [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
            .map(|(u, v)| z[1] + 0.5 * (u * 6.1 * sn + v * 2.56 * cs))
    };
    let states: Vec<State> = [(-1.19, 0.0), (-1.15, 0.08), (-1.1, -0.12), (4.5, 0.2)]
        .iter()
        .map(|&(y, psi)| State::new(0.0, y - p.ego.y, psi, 12.0))
        .collect();
    let truth: f64 = states
        .iter()
        .map(|z| {
            let c = corners(&State::new(0.0, z[1] + p.ego.y, z[2], 12.0));
            let low = c.iter().copied().fold(f64::INFINITY, f64::min);
            let high = c.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (right - low).max(0.0) + (high - 5.55).max(0.0)
        })
        .sum();
    assert!(truth > 0.1, "the turned states leave the road: {truth}");
    assert!(
        (lp.edge_excess(&states) - truth).abs() < 1e-9,
        "{} vs {truth}",
        lp.edge_excess(&states)
    );
}

/// The rank of an admissible candidate of cost `value`.
fn admissible_rank(value: f64) -> super::repair::Rank {
    super::repair::Rank::admissible(false, value)
}

/// The fixed key order of the ranking ([`RANK_ORDER`]), key by key: each decides only on a tie
/// of those before it, an admissible candidate beats every inadmissible one, and `decide`
/// names the key that separated two candidates.
#[test]
fn the_ranking_compares_its_keys_in_order() {
    use super::repair::{Rank, Violations};
    let s = PlannerSettings::default();
    let v = |bound_excess: f64, contact: f64, edge: f64, value: f64| Violations {
        unbegun: false,
        clear: false,
        value,
        bound_excess,
        contact,
        edge,
        ahead: 0.0,
        leaves_lane: false,
    };
    let rank = |x: Violations| Rank::inadmissible(&s, &x);
    // Within the bounds (up to the slack of 0.05) beats a swerve past them that touches less.
    let swerve = v(0.4, 0.1, 0.0, 4.5);
    let within = v(0.0, 0.8, 0.0, 6.0);
    assert_eq!(
        rank(within).decide(&rank(swerve)),
        (RankKey::WithinBounds, true)
    );
    assert_eq!(
        rank(swerve).decide(&rank(within)),
        (RankKey::WithinBounds, false)
    );
    let dip = v(0.015, 0.0, 0.0, 1.4);
    let turn = v(0.0, 0.3, 0.0, 2.7);
    assert_eq!(rank(dip).decide(&rank(turn)), (RankKey::Contact, true));
    assert!(rank(turn).beats(&rank(v(0.06, 0.0, 0.0, 1.4))));
    // Then contact, then the road edge, then the value.
    assert_eq!(
        rank(v(0.0, 0.1, 0.5, 9.0)).decide(&rank(v(0.0, 0.2, 0.0, 1.0))),
        (RankKey::Contact, true)
    );
    assert_eq!(
        rank(v(0.0, 0.1, 0.0, 9.0)).decide(&rank(v(0.0, 0.1, 0.2, 1.0))),
        (RankKey::RoadEdge, true)
    );
    assert_eq!(
        rank(v(0.0, 0.1, 0.2, 1.0)).decide(&rank(v(0.0, 0.1, 0.2, 9.0))),
        (RankKey::Value, true)
    );
    // Differences below the rounding tolerance tie.
    assert_eq!(
        rank(v(0.0, 0.1 + 1e-12, 0.0, 1.0)).decide(&rank(v(0.0, 0.1, 0.0, 2.0))),
        (RankKey::Value, true)
    );
    // A lane entered before it begins loses after contact and the edge, before the floor.
    let r = |value: f64, edge: f64, contact: f64, clear: bool| Rank {
        clear,
        ..rank(v(0.0, contact, edge, value))
    };
    let unbegun = |rank: Rank| Rank {
        unbegun: true,
        ..rank
    };
    assert_eq!(
        r(5.0, 0.0, 0.0, false).decide(&unbegun(r(1.0, 0.0, 0.0, true))),
        (RankKey::LaneBegun, true)
    );
    assert_eq!(
        unbegun(r(5.0, 0.0, 0.0, false)).decide(&r(1.0, 0.3, 0.0, true)),
        (RankKey::RoadEdge, true)
    );
    // The clear path beats a smaller value; on a tie of value the incumbent stays.
    assert_eq!(
        r(5.0, 0.0, 0.0, true).decide(&r(1.0, 0.0, 0.0, false)),
        (RankKey::ClearPath, true)
    );
    assert_eq!(
        r(1.0, 0.0, 0.0, false).decide(&r(1.0, 0.0, 0.0, false)),
        (RankKey::Value, false)
    );
    // Admissible first, then its cost.
    assert_eq!(
        admissible_rank(100.0).decide(&r(0.0, 0.0, 0.0, true)),
        (RankKey::Admissible, true)
    );
    assert_eq!(
        admissible_rank(1.0).decide(&admissible_rank(2.0)),
        (RankKey::Value, true)
    );
    assert_eq!(RANK_ORDER[0], RankKey::Admissible);
    assert_eq!(RANK_ORDER[RANK_ORDER.len() - 1], RankKey::Value);
}

/// A car at 12 m/s, heading 0.1 rad towards the lane on its left, 7 m behind a car at 6 m/s
/// in its own lane, with a previous plan that steers left at the steering bound (0.15 rad):
/// nothing is admissible. The least predicted contact is that previous plan, shifted: a swerve
/// past the heading bound (0.2 rad), out of the lateral corridor and off the road. The
/// fallback ranks the state bounds first and governs the heading, so it stays within the
/// heading bound, the corridor and the road (checked from the rotated corners of its box).
#[test]
fn the_fallback_of_a_squeezed_car_stays_within_the_heading_bound() {
    let (h, sizes) = scene(12.0, 0.0, &[(7.0, 0.0, 6.0)]);
    let mut p = problem(&h, &sizes, 12.0);
    p.ego.psi = 0.1;
    let mut s = PlannerSettings::default();
    s.safety.ego_segment_length = 6.0;
    let mut planner = Planner::new(s).unwrap();
    planner.warm = Some(super::linearised::WarmStart {
        delta: vec![0.15; 6],
        accel: vec![0.0; 6],
    });
    let plan = planner
        .plan(&p, &mut ConstantVelocity::new(6).unwrap())
        .unwrap();
    let heading_max = PlannerSettings::default().bounds.heading_max;
    let max_heading = plan.states.iter().map(|z| z[2].abs()).fold(0.0, f64::max);
    // The box's lateral extent from its corners, rotated (independent of the planner's
    // half-extent formula).
    let on_road = plan.states.iter().all(|z| {
        let (sn, cs) = z[2].sin_cos();
        [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
            .iter()
            .map(|(u, v)| z[1] + 0.5 * (u * sizes[0][0] * sn + v * sizes[0][1] * cs))
            .all(|y| (p.road[0]..=p.road[1]).contains(&y))
    });
    assert!(
        plan.min_safety.is_some_and(|b| b < 0.0),
        "nothing admissible: {:?}",
        plan.min_safety
    );
    assert!(
        max_heading <= heading_max + 1e-12 && on_road,
        "within the heading bound and on the road: {:?}",
        plan.states
    );
    let corridor = -PlannerSettings::default().bounds.overshoot_max
        ..=p.y_target + PlannerSettings::default().bounds.overshoot_max;
    assert!(
        plan.states.iter().all(|z| corridor.contains(&z[1])),
        "and within the lateral corridor: {:?}",
        plan.states
    );
}

/// The heading governor: an ADMM answer whose nonlinear roll-out passed the heading bound only
/// by the linearisation's error is admissible once governed, and the plan is the optimiser's
/// own (not the refinement's), recorded as the ADMM inputs governed; its states are the
/// roll-out of its inputs and keep the bound.
#[test]
fn the_heading_governor_adopts_the_optimisers_plan() {
    let (h, sizes) = scene(10.5, 0.0, &[(8.0, 3.7, 10.5)]);
    let p = problem(&h, &sizes, 10.5);
    let q = PlanningProblem {
        ego: EgoState {
            x: 0.0,
            y: 0.0,
            psi: 0.12,
            v: 10.5,
        },
        ..p
    };
    let s = PlannerSettings::default();
    let with = Planner::new(s.clone())
        .unwrap()
        .plan(&q, &mut ConstantVelocity::default())
        .unwrap();
    assert!(
        matches!(
            with.status,
            PlanStatus::Converged | PlanStatus::MaxIterations
        ),
        "{with:?}"
    );
    assert_eq!(with.decided_by, DecidedBy::AdmmGoverned);
    let mut rollout = vec![State::zeros(); with.states.len()];
    let start = State::new(0.0, 0.0, 0.12, 10.5);
    model(&s).rollout(&start, &with.delta, &with.accel, &mut rollout);
    for (z, r) in with.states.iter().zip(&rollout) {
        assert!((0..4).all(|j| (z[j] - r[j]).abs() < 1e-9), "{z:?} vs {r:?}");
        assert!(z[2].abs() <= s.bounds.heading_max + 1e-12, "{z:?}");
    }
}

/// The acceleration profiles of the fallback: the four constants, each the fastest the jerk
/// bound allows towards its target (from the last applied acceleration 0): written out by
/// hand for T = 6. The simple and retreat sequences take theirs from them.
#[test]
fn the_fallback_profiles_reach_their_constants_within_the_jerk_bound() {
    let s = PlannerSettings::default();
    let (h, sizes) = scene(12.0, 1.6, &[(-40.0, 3.7, 12.0)]);
    let mut p = problem(&h, &sizes, 12.0);
    p.ego.y = 1.6;
    p.y_retreat = Some(0.0);
    assert_eq!(
        (s.bounds.a_min, s.bounds.a_max, s.bounds.da_max),
        (-5.0, 3.0, 1.5)
    );
    let want: Vec<Vec<f64>> = vec![
        vec![0.0; 6],
        vec![-1.5, -2.5, -2.5, -2.5, -2.5, -2.5],
        vec![-1.5, -3.0, -4.5, -5.0, -5.0, -5.0],
        vec![1.5; 6],
    ];
    let accels =
        |inputs: Vec<Inputs>| -> Vec<Vec<f64>> { inputs.into_iter().map(|(_, a)| a).collect() };
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    assert_eq!(fallback_accels(&s, &lp), want);
    // Twice each (aligned with the road, towards the goal), in their order; once each
    // towards the retreat.
    let twice: Vec<Vec<f64>> = want.iter().flat_map(|a| [a.clone(), a.clone()]).collect();
    assert_eq!(accels(simple_inputs(&s, &model(&s), &lp)), twice);
    assert_eq!(accels(retreat_inputs(&s, &model(&s), &lp)), want);
}

/// The fallback's input lattice keeps the box and rate bounds from the inputs applied last,
/// holds no sequence twice, and holds the extreme ramps (full acceleration, full braking,
/// full steering either way) and holding the inputs.
#[test]
fn the_lattice_keeps_the_input_bounds_and_holds_the_extreme_ramps() {
    let (h, sizes) = car_behind_in_target_lane();
    let s = repairs_only();
    let m = model(&s);
    let p = problem(&h, &sizes, 12.0);
    let lp = LinearisedProblem::new(&s, &m, None, &p);
    let lattice = lattice_inputs(&lp);
    assert!(
        lattice.len() > 300 && lattice.len() <= 729,
        "{}",
        lattice.len()
    );
    let (db, ab) = (lp.delta_box, lp.accel_box);
    for (d, a) in &lattice {
        assert_eq!((d.len(), a.len()), (6, 6));
        let (mut pd, mut pa) = (db.prev, ab.prev);
        for (&dk, &ak) in d.iter().zip(a) {
            assert!(dk >= db.lo && dk <= db.hi && ak >= ab.lo && ak <= ab.hi);
            assert!((dk - pd).abs() <= db.rate + 1e-12 && (ak - pa).abs() <= ab.rate + 1e-12);
            (pd, pa) = (dk, ak);
        }
    }
    for (i, x) in lattice.iter().enumerate() {
        assert!(!lattice[i + 1..].contains(x), "sequence {i} twice");
    }
    // Written out from the bounds (δ: ±0.15 rad, 0.05 per step; a: −5..3 m/s², 1.5 per step),
    // from the inputs (0, 0).
    assert_eq!((db.prev, ab.prev), (0.0, 0.0));
    let hold = (vec![0.0; 6], vec![0.0; 6]);
    let full = (vec![0.0; 6], vec![1.5, 3.0, 3.0, 3.0, 3.0, 3.0]);
    let brake = (vec![0.0; 6], vec![-1.5, -3.0, -4.5, -5.0, -5.0, -5.0]);
    let left = (vec![0.05, 0.1, 0.15, 0.15, 0.15, 0.15], vec![0.0; 6]);
    let right = (vec![-0.05, -0.1, -0.15, -0.15, -0.15, -0.15], vec![0.0; 6]);
    assert_eq!(lattice[0], hold);
    for want in [full, brake, left, right] {
        assert!(
            lattice.iter().any(|x| x.0 == want.0 && x.1 == want.1),
            "{want:?}"
        );
    }
}

/// On horizons of 10 and 60 steps (the predictors' largest) the lattice stays the 6-step one,
/// each sequence holding its last inputs after step 6: the same sequences, in the same order,
/// as on the shipped horizon. It used to grow as 9^⌈T/2⌉ (59,049 sequences at 10 steps, 9^30
/// at 60, which the settings fuzzer found as a hang).
#[test]
fn a_long_horizon_lattice_branches_over_the_first_six_steps_only() {
    let (h, sizes) = car_behind_in_target_lane();
    let short = repairs_only();
    let m = model(&short);
    let p = problem(&h, &sizes, 12.0);
    let six = lattice_inputs(&LinearisedProblem::new(&short, &m, None, &p));
    for horizon in [10, 60] {
        let long = {
            let mut s = repairs_only();
            s.model.horizon = horizon;
            s
        };
        long.validate().unwrap();
        let lattice = lattice_inputs(&LinearisedProblem::new(&long, &m, None, &p));
        assert_eq!(lattice.len(), six.len(), "{horizon} steps");
        for ((d, a), (d6, a6)) in lattice.iter().zip(&six) {
            assert_eq!((d.len(), a.len()), (horizon, horizon));
            assert_eq!((&d[..6], &a[..6]), (d6.as_slice(), a6.as_slice()));
            assert!(d[6..].iter().all(|&x| x == d6[5]) && a[6..].iter().all(|&x| x == a6[5]));
        }
    }
}

/// With nothing else admissible the lattice finds the escape: a vehicle closing from behind
/// catches every candidate that ends short of a line only the full-acceleration ramp reaches.
/// Without the lattice (its speed floor above the ego's speed) no fallback is safe; with it
/// the fallback is safe and ends beyond the line, within the input bounds. Independent check:
/// every lattice sequence's safety is whether its own roll-out ends beyond the line.
#[test]
fn the_fallback_lattice_finds_the_escape_the_simple_fallbacks_miss() {
    let (h, sizes) = car_behind_in_target_lane();
    for on in [false, true] {
        let s = {
            let mut s = repairs_only();
            if !on {
                s.repair.lattice_min_speed = 100.0;
            }
            s
        };
        let m = model(&s);
        let mut p = problem(&h, &sizes, 12.0);
        p.y_target = 0.0;
        let lp = LinearisedProblem::new(&s, &m, None, &p);
        let zero_steer = vec![0.0; 6];
        let end = |a: &[f64]| rollout_world(&s, &p, &zero_steer, a)[5];
        let full = vec![1.5, 3.0, 3.0, 3.0, 3.0, 3.0];
        let (end_half, end_full) = (end(&[1.5; 6]), end(&full));
        let limit = 0.5 * (end_half[0] + end_full[0]);
        let constraint = SafetyConstraint::new(&p, &s);
        let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, s.safety.safety_min);
        let mut gate = Gate::behind(limit);
        gate.set_scene(&h).unwrap();
        let mut r = plain_repairer(&s, &m, &lp, &mut safety, &mut gate);
        if on {
            for (d, a) in lattice_inputs(&lp).into_iter().take(60) {
                let c = r.check(d, a).unwrap();
                assert_eq!(c.rank.safe, c.rollout[5][0] >= limit, "{:?}", c.accel);
            }
        }
        let best = r.best_fallback().unwrap();
        assert_eq!(best.rank.safe, on, "{:?}", best.accel);
        if on {
            assert!(best.rollout[5][0] >= limit);
            let (mut pd, mut pa) = (lp.delta_box.prev, lp.accel_box.prev);
            for (&dk, &ak) in best.delta.iter().zip(&best.accel) {
                assert!(
                    dk.abs() <= s.bounds.delta_max && ak >= s.bounds.a_min && ak <= s.bounds.a_max
                );
                assert!((dk - pd).abs() <= s.bounds.ddelta_max + 1e-12);
                assert!((ak - pa).abs() <= s.bounds.da_max + 1e-12);
                (pd, pa) = (dk, ak);
            }
        }
    }
}

/// The line (m along the road) halfway between where the ramps to a_max/2 and to a_max end,
/// driving straight from acceleration 0: of the lattice's sequences only those near the
/// full-acceleration ramp get past it.
fn full_ramp_line(s: &PlannerSettings, p: &PlanningProblem<'_>) -> f64 {
    let zero_steer = vec![0.0; 6];
    let end = |a: &[f64]| rollout_world(s, p, &zero_steer, a)[5][0];
    0.5 * (end(&[1.5; 6]) + end(&[1.5, 3.0, 3.0, 3.0, 3.0, 3.0]))
}

/// Whether the world-frame roll-out `z` (`[T]` states, 0.3 s apart) overlaps, at some step, a
/// 4.5 m × 1.9 m car that starts at (`x`, `y`) and drives along the road at `v` m/s: the boxes'
/// separating-axis test, independent of the planner's ellipses.
fn hits_car_at_constant_velocity(z: &[[f64; 4]], (x, y, v): (f64, f64, f64)) -> bool {
    hits_drifting_car(z, (x, y, v, 0.0))
}

/// Whether the world-frame roll-out `z` (`[T]` states, 0.3 s apart) overlaps, at some step, a
/// 4.5 m × 1.9 m car that starts at (`x`, `y`) and moves at (`vx`, `vy`) m/s, heading along
/// its motion: the boxes' separating-axis test, independent of the planner's ellipses and of
/// its constant-velocity predictor.
pub(super) fn hits_drifting_car(z: &[[f64; 4]], (x, y, vx, vy): (f64, f64, f64, f64)) -> bool {
    let car_box = |x: f64, y: f64, heading: f64| crate::OrientedBox {
        x,
        y,
        heading,
        length: 4.5,
        width: 1.9,
    };
    let heading = vy.atan2(vx);
    z.iter().enumerate().any(|(k, zk)| {
        let t = 0.3 * (k + 1) as f64;
        car_box(zk[0], zk[1], zk[2]).overlaps(&car_box(x + vx * t, y + vy * t, heading))
    })
}

/// Runs `f` on a repairer under `s` of a lane-keeping call at 12 m/s in the scene `h`: the
/// planning predictor is [`YieldUnless`] at the [`full_ramp_line`], the non-reactive one
/// constant velocity. `f` gets the repairer, the problem, its linearisation and the line.
fn with_yield_repairer<R>(
    s: &PlannerSettings,
    h: &History,
    sizes: &[[f64; 2]],
    f: impl FnOnce(&mut Repairer<'_, '_>, &PlanningProblem<'_>, &LinearisedProblem, f64) -> R,
) -> R {
    let m = model(s);
    let mut p = problem(h, sizes, 12.0);
    p.y_target = 0.0;
    let lp = LinearisedProblem::new(s, &m, None, &p);
    let limit = full_ramp_line(s, &p);
    let constraint = SafetyConstraint::new(&p, s);
    let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, s.safety.safety_min);
    let mut planning = YieldUnless { limit };
    let mut cv = ConstantVelocity::new(6).unwrap();
    cv.set_scene(h).unwrap();
    let mut r = Repairer {
        nonreactive: Some(&mut cv),
        ..plain_repairer(s, &m, &lp, &mut safety, &mut planning)
    };
    f(&mut r, &p, &lp, limit)
}

/// A planning predictor by which agent 1 yields (it stays 60 m behind the candidate at every
/// step) unless the candidate ends short of `limit` (m along the road): then it sits on the
/// candidate's positions.
struct YieldUnless {
    limit: f64,
}

impl Predictor for YieldUnless {
    fn name(&self) -> &'static str {
        "yield-unless"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, _history: &History) -> nudge_predictor::Result<()> {
        Ok(())
    }
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        let behind = if candidates[10] < self.limit {
            0.0
        } else {
            60.0
        };
        for k in 0..6 {
            out[2 * k] = candidates[2 * k] - behind;
            out[2 * k + 1] = candidates[2 * k + 1];
        }
        Ok(())
    }
}

/// The lattice's clearance without reaction: a car closes from behind in the ego's lane at 30 m/s. By the
/// planning predictor it yields to any candidate that ends beyond a line only the
/// full-acceleration ramp passes, and hits every other; at constant velocity it drives
/// through the ego whatever the ego does. Without the check (no constant-velocity predictor)
/// the lattice's escape is taken as admissible, and its roll-out overlaps the car at constant
/// velocity (checked with the boxes, independently of the planner). With it every lattice
/// sequence the planning predictor admits is such a one (checked the same way), so none
/// replaces the fallback and the plan is not admissible.
#[test]
fn a_lattice_escape_that_counts_on_a_yield_is_refused_when_it_must_be_clear_without_reaction() {
    let car = (-12.0, 0.0, 30.0);
    let (h, sizes) = scene(12.0, 0.0, &[car]);
    let hits = |s: &PlannerSettings, p: &PlanningProblem<'_>, d: &[f64], a: &[f64]| {
        hits_car_at_constant_velocity(&rollout_world(s, p, d, a), car)
    };
    for clear in [false, true] {
        let s = repairs_only();
        with_yield_repairer(&s, &h, &sizes, |r, p, lp, _| {
            if !clear {
                r.nonreactive = None;
            }
            let admitted: Vec<(Vec<f64>, Vec<f64>)> = lattice_inputs(lp)
                .into_iter()
                .filter_map(|(d, a)| {
                    let c = r.check(d, a).unwrap();
                    c.rank.safe.then_some((c.delta, c.accel))
                })
                .collect();
            assert!(!admitted.is_empty());
            assert!(admitted.iter().all(|(d, a)| hits(&s, p, d, a)));
            let best = r.best_fallback().unwrap();
            assert_eq!(best.rank.safe, !clear, "{:?}", best.accel);
            if !clear {
                assert!(hits(&s, p, &best.delta, &best.accel));
            }
        });
    }
}

/// `lattice_min_speed`: the lattice escape of
/// [`the_fallback_lattice_finds_the_escape_the_simple_fallbacks_miss`] is searched for at the
/// ego's speed (12 m/s) with the floor at or below it, and not with the floor above it.
#[test]
fn the_lattice_is_searched_only_from_its_minimum_speed() {
    let (h, sizes) = car_behind_in_target_lane();
    for (floor, searched) in [(0.0, true), (12.0, true), (12.5, false)] {
        let s = {
            let mut s = repairs_only();
            s.repair.lattice_min_speed = floor;
            s
        };
        s.validate().unwrap();
        let m = model(&s);
        let mut p = problem(&h, &sizes, 12.0);
        p.y_target = 0.0;
        let lp = LinearisedProblem::new(&s, &m, None, &p);
        let limit = full_ramp_line(&s, &p);
        let constraint = SafetyConstraint::new(&p, &s);
        let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, s.safety.safety_min);
        let mut gate = Gate::behind(limit);
        gate.set_scene(&h).unwrap();
        let mut r = plain_repairer(&s, &m, &lp, &mut safety, &mut gate);
        let best = r.best_fallback().unwrap();
        assert_eq!(best.rank.safe, searched, "floor {floor}: {:?}", best.accel);
        assert_eq!(best.rollout[5][0] >= limit, searched);
    }
}

/// The reported violation ([`Plan::violation`]): zero on a free lane change; on a single-lane
/// road with a car standing 9 m ahead of an ego at 15 m/s (unavoidable), the safety part is
/// safety_min − min b of the returned states, b recomputed here from the constraint's public
/// `b` against the standing car at every step.
#[test]
fn the_plan_reports_its_largest_violation_per_constraint_type() {
    let s = PlannerSettings::default();
    let (h, sizes) = scene(12.0, 0.0, &[]);
    let p = problem(&h, &sizes, 12.0);
    let mut cv = ConstantVelocity::new(6).unwrap();
    let free = Planner::new(s.clone()).unwrap().plan(&p, &mut cv).unwrap();
    // Zero up to the admissibility tolerance (the heading governor lands on its bound within
    // rounding).
    let f = free.violation;
    for part in [f.safety, f.heading, f.corridor, f.road_edge, f.lane] {
        assert!((0.0..=1e-9).contains(&part), "{f:?} {:?}", free.status);
    }

    let (h, sizes) = scene(15.0, 0.0, &[(9.0, 0.0, 0.0)]);
    let mut p = problem(&h, &sizes, 15.0);
    p.road = [-1.85, 1.85];
    p.y_target = 0.0;
    let mut cv = ConstantVelocity::new(6).unwrap();
    let plan = Planner::new(s.clone()).unwrap().plan(&p, &mut cv).unwrap();
    let constraint = SafetyConstraint::new(&p, &s);
    let v = constraint.vehicles()[0];
    let car = [9.0, 0.0];
    let min_b = plan
        .states
        .iter()
        .enumerate()
        .map(|(k, z)| constraint.b(&v, *z, car, car, k + 1 == plan.states.len()).0)
        .fold(f64::INFINITY, f64::min);
    assert!(
        min_b < s.safety.safety_min,
        "the conflict was avoidable: {min_b}"
    );
    assert!(
        (plan.violation.safety - (s.safety.safety_min - min_b)).abs() < 1e-9,
        "{} vs {}",
        plan.violation.safety,
        s.safety.safety_min - min_b
    );
    assert_eq!(plan.status, PlanStatus::Unsafe);
    for part in [
        plan.violation.heading,
        plan.violation.corridor,
        plan.violation.road_edge,
        plan.violation.lane,
    ] {
        assert!(part.is_finite() && part >= 0.0);
    }
}
