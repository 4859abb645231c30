//! Tests of the convergence mechanisms of the ADMM loop, each against an independent truth:
//! the linearised-safety step against a Clarabel solve of the same QP, the re-linearised ADMM
//! against the joint Clarabel QP linearised around its own answer, the roll-out trial against
//! the bicycle's own roll-out; and each fails when its mechanism is switched off.
#![allow(clippy::unwrap_used)]

use clarabel::solver::{DefaultSolver, IPSolver, NonnegativeConeT};
use nudge_predictor::{ConstantVelocity, History, Predictor};

use super::constraint::{SafetyEval, SafetyRow};
use super::inputs::Input;
use super::linearised::LinearisedProblem;
use super::safe_step::linearised_step;
use super::workspace::{CurrentSafety, Iterates, Workspace, max_diff};
use super::z_update::Lagrangian;
use super::*;
use crate::qp::{clarabel_settings, triplets_csc, upper_csc};

/// Ego at (0, 0) with speed v; others `(x, y, speed)`; all driving along +x.
fn scene(v: f64, others: &[(f64, f64, f64)]) -> (History, Vec<[f64; 2]>) {
    super::tests::scene(v, 0.0, others)
}

/// A lane change from y = 0 to y = 3.7 at 12 m/s on a two-lane road.
fn problem<'a>(h: &'a History, sizes: &'a [[f64; 2]]) -> PlanningProblem<'a> {
    super::tests::problem(h, sizes, 12.0)
}

fn model(s: &PlannerSettings) -> Bicycle {
    Bicycle {
        l_f: s.l_f,
        l_r: s.l_r,
        dt: s.dt,
    }
}

/// A deterministic pseudo-random number in [−1, 1).
fn noise(i: usize) -> f64 {
    let x = (i as f64 * 12.9898 + 78.233).sin() * 43_758.545_3;
    2.0 * (x - x.floor()) - 1.0
}

/// min ½dᵀHd + g·d s.t. ∇b_r·d_xy ≥ target − b_r, solved by Clarabel (`h` `[n, n]`).
fn clarabel_step(h: &[f64], g: &[f64], rows: &[SafetyRow], target: f64) -> Vec<f64> {
    let n = g.len();
    let mut a = Vec::new();
    let mut b = Vec::new();
    for (j, r) in rows.iter().enumerate() {
        a.push((j, 4 * r.step, -r.gradient[0]));
        a.push((j, 4 * r.step + 1, -r.gradient[1]));
        b.push(r.b - target);
    }
    let (pm, am) = (upper_csc(h, n), triplets_csc(rows.len(), n, a));
    let cones = [NonnegativeConeT(rows.len())];
    let mut solver = DefaultSolver::new(&pm, g, &am, &b, &cones, clarabel_settings(true)).unwrap();
    solver.solve();
    solver.solution.x.clone()
}

/// The active-set step is the QP's minimiser: it matches Clarabel on the same QP (a random
/// positive-definite H, three rows of which two bind), and with no binding row it is the
/// Newton step −H⁻¹∇G.
#[test]
fn safe_step_matches_clarabel_on_the_same_qp() {
    let n = 24;
    // H = MᵀM + I, g random.
    let m: Vec<f64> = (0..n * n).map(noise).collect();
    let mut h = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            h[i * n + j] = (0..n).map(|r| m[r * n + i] * m[r * n + j]).sum::<f64>();
        }
        h[i * n + i] += 1.0;
    }
    let inverse = {
        let hm = nalgebra::DMatrix::from_row_slice(n, n, &h);
        let inv = hm.cholesky().unwrap().inverse();
        (0..n * n).map(|k| inv[(k / n, k % n)]).collect::<Vec<_>>()
    };
    let g: Vec<f64> = (0..n).map(|i| 10.0 * noise(1000 + i)).collect();
    let gradient: Vec<State> = (0..6)
        .map(|k| State::from_column_slice(&g[4 * k..4 * k + 4]))
        .collect();
    let newton: Vec<f64> = (0..n)
        .map(|r| -(0..n).map(|c| inverse[r * n + c] * g[c]).sum::<f64>())
        .collect();
    let row = |step: usize, b: f64, gradient: [f64; 2]| SafetyRow { step, b, gradient };
    // Each row pushes against the Newton step at its step (binding), except the last.
    let against = |k: usize| [-newton[4 * k].signum(), -newton[4 * k + 1].signum()];
    let rows = [
        row(1, 0.0, against(1)),
        row(4, 0.0, against(4)),
        row(2, 1e3, [0.3, 0.1]),
    ];
    let mut out = vec![State::zeros(); 6];
    assert!(linearised_step(&inverse, &gradient, &rows, 0.01, &mut out));
    let truth = clarabel_step(&h, &g, &rows, 0.01);
    for k in 0..6 {
        for c in 0..4 {
            let d = -out[k][c];
            assert!(
                (d - truth[4 * k + c]).abs() < 1e-6,
                "component {k},{c}: {d} vs {}",
                truth[4 * k + c]
            );
        }
    }
    let moved =
        |k: usize, r: &SafetyRow| r.gradient[0] * truth[4 * k] + r.gradient[1] * truth[4 * k + 1];
    assert!(
        (moved(1, &rows[0]) - 0.01).abs() < 1e-6,
        "the first row binds"
    );
    // No binding row: the Newton step.
    let far = [row(2, 1e3, [0.3, 0.1])];
    assert!(linearised_step(&inverse, &gradient, &far, 0.01, &mut out));
    for k in 0..6 {
        for c in 0..4 {
            assert!((-out[k][c] - newton[4 * k + c]).abs() < 1e-9);
        }
    }
}

/// The lane change without traffic, solved to 1e-7: with `relinearise` the ADMM answer is a
/// fixed point of the sequential-convex loop: Z is the nonlinear roll-out of the inputs, and
/// the joint Clarabel QP of the dynamics linearised around that roll-out returns the same
/// inputs and states. Without it, Z differs from the roll-out by the linearisation error.
#[test]
fn relinearised_admm_is_the_joint_qp_around_its_own_rollout() {
    let (h, sizes) = scene(12.0, &[(200.0, 3.7, 12.0)]);
    let p = problem(&h, &sizes);
    let gap = |relinearise: bool| {
        let s = PlannerSettings {
            max_iter: 3000,
            eps_primal: 1e-7,
            eps_change: 1e-7,
            heading_max: 3.0,
            overshoot_max: 100.0,
            relinearise,
            ..PlannerSettings::default()
        };
        let mut planner = Planner::new(s.clone()).unwrap();
        let plan = planner.plan(&p, &mut ConstantVelocity::default()).unwrap();
        assert_eq!(plan.status, PlanStatus::Converged);
        let gap = plan
            .states
            .iter()
            .zip(&plan.admm_states)
            .flat_map(|(a, b)| (0..4).map(move |j| (a[j] - b[j]).abs()))
            .fold(0.0, f64::max);
        (s, plan, gap)
    };
    let (s, plan, on) = gap(true);
    assert!(on < 1e-5, "Z is the roll-out up to {on}");
    let (_, _, off) = gap(false);
    assert!(off > 1e-3, "without re-linearisation the gap is {off}");
    // The joint QP around the plan's own inputs and roll-out (call frame: origin at the ego).
    let model = model(&s);
    let mut lp = LinearisedProblem::new(&s, &model, None, &p);
    let rollout: Vec<State> = plan
        .states
        .iter()
        .map(|z| State::new(z[0] - lp.origin[0], z[1] - lp.origin[1], z[2], z[3]))
        .collect();
    lp.relinearise(&model, &plan.delta, &plan.accel, &rollout, s.v_lin_min);
    let joint = reference::solve_joint(&s, &lp).unwrap();
    for (a, b) in plan
        .delta
        .iter()
        .zip(&joint.delta)
        .chain(plan.accel.iter().zip(&joint.accel))
    {
        assert!((a - b).abs() < 1e-3, "input {a} vs {b}");
    }
    for (a, b) in plan.admm_states.iter().zip(&joint.states) {
        for j in 0..4 {
            assert!((a[j] - b[j]).abs() < 1e-3, "state {a:?} vs {b:?}");
        }
    }
}

/// One Z-update step (`pgd_steps` = 1) with nothing checked (every trial is safe), from a Z
/// 2 m to the left of where the inputs take the ego (the nominal inputs, a costly primal
/// residual): with `z_rollout_trial` the new Z is the bicycle's own roll-out of the inputs,
/// clamped into the state bounds; without it, it is not.
#[test]
fn rollout_trial_puts_z_on_the_rollout_of_the_inputs() {
    let (h, sizes) = scene(12.0, &[(200.0, 3.7, 12.0)]);
    let p = problem(&h, &sizes);
    let z_after = |z_rollout_trial: bool| {
        let s = PlannerSettings {
            pgd_steps: 1,
            z_rollout_trial,
            ..PlannerSettings::default()
        };
        let model = model(&s);
        let lp = LinearisedProblem::new(&s, &model, None, &p);
        let constraint = SafetyConstraint::new(&p, &s);
        assert!(constraint.vehicles().is_empty());
        let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, 0.0);
        let mut cv = ConstantVelocity::default();
        let mut iterates = Iterates::start(&lp);
        for (k, z) in iterates.z.iter_mut().enumerate() {
            z[1] += 2.0;
            *z = lp.clamp(k, z);
        }
        let first = safety.eval(&mut cv, &iterates.z).unwrap();
        let mut ws = Workspace::new(&s, &lp, iterates, CurrentSafety::new(first, &safety));
        ws.roll_out_inputs(&model, &lp);
        let mut truth = vec![State::zeros(); 6];
        model.rollout(
            &lp.start,
            &ws.iterates.delta,
            &ws.iterates.accel,
            &mut truth,
        );
        let truth: Vec<State> = truth
            .iter()
            .enumerate()
            .map(|(k, z)| lp.clamp(k, z))
            .collect();
        let g = Lagrangian {
            s: &s,
            lp: &lp,
            delta: &ws.iterates.delta,
            accel: &ws.iterates.accel,
            duals: &ws.iterates.duals,
        };
        let mut r = vec![State::zeros(); 6];
        assert!(
            g.value(&truth, &mut r) < g.value(&ws.iterates.z, &mut r),
            "the roll-out lowers G"
        );
        let mut timings = PhaseTimings::default();
        ws.update_z(&s, &lp, &mut safety, &mut cv, &mut timings)
            .unwrap();
        (ws.iterates.z.clone(), truth)
    };
    let (z, truth) = z_after(true);
    assert_eq!(z, truth);
    let (z, truth) = z_after(false);
    assert!(max_diff(&z, &truth) > 1e-3);
}

/// A car 8 m ahead at half the ego's speed: the nominal runs into it. The ADMM iterations
/// (roll-out trial and re-linearisation off) restore Z and then descend; whenever a Z-update
/// without the safe step leaves a safe Z where it was (every Newton trial crosses the
/// constraint boundary), the same Z-update with the safe step moves it, keeps it safe at the
/// threshold and lowers G.
#[test]
fn safe_step_moves_z_where_the_newton_trials_stall() {
    let base = PlannerSettings {
        z_safe_step: true,
        ..PlannerSettings::default()
    };
    let off = PlannerSettings {
        z_safe_step: false,
        ..base.clone()
    };
    let (h, sizes) = scene(12.0, &[(8.0, 0.0, 6.0)]);
    let p = problem(&h, &sizes);
    let model = model(&base);
    let lp = LinearisedProblem::new(&base, &model, None, &p);
    let constraint = SafetyConstraint::new(&p, &base);
    let mut cv = ConstantVelocity::default();
    cv.set_scene(&h).unwrap();
    let threshold = base.safety_min + base.plan_buffer;
    let (mut safety, _, mut ws, mut qps) =
        super::tests::call_start(&off, &lp, &constraint, threshold, &mut cv);
    let mut timings = PhaseTimings::default();
    let mut stalls = 0;
    for it in 0..off.max_iter {
        let mut t = 0.0;
        qps.update(Input::Steering, &off, &lp, &mut ws, it, &mut t)
            .unwrap();
        qps.update(Input::Acceleration, &off, &lp, &mut ws, it, &mut t)
            .unwrap();
        let before = ws.iterates.z.clone();
        let was_safe = ws.current.is_safe(threshold);
        ws.update_z(&off, &lp, &mut safety, &mut cv, &mut timings)
            .unwrap();
        if was_safe && ws.iterates.z == before {
            stalls += 1;
            // The same Z-update with the safe step.
            let g_before = {
                let g = Lagrangian {
                    s: &base,
                    lp: &lp,
                    delta: &ws.iterates.delta,
                    accel: &ws.iterates.accel,
                    duals: &ws.iterates.duals,
                };
                g.value(&before, &mut [State::zeros(); 6])
            };
            ws.update_z(&base, &lp, &mut safety, &mut cv, &mut timings)
                .unwrap();
            assert_ne!(
                ws.iterates.z, before,
                "the safe step did not move Z at iteration {it}"
            );
            let now = safety.eval(&mut cv, &ws.iterates.z).unwrap();
            assert!(now.is_safe(threshold), "{now:?}");
            let g = Lagrangian {
                s: &base,
                lp: &lp,
                delta: &ws.iterates.delta,
                accel: &ws.iterates.accel,
                duals: &ws.iterates.duals,
            };
            assert!(g.value(&ws.iterates.z, &mut [State::zeros(); 6]) < g_before);
            break;
        }
        ws.update_duals(&off, &lp);
    }
    assert_eq!(stalls, 1, "no stall of the Newton trials in this scene");
}
