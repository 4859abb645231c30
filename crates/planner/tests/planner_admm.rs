//! ADMM MPC anchors (PLANNER.md "Correctness anchors") on synthetic straight-road scenes:
//! agreement with the joint Clarabel QP, exact bounds, safety of returned plans,
//! determinism, typed errors on bad input, and property tests.
#![allow(clippy::unwrap_used)]

use nudge_planner::scenario::{VEHICLE_LENGTH, VEHICLE_WIDTH};
use nudge_planner::{
    EgoState, Ellipse, OrientedBox, PlanStatus, Planner, PlannerError, PlannerSettings,
    PlanningProblem, motion_heading,
};
use nudge_predictor::{ConstantVelocity, History, Predictor, T_OBS};
use proptest::prelude::*;

/// Ego at (0, y0) with speed v; others `(dx, y, speed)`; all driving along +x.
fn scene(v: f64, y0: f64, others: &[(f64, f64, f64)]) -> (History, Vec<[f64; 2]>) {
    let n = 1 + others.len();
    let mut pos = Vec::with_capacity(n * T_OBS * 2);
    for &(x, y, s) in std::iter::once(&(0.0, y0, v)).chain(others) {
        for t in 0..T_OBS {
            let back = (T_OBS - 1 - t) as f64 * 0.3;
            pos.push(x - s * back);
            pos.push(y);
        }
    }
    (History::new(pos, n).unwrap(), vec![[4.5, 1.9]; n])
}

fn problem<'a>(
    h: &'a History,
    sizes: &'a [[f64; 2]],
    v: f64,
    y0: f64,
    yt: f64,
) -> PlanningProblem<'a> {
    PlanningProblem {
        ego: EgoState {
            x: 0.0,
            y: y0,
            psi: 0.0,
            v,
        },
        last_delta: 0.0,
        last_accel: 0.0,
        history: h,
        sizes,
        y_target: yt,
        v_ref: v,
        road: [-1.85, 9.25],
        y_retreat: None,
        lanes: None,
    }
}

/// Checks every box/rate bound of a plan exactly.
fn assert_bounds(s: &PlannerSettings, delta: &[f64], accel: &[f64], states: &[[f64; 4]]) {
    let mut pd = 0.0;
    let mut pa = 0.0;
    for (d, a) in delta.iter().zip(accel) {
        assert!(d.abs() <= s.bounds.delta_max, "delta {d}");
        assert!(
            (d - pd).abs() <= s.bounds.ddelta_max + 1e-12,
            "steering rate {d} after {pd}"
        );
        assert!(*a >= s.bounds.a_min && *a <= s.bounds.a_max, "accel {a}");
        assert!(
            (a - pa).abs() <= s.bounds.da_max + 1e-12,
            "jerk {a} after {pa}"
        );
        pd = *d;
        pa = *a;
    }
    for z in states {
        assert!(z[3] >= 0.0 && z[3] <= s.bounds.v_max, "speed {}", z[3]);
        assert!(z[1] >= -1.85 && z[1] <= 9.25, "y {} off the road", z[1]);
    }
}

/// With no vehicle in range ADMM on the dynamics linearised once (`relinearise` off) converges
/// to the joint QP's solution; tolerance 1e-3 on every state component of Z (m, rad, m/s) and
/// 1e-3 on the inputs (with `relinearise` on, the fixed point is the joint QP around ADMM's own
/// roll-out: `relinearised_admm_is_the_joint_qp_around_its_own_rollout`). The heading and corridor
/// bounds are left loose so that the nonlinear roll-out of the ADMM inputs is admissible as it
/// is and the plan is ADMM's own answer; its states (that roll-out) differ from Z by the
/// linearisation error only.
#[test]
fn admm_matches_joint_qp_without_vehicles() {
    let settings = {
        let mut s = PlannerSettings::default();
        s.admm.max_iter = 3000;
        s.admm.eps_primal = 1e-7;
        s.admm.eps_change = 1e-7;
        s.bounds.heading_max = 3.0;
        s.bounds.overshoot_max = 100.0;
        s
    };
    // One far vehicle, outside check_range: the safety constraint is inactive.
    let (h, sizes) = scene(12.0, 0.0, &[(200.0, 3.7, 12.0)]);
    let p = problem(&h, &sizes, 12.0, 0.0, 3.7);
    let mut planner = Planner::new(settings).unwrap();
    let reference = planner.reference_qp(&p).unwrap();
    let mut cv = ConstantVelocity::default();
    let plan = planner.plan(&p, &mut cv).unwrap();
    assert_eq!(plan.status, PlanStatus::Converged);
    assert_eq!(plan.checked, 0);
    assert_eq!(plan.predictor_calls, 0);
    for (a, b) in plan.admm_states.iter().zip(&reference.states) {
        for j in 0..4 {
            assert!((a[j] - b[j]).abs() < 1e-3, "state {a:?} vs {b:?}");
        }
    }
    // The returned states are the nonlinear roll-out of the returned inputs (an independent
    // roll-out with the bicycle's own step and the speed clamp).
    let model = nudge_planner::Bicycle {
        l_f: planner.settings().model.l_f,
        l_r: planner.settings().model.l_r,
        dt: planner.settings().model.dt,
    };
    let mut z = nudge_planner::State::new(p.ego.x, p.ego.y, p.ego.psi, p.ego.v);
    for (k, (d, a)) in plan.delta.iter().zip(&plan.accel).enumerate() {
        z = model.step(&z, *d, *a);
        z[3] = z[3].max(0.0);
        assert_eq!(plan.states[k], [z[0], z[1], z[2], z[3]]);
    }
    for (a, b) in plan
        .delta
        .iter()
        .zip(&reference.delta)
        .chain(plan.accel.iter().zip(&reference.accel))
    {
        assert!((a - b).abs() < 1e-3, "input {a} vs {b}");
    }
    assert!((plan.cost - reference.cost).abs() < 1e-2 * reference.cost.max(1.0));
}

/// The minimum b of `states` under the predictor's prediction, each ellipse sized by the ego's
/// planned heading and the other's predicted heading of motion, at the last step lengthened by
/// the rear vehicle's extra braking distance to the front one's speed at `brake_decel`, and
/// whether any predicted bounding box overlaps the ego's.
fn min_b_under(
    pred: &mut dyn Predictor,
    h: &History,
    sizes: &[[f64; 2]],
    states: &[[f64; 4]],
    s: &PlannerSettings,
) -> (f64, bool) {
    pred.set_scene(h).unwrap();
    let cand: Vec<f64> = states.iter().flat_map(|z| [z[0], z[1]]).collect();
    let n = h.n_agents();
    let mut out = vec![0.0; (n - 1) * 6 * 2];
    pred.predict(&cand, &mut out).unwrap();
    let mut m = f64::INFINITY;
    let mut overlap = false;
    for i in 1..n {
        let last = h.at(i, 7);
        let mut prev = [last[0], last[1]];
        for (k, st) in states.iter().enumerate().take(6) {
            let b = (i - 1) * 12 + 2 * k;
            let other = [out[b], out[b + 1]];
            let heading = motion_heading(prev, other, 0.0);
            let other_speed = (other[0] - prev[0]) / s.model.dt;
            prev = other;
            let mut e = Ellipse::with_headings(
                sizes[0],
                st[2],
                sizes[i],
                heading,
                s.safety.ellipse_scale,
                s.safety.margin_x,
                s.safety.margin_y,
            );
            if k == 5 {
                let (rear, front) = if st[0] <= other[0] {
                    (st[3], other_speed.max(0.0))
                } else {
                    (other_speed, st[3].max(0.0))
                };
                e.a_x += ((rear * rear - front * front) / (2.0 * s.safety.brake_decel)).max(0.0);
            }
            m = m.min(e.value([st[0], st[1]], other));
            let ego_box = OrientedBox {
                x: st[0],
                y: st[1],
                heading: st[2],
                length: sizes[0][0],
                width: sizes[0][1],
            };
            let other_box = OrientedBox {
                x: other[0],
                y: other[1],
                heading,
                length: sizes[i][0],
                width: sizes[i][1],
            };
            overlap |= ego_box.overlaps(&other_box);
        }
    }
    (m, overlap)
}

#[test]
fn plans_are_safe_bounded_and_deterministic_with_traffic() {
    let s = PlannerSettings::default();
    // A slower car ahead in the ego lane, a car in the target lane slightly behind.
    let (h, sizes) = scene(
        12.0,
        0.0,
        &[(14.0, 0.0, 9.0), (-9.0, 3.7, 12.5), (25.0, 3.7, 12.0)],
    );
    let p = problem(&h, &sizes, 12.0, 0.0, 3.7);
    let mut a = Planner::new(s.clone()).unwrap();
    let mut b = Planner::new(s.clone()).unwrap();
    let mut cv = ConstantVelocity::default();
    let pa = a.plan(&p, &mut cv).unwrap();
    let pb = b.plan(&p, &mut cv).unwrap();
    assert_ne!(pa.status, PlanStatus::Unsafe);
    assert!(pa.predictor_calls > 0);
    assert_bounds(&s, &pa.delta, &pa.accel, &pa.states);
    let (mb, overlap) = min_b_under(&mut cv, &h, &sizes, &pa.states, &s);
    assert!(mb > 0.0, "returned plan unsafe: min b = {mb}");
    assert!(!overlap, "a predicted box overlaps the plan's");
    let reported = pa.min_safety.unwrap();
    assert!(
        (reported - mb).abs() < 1e-9,
        "min_safety {reported} vs {mb}"
    );
    // Determinism: bit-identical plans from identical inputs.
    for (x, y) in pa.states.iter().flatten().zip(pb.states.iter().flatten()) {
        assert_eq!(x.to_bits(), y.to_bits());
    }
    for (x, y) in pa.delta.iter().zip(&pb.delta) {
        assert_eq!(x.to_bits(), y.to_bits());
    }
}

#[test]
fn invalid_settings_are_typed_errors() {
    let bad = [
        {
            let mut s = PlannerSettings::default();
            s.cost.w_y = -1.0;
            s
        },
        {
            let mut s = PlannerSettings::default();
            s.model.horizon = 0;
            s
        },
        {
            let mut s = PlannerSettings::default();
            s.bounds.a_min = 3.0;
            s.bounds.a_max = 3.0;
            s
        },
        {
            let mut s = PlannerSettings::default();
            s.bounds.delta_max = 0.0;
            s
        },
        {
            let mut s = PlannerSettings::default();
            s.admm.rho = f64::NAN;
            s
        },
        {
            let mut s = PlannerSettings::default();
            s.admm.max_iter = 0;
            s
        },
        {
            let mut s = PlannerSettings::default();
            s.safety.safety_min = -0.1;
            s
        },
    ];
    let fields = [
        "w_y",
        "horizon",
        "a_max",
        "delta_max",
        "rho",
        "max_iter",
        "safety.safety_min",
    ];
    for (s, f) in bad.into_iter().zip(fields) {
        match Planner::new(s) {
            Err(PlannerError::Settings(e)) => {
                assert!(e.to_string().contains(f), "{e} should name {f}")
            }
            other => panic!("expected a settings error naming {f}, got {other:?}"),
        }
    }
    assert!(PlannerSettings::from_json(r#"{"cost": {"w_y": 2.0, "bogus": 1}}"#).is_err());
    let e = PlannerSettings::from_json(r#"{"w_y": 2.0}"#).unwrap_err();
    assert!(
        e.to_string().contains("`w_y` moved: it is now `cost.w_y`"),
        "{e}"
    );
    let e = PlannerSettings::from_json(r#"{"z_safe_step": true}"#).unwrap_err();
    assert!(e.to_string().contains("`z_safe_step` was removed"), "{e}");
    let ok = PlannerSettings::from_json(r#"{"cost": {"w_y": 2.0}}"#).unwrap();
    assert_eq!(ok.cost.w_y, 2.0);
    assert_eq!(ok.model.horizon, 6);
}

#[test]
fn bad_problems_are_typed_errors() {
    let (h, sizes) = scene(12.0, 0.0, &[(14.0, 0.0, 9.0)]);
    let mut planner = Planner::new(PlannerSettings::default()).unwrap();
    let mut cv = ConstantVelocity::default();
    let mut p = problem(&h, &sizes, 12.0, 0.0, 3.7);
    p.ego.v = f64::NAN;
    assert!(matches!(
        planner.plan(&p, &mut cv),
        Err(PlannerError::BadProblem { field: "ego.v", .. })
    ));
    let p2 = PlanningProblem {
        sizes: &sizes[..1],
        ..problem(&h, &sizes, 12.0, 0.0, 3.7)
    };
    assert!(matches!(
        planner.plan(&p2, &mut cv),
        Err(PlannerError::BadProblem { field: "sizes", .. })
    ));
    let mut cv5 = ConstantVelocity::new(5).unwrap();
    let p3 = problem(&h, &sizes, 12.0, 0.0, 3.7);
    assert!(matches!(
        planner.plan(&p3, &mut cv5),
        Err(PlannerError::HorizonMismatch { .. })
    ));
}

/// The ego's safety slices are bounded: at the finest accepted slice length a 16 m ego (a
/// plausible vehicle, `VEHICLE_LENGTH`) needs exactly `MAX_EGO_SEGMENTS` = 64 slices and plans;
/// 16.01 m needs 65 and is refused naming `sizes` (not cut into an unbounded number of
/// ellipses); with one ellipse for the whole ego (`ego_segment_length` 0) the same ego plans.
#[test]
fn an_ego_needing_too_many_safety_slices_is_a_typed_error() {
    let fine = {
        let mut s = PlannerSettings::default();
        s.safety.ego_segment_length = PlannerSettings::MIN_EGO_SEGMENT_LENGTH;
        s
    };
    let at_most = PlannerSettings::MAX_EGO_SEGMENTS as f64 * fine.safety.ego_segment_length;
    assert!(
        at_most + 0.01 < VEHICLE_LENGTH[1],
        "the refused ego must be a plausible vehicle, so that only the slices refuse it"
    );
    let (h, mut sizes) = scene(12.0, 0.0, &[(40.0, 3.7, 12.0)]);
    let mut cv = ConstantVelocity::default();
    sizes[0][0] = at_most;
    let plan = Planner::new(fine.clone())
        .unwrap()
        .plan(&problem(&h, &sizes, 12.0, 0.0, 3.7), &mut cv)
        .unwrap();
    assert!(plan.states.iter().flatten().all(|v| v.is_finite()));
    sizes[0][0] = at_most + 0.01;
    match Planner::new(fine.clone())
        .unwrap()
        .plan(&problem(&h, &sizes, 12.0, 0.0, 3.7), &mut cv)
    {
        Err(PlannerError::BadProblem {
            field: "sizes",
            reason,
        }) => assert!(reason.contains("MAX_EGO_SEGMENTS"), "{reason}"),
        other => panic!(
            "a {} m ego in {} m slices: {other:?}",
            sizes[0][0], fine.safety.ego_segment_length
        ),
    }
    let whole = {
        let mut s = fine;
        s.safety.ego_segment_length = 0.0;
        s
    };
    Planner::new(whole)
        .unwrap()
        .plan(&problem(&h, &sizes, 12.0, 0.0, 3.7), &mut cv)
        .unwrap();
}

/// A raw problem is checked against the bounds of the scenario files (`VEHICLE_LENGTH`,
/// `VEHICLE_WIDTH`, one source for both) and the road: a 100 m ego, a 0.2 m wide one, a 40 m
/// other vehicle and an ego whose centre is 5 m beyond an edge are typed errors naming the
/// field and the agent or the distance; the bounds themselves and an ego centred
/// `MAX_OFF_ROAD` beyond either edge plan.
#[test]
fn implausible_vehicles_and_an_ego_off_the_road_are_typed_errors() {
    let (h, sizes) = scene(12.0, 0.0, &[(40.0, 3.7, 12.0)]);
    let mut cv = ConstantVelocity::default();
    let mut planner = Planner::new(PlannerSettings::default()).unwrap();
    let refused =
        |planner: &mut Planner, p: PlanningProblem<'_>, cv: &mut ConstantVelocity| match planner
            .plan(&p, cv)
        {
            Err(PlannerError::BadProblem { field, reason }) => (field, reason),
            other => panic!("accepted: {other:?}"),
        };
    for (agent, size, what) in [
        (0, [100.0, 1.9], "agent 0 (the ego) has length 100"),
        (0, [4.5, 0.2], "agent 0 (the ego) has width 0.2"),
        (1, [40.0, 2.5], "agent 1 has length 40"),
        (1, [f64::NAN, 2.5], "agent 1 has length NaN"),
    ] {
        let mut bad = sizes.clone();
        bad[agent] = size;
        let (field, reason) = refused(&mut planner, problem(&h, &bad, 12.0, 0.0, 3.7), &mut cv);
        assert_eq!(field, "sizes");
        assert!(reason.contains(what), "{reason}");
    }
    let mut edge = sizes.clone();
    edge[0] = [VEHICLE_LENGTH[1], VEHICLE_WIDTH[1]];
    edge[1] = [VEHICLE_LENGTH[0], VEHICLE_WIDTH[0]];
    planner
        .plan(&problem(&h, &edge, 12.0, 0.0, 3.7), &mut cv)
        .unwrap();
    // The road of `problem` is [-1.85, 9.25] m.
    let max = PlanningProblem::MAX_OFF_ROAD;
    for (y, side) in [(-1.85 - 5.0, "right"), (9.25 + 5.0, "left")] {
        let (h, sizes) = scene(12.0, y, &[(40.0, 3.7, 12.0)]);
        let (field, reason) = refused(&mut planner, problem(&h, &sizes, 12.0, y, 3.7), &mut cv);
        assert_eq!(field, "ego.y");
        assert!(
            reason.contains(&format!("5.00 m beyond the road's {side} edge")),
            "{reason}"
        );
    }
    for y in [-1.85 - max, 9.25 + max] {
        let (h, sizes) = scene(12.0, y, &[(40.0, 3.7, 12.0)]);
        planner.reset();
        planner
            .plan(&problem(&h, &sizes, 12.0, y, 3.7), &mut cv)
            .unwrap_or_else(|e| panic!("y = {y}: {e}"));
    }
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 16,
        rng_seed: proptest::test_runner::RngSeed::Fixed(5), ..ProptestConfig::default() })]

    /// Random initial states, traffic and settings: no panic, plans within every bound, and a
    /// returned plan not marked Unsafe is safe under the predictor.
    #[test]
    fn plans_respect_bounds(
        v in 0.0f64..25.0,
        y0 in -0.5f64..4.0,
        psi in -0.1f64..0.1,
        last_delta in -0.2f64..0.2,
        last_accel in -6.0f64..4.0,
        dx in 10.0f64..40.0,
        w_y in 0.0f64..30.0,
        rho in 10.0f64..2000.0,
        delta_max in 0.05f64..0.3,
    ) {
        let s = {
            let mut s = PlannerSettings::default();
            s.cost.w_y = w_y;
            s.admm.rho = rho;
            s.bounds.delta_max = delta_max;
            s.admm.max_iter = 20;
            s
        };
        let (h, sizes) = scene(v, y0, &[(dx, 3.7, v * 0.8), (-dx, 0.0, v)]);
        let mut p = problem(&h, &sizes, v, y0, 3.7);
        p.ego.psi = psi;
        p.last_delta = last_delta;
        p.last_accel = last_accel;
        let mut planner = Planner::new(s.clone()).unwrap();
        let mut cv = ConstantVelocity::default();
        let plan = planner.plan(&p, &mut cv).unwrap();
        // Bounds with the clamped last inputs.
        let mut pd = last_delta.clamp(-s.bounds.delta_max, s.bounds.delta_max);
        let mut pa = last_accel.clamp(s.bounds.a_min, s.bounds.a_max);
        for (d, a) in plan.delta.iter().zip(&plan.accel) {
            prop_assert!(d.abs() <= s.bounds.delta_max);
            prop_assert!((d - pd).abs() <= s.bounds.ddelta_max + 1e-12);
            prop_assert!(*a >= s.bounds.a_min && *a <= s.bounds.a_max);
            prop_assert!((a - pa).abs() <= s.bounds.da_max + 1e-12);
            pd = *d;
            pa = *a;
        }
        for z in &plan.states {
            prop_assert!(z[3] >= 0.0 && z[3] <= s.bounds.v_max.max(v));
        }
        if plan.status != PlanStatus::Unsafe
            && let Some(b) = plan.min_safety
        {
            prop_assert!(b > 0.0);
        }
    }
}
