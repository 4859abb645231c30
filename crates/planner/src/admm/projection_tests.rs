//! Tests of the Z-update's projection onto the linearised safe set (`z_cuts`), the safe start
//! (`safe_start`) and the re-tightening of the Z-update's threshold (`z_retighten`), each
//! phase alone against an independent truth: the cut row against finite differences of b, the
//! projected step with cuts and bounds against a Clarabel solve of the same QP, the safe start
//! against a brute-force check of every candidate, the re-tightening rule by hand; and each
//! mechanism against the same run with it switched off.
#![allow(clippy::unwrap_used)]

use nudge_predictor::{ConstantVelocity, History, Predictor};

use clarabel::solver::{DefaultSolver, IPSolver, NonnegativeConeT};

use super::constraint::{SafetyEval, SafetyRow};
use super::inputs::Input;
use super::linearised::LinearisedProblem;
use super::projection::{bound_rows, cut_row};
use super::repair::simple_inputs;
use super::retighten;
use super::safe_step::{StepRow, constrained_step};
use super::start::{StartCandidate, start};
use super::workspace::{Iterates, Workspace};
use super::z_update::Lagrangian;
use super::*;
use crate::qp::{clarabel_settings, triplets_csc, upper_csc};

/// Ego at (0, 0) with speed v; others `(x, y, speed)`; all driving along +x.
fn scene(v: f64, others: &[(f64, f64, f64)]) -> (History, Vec<[f64; 2]>) {
    super::tests::scene(v, 0.0, others)
}

fn model(s: &PlannerSettings) -> Bicycle {
    Bicycle {
        l_f: s.l_f,
        l_r: s.l_r,
        dt: s.dt,
    }
}

/// Every other agent at constant velocity from its last two observed positions, except
/// agent 1, which also shifts sideways by `follow` times the candidate's lateral position at
/// each step (a reacting vehicle: it shadows the ego's lateral moves), so a prediction held
/// fixed under-estimates how far the ego has to go.
struct Shadow {
    follow: f64,
    last: Vec<[[f64; 2]; 2]>,
}

impl Predictor for Shadow {
    fn name(&self) -> &'static str {
        "shadow"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.last = super::tests::last_two(history);
        Ok(())
    }
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        for (i, [prev, now]) in self.last.iter().enumerate().skip(1) {
            for k in 0..6 {
                let o = ((i - 1) * 6 + k) * 2;
                let steps = (k + 1) as f64;
                out[o] = now[0] + steps * (now[0] - prev[0]);
                out[o + 1] = now[1] + steps * (now[1] - prev[1]);
                if i == 1 {
                    out[o + 1] += self.follow * candidates[2 * k + 1];
                }
            }
        }
        Ok(())
    }
}

/// H = 2W + ρCᵀC of the call, dense `[4T, 4T]` row-major (the matrix whose inverse the
/// Z-update uses).
fn hessian(s: &PlannerSettings, lp: &LinearisedProblem) -> Vec<f64> {
    let h = super::workspace::hessian(s, lp);
    let n = h.nrows();
    (0..n * n).map(|k| h[(k / n, k % n)]).collect()
}

/// min ½dᵀHd + g·d subject to a·d ≥ need for every row, solved by Clarabel (`h` `[n, n]`).
fn clarabel_rows(h: &[f64], g: &[f64], rows: &[StepRow]) -> Vec<f64> {
    let n = g.len();
    let mut a = Vec::new();
    let mut b = Vec::new();
    for (j, r) in rows.iter().enumerate() {
        for &(i, c) in &r.terms {
            if c != 0.0 {
                a.push((j, i, -c));
            }
        }
        b.push(-r.need);
    }
    let (pm, am) = (upper_csc(h, n), triplets_csc(rows.len(), n, a));
    let cones = [NonnegativeConeT(rows.len())];
    let mut solver = DefaultSolver::new(&pm, g, &am, &b, &cones, clarabel_settings(true)).unwrap();
    solver.solve();
    solver.solution.x.clone()
}

/// The set-up of one call in `scene` under `s`: the linearised problem and the constraint.
fn setup(
    s: &PlannerSettings,
    h: &History,
    sizes: &[[f64; 2]],
) -> (LinearisedProblem, SafetyConstraint) {
    let p = super::tests::problem(h, sizes, 12.0);
    let lp = LinearisedProblem::new(s, &model(s), None, &p);
    (lp, SafetyConstraint::new(&p, s))
}

/// The row of `step` among `rows` (one checked vehicle: one row per step at most).
fn row_at(rows: &[SafetyRow], step: usize) -> SafetyRow {
    *rows.iter().find(|r| r.step == step).unwrap()
}

/// A cut is the linearisation of b at the trial point, expressed around Z: at the trial point
/// it is b there, and at points near it it agrees with b (a constant-velocity prediction, so
/// b is a function of the ego's position alone) to second order: finite differences of b.
#[test]
fn cut_row_is_the_linearisation_of_b_at_the_trial_point() {
    let s = PlannerSettings::default();
    let (h, sizes) = scene(12.0, &[(9.0, 1.2, 8.0)]);
    let (lp, constraint) = setup(&s, &h, &sizes);
    let mut cv = ConstantVelocity::default();
    cv.set_scene(&h).unwrap();
    let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, 0.0);
    let z = Iterates::start(&lp).z;
    let trial: Vec<State> = z
        .iter()
        .enumerate()
        .map(|(k, zk)| zk + State::new(0.3 - 0.1 * k as f64, 0.2 * k as f64, 0.0, 0.0))
        .collect();
    safety.eval(&mut cv, &trial).unwrap();
    let at_trial = safety.rows.clone();
    assert_eq!(at_trial.len(), 6, "every step is near the car");
    for r in &at_trial {
        let k = r.step;
        let cut = cut_row(r, &trial, &z);
        // At the trial point the cut is b there.
        let moved =
            |p: &State| cut.gradient[0] * (p[0] - z[k][0]) + cut.gradient[1] * (p[1] - z[k][1]);
        assert!((cut.b + moved(&trial[k]) - r.b).abs() < 1e-12);
        // Near it, b to second order.
        for (i, e) in [[1.0, 0.0], [0.0, 1.0], [0.6, -0.8]].iter().enumerate() {
            let eps = 1e-4;
            let mut near = trial.clone();
            near[k][0] += eps * e[0];
            near[k][1] += eps * e[1];
            safety.eval(&mut cv, &near).unwrap();
            let b = row_at(&safety.rows, k).b;
            let linear = cut.b + moved(&near[k]);
            assert!(
                (b - linear).abs() < 1e-6,
                "step {k} direction {i}: b {b} vs the cut {linear}"
            );
        }
    }
}

/// The projection's QP with the safety rows of Z, the state bounds and the cuts of an unsafe
/// trial point (a vehicle that shadows the ego's lateral moves): the active-set step is
/// Clarabel's minimiser of the same QP, it keeps every row, and with the bounds as rows the
/// clamping of the trial point changes nothing.
#[test]
fn projection_step_with_cuts_and_bounds_matches_clarabel() {
    let s = PlannerSettings {
        z_safe_step: true,
        z_cuts: 3,
        ..PlannerSettings::default()
    };
    let (h, sizes) = scene(12.0, &[(25.0, 0.0, 8.0)]);
    let (lp, constraint) = setup(&s, &h, &sizes);
    let mut shadow = Shadow {
        follow: 0.9,
        last: Vec::new(),
    };
    shadow.set_scene(&h).unwrap();
    let threshold = s.safety_min + s.plan_buffer;
    let target = threshold + s.z_step_margin;
    let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, threshold);
    let it = Iterates::start(&lp);
    let z = it.z.clone();
    safety.eval(&mut shadow, &z).unwrap();
    let mut rows: Vec<StepRow> = safety
        .rows
        .iter()
        .map(|r| StepRow::safety(r, target))
        .collect();
    rows.extend(bound_rows(&lp, &z));
    let g = Lagrangian {
        s: &s,
        lp: &lp,
        delta: &it.delta,
        accel: &it.accel,
        duals: &it.duals,
    };
    let mut residual = vec![State::zeros(); 6];
    let mut weighted = vec![State::zeros(); 6];
    let mut gradient = vec![State::zeros(); 6];
    g.value(&z, &mut residual);
    // A Lagrangian pulled 3 m to the left and 5 m/s faster than Z: the step leaves the rows.
    g.gradient(&z, &residual, &mut weighted, &mut gradient);
    for gk in &mut gradient {
        gk[1] -= 2.0 * lp.weights[1] * 3.0;
        gk[3] -= 2.0 * lp.weights[3] * 5.0;
    }
    let hm = hessian(&s, &lp);
    let n = 24;
    let inverse = {
        let m = nalgebra::DMatrix::from_row_slice(n, n, &hm);
        let inv = m.cholesky().unwrap().inverse();
        (0..n * n).map(|k| inv[(k / n, k % n)]).collect::<Vec<_>>()
    };
    let mut step = vec![State::zeros(); 6];
    assert!(constrained_step(&inverse, &gradient, &rows, 24, &mut step));
    let mut trial = vec![State::zeros(); 6];
    lp.project_step(&z, &step, 1.0, &mut trial);
    let e = safety.eval(&mut shadow, &trial).unwrap();
    assert!(
        !e.is_safe(threshold),
        "the shadowing vehicle makes the first trial unsafe"
    );
    let cuts: Vec<StepRow> = safety
        .rows
        .iter()
        .filter(|r| r.b < target)
        .map(|r| StepRow::safety(&cut_row(r, &trial, &z), target))
        .collect();
    assert!(!cuts.is_empty());
    rows.extend(cuts);
    assert!(constrained_step(&inverse, &gradient, &rows, 24, &mut step));
    let flat_g: Vec<f64> = gradient.iter().flat_map(|s| s.iter().copied()).collect();
    let truth = clarabel_rows(&hm, &flat_g, &rows);
    let d: Vec<f64> = step.iter().flat_map(|s| s.iter().map(|v| -v)).collect();
    for (i, (a, b)) in d.iter().zip(&truth).enumerate() {
        assert!((a - b).abs() < 1e-5, "component {i}: {a} vs {b}");
    }
    for r in &rows {
        assert!(r.along(&truth) >= r.need - 1e-6);
    }
    lp.project_step(&z, &step, 1.0, &mut trial);
    for ((t, zk), dk) in trial.iter().zip(&z).zip(step.iter()) {
        assert!((t - (zk - dk)).amax() < 1e-6, "the step needed no clamping");
    }
}

/// One Z-update from the same safe Z and inputs, with and without the projection, in a scene
/// whose vehicle ahead shadows the ego's lateral moves (the linearisation with the prediction
/// held is wrong): at the first safe iteration the projection ends at a safe Z with a lower G
/// than the safe step with halvings.
#[test]
fn projection_lowers_g_where_the_halved_safe_step_stops() {
    let off = PlannerSettings {
        z_safe_step: true,
        ..PlannerSettings::default()
    };
    let on = PlannerSettings {
        z_cuts: 3,
        ..off.clone()
    };
    let (h, sizes) = scene(12.0, &[(8.0, 0.0, 6.0)]);
    let (lp, constraint) = setup(&off, &h, &sizes);
    let mut shadow = Shadow {
        follow: 0.3,
        last: Vec::new(),
    };
    shadow.set_scene(&h).unwrap();
    let threshold = off.safety_min + off.plan_buffer;
    let (mut safety, _, mut ws, mut qps) =
        super::tests::call_start(&off, &lp, &constraint, threshold, &mut shadow);
    let mut timings = PhaseTimings::default();
    let g_of = |ws: &Workspace| {
        Lagrangian {
            s: &off,
            lp: &lp,
            delta: &ws.iterates.delta,
            accel: &ws.iterates.accel,
            duals: &ws.iterates.duals,
        }
        .value(&ws.iterates.z, &mut [State::zeros(); 6])
    };
    for it in 0..off.max_iter {
        let mut t = 0.0;
        qps.update(Input::Steering, &off, &lp, &mut ws, it, &mut t)
            .unwrap();
        qps.update(Input::Acceleration, &off, &lp, &mut ws, it, &mut t)
            .unwrap();
        if !ws.current.is_safe(threshold) {
            ws.update_z(&off, &lp, &mut safety, &mut shadow, &mut timings)
                .unwrap();
            ws.update_duals(&off, &lp);
            continue;
        }
        let saved = (
            ws.iterates.z.clone(),
            ws.current.min_b,
            ws.current.rows.clone(),
        );
        ws.update_z(&off, &lp, &mut safety, &mut shadow, &mut timings)
            .unwrap();
        let g_off = g_of(&ws);
        ws.iterates.z = saved.0;
        ws.current.min_b = saved.1;
        ws.current.violation = 0.0;
        ws.current.rows = saved.2;
        ws.update_z(&on, &lp, &mut safety, &mut shadow, &mut timings)
            .unwrap();
        let g_on = g_of(&ws);
        let now = safety.eval(&mut shadow, &ws.iterates.z).unwrap();
        assert!(now.is_safe(threshold), "iteration {it}: {now:?}");
        assert!(
            g_on < g_off - 1.0,
            "iteration {it}: G {g_on} with the projection, {g_off} without"
        );
        return;
    }
    panic!("no safe iteration");
}

/// The safe start against a brute-force check: from the unsafe nominal of a car 16 m ahead at
/// half the ego's speed (two of the simple candidates safe), the start is the safe simple candidate of least cost (each candidate
/// rolled out, clamped and checked on its own), its evaluation that of its Z; without
/// `safe_start`, or when no candidate is safe (the car 8 m ahead), the nominal and its own
/// evaluation.
#[test]
fn safe_start_is_the_cheapest_safe_candidate() {
    for (others, any_safe) in [
        (vec![(16.0, 0.0, 6.0)], true),
        (vec![(8.0, 0.0, 6.0)], false),
    ] {
        let s = PlannerSettings {
            safe_start: true,
            ..PlannerSettings::default()
        };
        let (h, sizes) = scene(12.0, &others);
        let (lp, constraint) = setup(&s, &h, &sizes);
        let model = model(&s);
        let threshold = s.safety_min + s.plan_buffer;
        let mut cv = ConstantVelocity::default();
        cv.set_scene(&h).unwrap();
        let fresh = |z: &[State], cv: &mut ConstantVelocity| {
            let mut e = SafetyEval::new(&constraint, lp.origin, 6, others.len() + 1, threshold);
            let v = e.eval(cv, z).unwrap();
            (v, e.rows.clone(), e.violation_gradient.clone())
        };
        let nominal = Iterates::start(&lp);
        assert!(
            !fresh(&nominal.z, &mut cv).0.is_safe(threshold),
            "the nominal is unsafe"
        );
        // Brute force.
        // (cost, inputs and Z) of the best safe candidate.
        let mut best: Option<(f64, StartCandidate)> = None;
        for (d, a) in simple_inputs(&s, &model, &lp) {
            let mut z = vec![State::zeros(); 6];
            model.rollout(&lp.start, &d, &a, &mut z);
            let z: Vec<State> = z
                .iter()
                .enumerate()
                .map(|(k, zk)| lp.clamp(k, zk))
                .collect();
            if fresh(&z, &mut cv).0.is_safe(threshold) {
                let cost = lp.cost(&s, &d, &a, &z);
                if best.as_ref().is_none_or(|b| cost < b.0) {
                    let c = StartCandidate {
                        delta: d,
                        accel: a,
                        z,
                    };
                    best = Some((cost, c));
                }
            }
        }
        assert_eq!(best.is_some(), any_safe);
        for safe_start in [true, false] {
            let s = PlannerSettings {
                safe_start,
                ..s.clone()
            };
            let mut safety =
                SafetyEval::new(&constraint, lp.origin, 6, others.len() + 1, threshold);
            let (it, e) = start(&s, &model, &lp, &mut safety, &mut cv).unwrap();
            match (&best, safe_start) {
                (Some((_, c)), true) => {
                    assert_eq!((&it.delta, &it.accel, &it.z), (&c.delta, &c.accel, &c.z));
                    assert!(e.is_safe(threshold));
                }
                _ => {
                    assert_eq!(it.z, nominal.z);
                    assert_eq!((&it.delta, &it.accel), (&nominal.delta, &nominal.accel));
                }
            }
            let (truth, rows, gradient) = fresh(&it.z, &mut cv);
            assert_eq!(e, truth);
            assert_eq!(safety.rows, rows);
            assert_eq!(safety.violation_gradient, gradient);
        }
    }
}

/// The re-tightening rule by hand: a roll-out 0.07 below Z's minimum and unsafe raises the
/// threshold by that drop plus the margin; a safe roll-out, nothing checked, or a non-finite
/// roll-out (the budget's "not evaluated") leave it; a roll-out above Z adds the margin alone.
#[test]
fn retightening_raises_the_threshold_by_the_rollouts_drop() {
    let near = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() < 1e-12);
    assert!(near(
        retighten::raise(0.03, 0.05, Some(-0.02), 0.0, 0.01),
        0.11
    ));
    assert!(near(
        retighten::raise(0.03, -0.01, Some(0.0), 0.0, 0.01),
        0.04
    ));
    assert_eq!(retighten::raise(0.03, 0.05, Some(0.001), 0.0, 0.01), None);
    assert_eq!(retighten::raise(0.03, 0.05, None, 0.0, 0.01), None);
    assert_eq!(
        retighten::raise(0.03, 0.05, Some(f64::NEG_INFINITY), 0.0, 0.01),
        None
    );
}

/// A lane change with a car 10 m ahead at 10 m/s and one 5 m behind in the target lane that
/// shadows the ego's lateral moves: with the rules and the projection, the loop converges
/// (before `max_iter`) with inputs whose roll-out the predictor finds unsafe, and the plan is
/// a repair; with the re-tightening the loop goes on inside the raised threshold and its own
/// roll-out is admissible (`Converged`).
#[test]
fn retightening_turns_a_converged_unsafe_rollout_into_a_converged_plan() {
    let rules = PlannerSettings {
        z_safe_step: true,
        z_rollout_trial: true,
        relinearise: true,
        plan_buffer: 0.03,
        z_cuts: 3,
        safe_start: true,
        ..PlannerSettings::default()
    };
    let (h, sizes) = scene(12.0, &[(10.0, 0.0, 10.0), (-5.0, 3.7, 12.0)]);
    let p = super::tests::problem(&h, &sizes, 12.0);
    let plan = |s: &PlannerSettings| {
        let mut planner = Planner::new(s.clone()).unwrap();
        let mut shadow = Shadow {
            follow: 0.3,
            last: Vec::new(),
        };
        planner.plan(&p, &mut shadow).unwrap()
    };
    let off = plan(&rules);
    assert!(off.iterations < rules.max_iter, "the loop converged");
    assert!(
        !matches!(
            off.status,
            PlanStatus::Converged | PlanStatus::MaxIterations
        ),
        "its roll-out was not admissible: {:?}",
        off.status
    );
    let on = plan(&PlannerSettings {
        z_retighten: 2,
        ..rules.clone()
    });
    assert_eq!(on.status, PlanStatus::Converged);
    assert!(on.min_safety.is_some_and(|b| b > rules.safety_min));
}
