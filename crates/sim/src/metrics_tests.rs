//! The metrics on constructed states, each against an independent truth: hand geometry of
//! the boxes and the road, interval overlap for contacts, the analytic time to collision (and
//! the boxes advanced to it), hand-computed kinematics and scores.

use std::collections::HashMap;

use super::*;

/// Three 3.5 m lanes: bounds −1.75, 1.75, 5.25, 8.75.
const BOUNDS: [f64; 4] = [-1.75, 1.75, 5.25, 8.75];

fn car(x: f64, y: f64, heading: f64, vx: f64) -> Vehicle {
    Vehicle {
        bbox: OrientedBox {
            x,
            y,
            heading,
            length: 4.0,
            width: 2.0,
        },
        vx,
    }
}

#[test]
fn corners_and_extents_by_hand() {
    let psi: f64 = 0.3;
    let b = car(10.0, 1.0, psi, 0.0).bbox;
    let (s, c) = psi.sin_cos();
    // Front-left corner: centre + half length along the heading + half width across it.
    let fl = [10.0 + 2.0 * c - 1.0 * s, 1.0 + 2.0 * s + 1.0 * c];
    assert!(
        corners(&b)
            .iter()
            .any(|p| (p[0] - fl[0]).abs() < 1e-12 && (p[1] - fl[1]).abs() < 1e-12)
    );
    let (lo, hi) = lateral_extent(&b);
    assert!((hi - (1.0 + 2.0 * s + c)).abs() < 1e-12);
    assert!((lo - (1.0 - 2.0 * s - c)).abs() < 1e-12);
    let (rear, front) = longitudinal_extent(&b);
    assert!((front - (10.0 + 2.0 * c + s)).abs() < 1e-12);
    assert!((rear - (10.0 - 2.0 * c - s)).abs() < 1e-12);
}

#[test]
fn off_road_and_straddle_by_hand_geometry() {
    // Centred in lane 0: 0.75 m inside both lines, on the road by 0.75 m.
    let a = car(0.0, 0.0, 0.0, 0.0).bbox;
    assert!((road_excess(&a, &BOUNDS) - (-0.75)).abs() < 1e-12);
    assert!(!straddles(&a, &BOUNDS));
    assert!(wholly_in_one_lane(&a, &BOUNDS, 0.0));
    assert_eq!(lane_of(0.0, &BOUNDS), Some(0));
    // Its right side 0.3 m beyond the right edge: y − 1 = −2.05.
    let b = car(0.0, -1.05, 0.0, 0.0).bbox;
    assert!((road_excess(&b, &BOUNDS) - 0.3).abs() < 1e-12);
    assert!(!wholly_in_one_lane(&b, &BOUNDS, 0.2));
    assert!(wholly_in_one_lane(&b, &BOUNDS, 0.35));
    // Turned by 0.2 rad at the left edge: the front-left corner sticks out by
    // y + 2 sin ψ + cos ψ − 8.75.
    let psi: f64 = 0.2;
    let c = car(0.0, 7.4, psi, 0.0).bbox;
    let expected = 7.4 + 2.0 * psi.sin() + psi.cos() - 8.75;
    assert!((road_excess(&c, &BOUNDS) - expected).abs() < 1e-12);
    // Straddling: the line at 1.75 strictly inside (1.0, 3.0).
    let d = car(0.0, 2.0, 0.0, 0.0).bbox;
    assert!(straddles(&d, &BOUNDS) && !wholly_in_one_lane(&d, &BOUNDS, 1.0));
    // Touching a line is not straddling.
    let e = car(0.0, 0.75, 0.0, 0.0).bbox;
    assert!(!straddles(&e, &BOUNDS));
    // A turned car whose corner crosses the line straddles although its centre is 1 m away.
    let f = car(0.0, 0.5, 0.15, 0.0).bbox;
    assert!(0.5 + 2.0 * 0.15_f64.sin() + 0.15_f64.cos() > 1.75 && straddles(&f, &BOUNDS));
    assert_eq!(lane_of(-2.0, &BOUNDS), None);
    assert_eq!(lane_of(8.0, &BOUNDS), Some(2));
}

#[test]
fn collisions_are_classified_by_the_stated_rule() {
    let ego = car(0.0, 0.0, 0.0, 20.0).bbox;
    let classify = |other: &Vehicle, ego: &OrientedBox, accel: f64| {
        classify_collision(3, ego, 20.0, accel, 5, other, &BOUNDS, 0.1, 3.0, 1.4)
    };
    // Rear-ended in its lane while braking gently: not at fault.
    let behind = car(-3.9, 0.2, 0.0, 25.0);
    assert!(ego.overlaps(&behind.bbox));
    let c = classify(&behind, &ego, -2.0);
    assert!(!c.at_fault && c.other_behind && c.rear_hit && c.ego_in_lane);
    assert_eq!((c.step, c.other), (3, 5));
    assert!((c.dx + 3.9).abs() < 1e-12 && (c.dy - 0.2).abs() < 1e-12);
    // Exactly at the braking limit: still not at fault; harder: at fault.
    assert!(!classify(&behind, &ego, -3.0).at_fault);
    assert!(classify(&behind, &ego, -3.01).at_fault);
    // Rear-ended while straddling a lane line: at fault.
    let straddling = car(0.0, 1.6, 0.0, 20.0).bbox;
    let behind_s = car(-3.9, 1.6, 0.0, 25.0);
    let c = classify(&behind_s, &straddling, 0.0);
    assert!(c.at_fault && c.rear_hit && !c.ego_in_lane);
    // The ego runs into a car ahead: at fault.
    let ahead = car(3.9, 0.0, 0.0, 10.0);
    let c = classify(&ahead, &ego, 0.0);
    assert!(c.at_fault && !c.other_behind);
    // Hit from behind at the side: the other's centre is 2.05 m across (not below half the
    // sum of the widths, 2 m), its front corner touching the side of the turned ego: at fault.
    let side = car(-1.0, 2.05, 0.0, 25.0);
    let turned = car(0.0, 0.0, 0.3, 20.0).bbox;
    assert!(turned.overlaps(&side.bbox));
    let c = classify(&side, &turned, 0.0);
    assert!(c.other_behind && !c.rear_hit && c.at_fault);
}

/// nuPlan's types and rule on hand geometry: ego 4 m × 2 m at the origin heading along the
/// road at 20 m/s, its rear axle 1.4 m behind its centre (at x = −1.4), its front edge x = 2.
#[test]
fn collisions_are_also_typed_and_judged_as_nuplan_does() {
    let ego = car(0.0, 0.0, 0.0, 20.0).bbox;
    let typed = |other: &Vehicle, ego: &OrientedBox, v: f64| {
        let c = classify_collision(3, ego, v, 0.0, 5, other, &BOUNDS, 0.1, 3.0, 1.4);
        assert_eq!(c.nuplan_type, nuplan_collision_type(ego, v, 1.4, other));
        (c.nuplan_type, c.nuplan_at_fault, c.at_fault)
    };
    use NuplanCollision::*;
    // Rear-ended in its lane: the other's centre at (−3.9, 0.2), from the axle (−2.5, 0.2),
    // 175° off the heading: rear, not at fault either way.
    let behind = car(-3.9, 0.2, 0.0, 25.0);
    assert_eq!(typed(&behind, &ego, 20.0), (ActiveRear, false, false));
    // The same while the ego stands (0.05 m/s at most): stopped ego; a stopped other ahead of
    // the ego's bumper: stopped track, at fault.
    assert_eq!(typed(&behind, &ego, 0.05), (StoppedEgo, false, false));
    let parked = car(3.9, 0.0, 0.0, 0.0);
    assert_eq!(typed(&parked, &ego, 20.0), (StoppedTrack, true, true));
    // Running into a moving car ahead: its box (x 1.9..5.9) holds the front edge: front.
    let ahead = car(3.9, 0.0, 0.0, 10.0);
    assert_eq!(typed(&ahead, &ego, 20.0), (ActiveFront, true, true));
    // A car cutting in from behind-left into the side of the turned ego (ψ 0.3, wholly inside
    // lane 0: lateral extent ±1.546 within ±1.75): from the axle (−1.337, −0.414) its centre
    // (−1, 2.05) lies 65° off the heading and the bumper (x ≥ 1.61) is clear of its box
    // (x ≤ 1): lateral, not at fault under nuPlan, at fault under the stated rule (no rear hit).
    let side = car(-1.0, 2.05, 0.0, 25.0);
    let turned = car(0.0, 0.0, 0.3, 20.0).bbox;
    assert!(turned.overlaps(&side.bbox) && wholly_in_one_lane(&turned, &BOUNDS, 0.1));
    assert_eq!(typed(&side, &turned, 20.0), (ActiveLateral, false, true));
    // The same side contact with the ego straddling the line at 1.75: at fault either way.
    let straddling = car(0.0, 1.6, 0.0, 20.0).bbox;
    let beside = car(-0.5, 3.55, 0.0, 20.0);
    assert!(straddling.overlaps(&beside.bbox));
    assert_eq!(
        typed(&beside, &straddling, 20.0),
        (ActiveLateral, true, true)
    );
    // 1 m further forward the other's box (x −1.5..2.5, y 2.55..4.55) holds the bumper's end
    // (x 2, y 2.6): front.
    let beside_front = car(0.5, 3.55, 0.0, 20.0);
    assert_eq!(typed(&beside_front, &straddling, 20.0).0, ActiveFront);
    // Exactly 150° off the heading is not behind (nuPlan: strictly more).
    let at_150 = car(
        -1.4 - 150f64.to_radians().cos().abs() * 2.0,
        2.0 * 0.5,
        0.0,
        20.0,
    );
    assert!(at_150.bbox.x < -1.4 && typed(&at_150, &ego, 20.0).0 != ActiveRear);
    let names: Vec<&str> = [
        StoppedEgo,
        StoppedTrack,
        ActiveRear,
        ActiveFront,
        ActiveLateral,
    ]
    .iter()
    .map(|t| t.as_str())
    .collect();
    assert_eq!(
        names,
        [
            "STOPPED_EGO_COLLISION",
            "STOPPED_TRACK_COLLISION",
            "ACTIVE_REAR_COLLISION",
            "ACTIVE_FRONT_COLLISION",
            "ACTIVE_LATERAL_COLLISION"
        ]
    );
}

proptest::proptest! {
    /// The clipped segment test against dense sampling of the segment (a point is in the
    /// box when its coordinates in the box's frame are within the half extents).
    #[test]
    fn a_segment_touches_a_box_where_its_points_do(
        a in proptest::array::uniform2(-6.0f64..6.0),
        b in proptest::array::uniform2(-6.0f64..6.0),
        heading in -1.5f64..1.5,
    ) {
        let bx = OrientedBox { x: 0.5, y: -0.3, heading, length: 4.0, width: 2.0 };
        let (s, c) = heading.sin_cos();
        let inside = |t: f64, shrink: f64| {
            let p = [a[0] + t * (b[0] - a[0]) - bx.x, a[1] + t * (b[1] - a[1]) - bx.y];
            (p[0] * c + p[1] * s).abs() <= 2.0 - shrink && (-p[0] * s + p[1] * c).abs() <= 1.0 - shrink
        };
        let n = 4000;
        // A point well inside: touches; no point even near: does not (the sampling step is
        // below 0.005 m, the margin 0.01 m).
        let deep = (0..=n).any(|k| inside(f64::from(k) / f64::from(n), 0.01));
        let near = (0..=n).any(|k| inside(f64::from(k) / f64::from(n), -0.01));
        let touches = segment_touches_box(a, b, &bx);
        if deep { proptest::prop_assert!(touches); }
        if !near { proptest::prop_assert!(!touches); }
    }
}

proptest::proptest! {
    /// Contacts of road-aligned boxes are exactly the pairs whose x and y intervals overlap
    /// (independent truth for the separating-axis test at heading 0).
    #[test]
    fn contacts_of_aligned_boxes_are_interval_overlaps(
        xs in proptest::collection::vec(-12.0f64..12.0, 1..6),
        ys in proptest::collection::vec(-4.0f64..4.0, 6),
    ) {
        let ego = car(0.0, 0.0, 0.0, 0.0).bbox;
        let others: Vec<Vehicle> = xs.iter().zip(&ys).map(|(&x, &y)| car(x, y, 0.0, 0.0)).collect();
        let expected: Vec<usize> = others
            .iter()
            .enumerate()
            .filter(|(_, o)| o.bbox.x.abs() < 4.0 && o.bbox.y.abs() < 2.0)
            .map(|(k, _)| k + 1)
            .collect();
        proptest::prop_assert_eq!(contacts(&ego, &others), expected);
    }
}

#[test]
fn time_to_collision_is_the_analytic_one() {
    let ego = car(0.0, 0.0, 0.0, 20.0);
    let ahead = car(30.0, 0.5, 0.0, 15.0);
    // Gap 30 − 2 − 2 = 26 m, closing 5 m/s.
    let ttc = min_ttc_ahead(&ego.bbox, 20.0, &[ahead]).expect("closing");
    assert!((ttc - 5.2).abs() < 1e-12);
    // Advanced at constant speeds, the boxes first touch at the TTC.
    let at = |t: f64| {
        let mut e = ego.bbox;
        let mut o = ahead.bbox;
        e.x += 20.0 * t;
        o.x += 15.0 * t;
        e.overlaps(&o)
    };
    assert!(!at(ttc - 1e-6) && at(ttc + 1e-6));
    // Ignored: a car in the next lane (no lateral overlap), one behind, one pulling away.
    let others = [
        car(10.0, 3.5, 0.0, 0.0),
        car(-10.0, 0.0, 0.0, 40.0),
        car(15.0, 0.0, 0.0, 25.0),
    ];
    assert_eq!(min_ttc_ahead(&ego.bbox, 20.0, &others), None);
    // The nearest of two closing cars, and 0 once the boxes overlap along the road.
    let two = [ahead, car(20.0, -0.5, 0.0, 0.0)];
    assert!((min_ttc_ahead(&ego.bbox, 20.0, &two).expect("closing") - 0.8).abs() < 1e-12);
    assert_eq!(
        min_ttc_ahead(&ego.bbox, 20.0, &[car(3.0, 0.0, 0.0, 30.0)]),
        Some(0.0)
    );
}

#[test]
fn slow_steps_need_live_traffic_in_the_ego_lane_else_next_to_it() {
    let ego = car(0.0, 0.0, 0.0, 2.0).bbox;
    // Own lane: 10, 12, 30 m/s within 50 m (median 12); one at 60 m is out of range.
    let own = [
        car(20.0, 0.0, 0.0, 10.0),
        car(-20.0, 0.3, 0.0, 12.0),
        car(45.0, -0.2, 0.0, 30.0),
        car(60.0, 0.0, 0.0, 1.0),
        car(5.0, 3.5, 0.0, 1.0),
    ];
    assert_eq!(traffic_speed(&ego, &own, &BOUNDS), Some(12.0));
    assert!(is_slow(3.0, Some(12.0)) && !is_slow(3.6, Some(12.0)));
    // No one in the own lane: the adjacent lane's median (two values: their mean).
    let next = [
        car(10.0, 3.5, 0.0, 8.0),
        car(-10.0, 3.5, 0.0, 11.0),
        car(0.0, 7.0, 0.0, 1.0),
    ];
    assert_eq!(traffic_speed(&ego, &next, &BOUNDS), Some(9.5));
    // Stopped traffic is not live: standing still with it is not slow.
    assert!(!is_slow(0.0, Some(3.0)) && !is_slow(0.0, None));
    assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
    assert_eq!(median(&[]), None);
}

#[test]
fn lead_gap_is_where_the_advanced_ego_first_touches_the_car_ahead() {
    let ego = car(0.0, 0.0, 0.0, 10.0).bbox;
    // In the path: 0.8 m to the side (boxes overlap laterally) and turned 0.2 rad.
    let ahead = car(25.0, 0.8, 0.2, 10.0);
    let gap = lead_gap(&ego, &[ahead]).expect("a car ahead");
    // Independent truth: advance the ego along the road until its box first overlaps the
    // other's (separating-axis test).
    let touches = |d: f64| {
        let mut e = ego;
        e.x += d;
        e.overlaps(&ahead.bbox)
    };
    assert!(!touches(gap - 1e-6) && touches(gap + 1e-6), "gap {gap}");
    // Not in the path: the next lane, a car behind; none ahead at all gives None.
    let aside = [car(10.0, 3.5, 0.0, 0.0), car(-10.0, 0.0, 0.0, 0.0)];
    assert_eq!(lead_gap(&ego, &aside), None);
    // The nearer of two cars ahead; ≤ 0 once they overlap along the road.
    let two = [ahead, car(12.0, -0.5, 0.0, 0.0)];
    assert!((lead_gap(&ego, &two).expect("ahead") - 8.0).abs() < 1e-12);
    assert!(lead_gap(&ego, &[car(3.0, 0.0, 0.0, 0.0)]).expect("ahead") <= 0.0);
}

proptest::proptest! {
    /// The sweep gap against the separating-axis test on the ego advanced along the road:
    /// apart just before it, touching just after it; never touching on a fine grid when there
    /// is none.
    #[test]
    fn the_sweep_gap_is_the_first_touch_of_the_advanced_box(
        x in 5.0f64..30.0,
        y in -4.0f64..4.0,
        heading in -1.2f64..1.2,
        ego_heading in -0.3f64..0.3,
    ) {
        let ego = OrientedBox { x: 0.0, y: 0.0, heading: ego_heading, length: 4.5, width: 1.9 };
        let other = OrientedBox { x, y, heading, length: 5.0, width: 2.0 };
        proptest::prop_assume!(!ego.overlaps(&other));
        let touches = |d: f64| {
            let mut e = ego;
            e.x += d;
            e.overlaps(&other)
        };
        match sweep_gap(&ego, &other) {
            Some(g) => {
                proptest::prop_assert!(g >= 0.0);
                proptest::prop_assert!(!touches(g - 1e-6) && touches(g + 1e-6), "gap {}", g);
            }
            None => {
                for k in 0..=800 {
                    proptest::prop_assert!(!touches(0.05 * f64::from(k)));
                }
            }
        }
    }
}

#[test]
fn the_road_is_free_beyond_two_seconds_of_headway() {
    // At the faster of the ego (8 m/s) and the traffic (10 m/s): 20 m.
    assert!(road_free(Some(20.0), 8.0, Some(10.0)));
    assert!(!road_free(Some(19.9), 8.0, Some(10.0)));
    // The ego faster than the traffic: its own speed (15 m/s: 30 m).
    assert!(!road_free(Some(29.0), 15.0, Some(10.0)) && road_free(Some(30.0), 15.0, None));
    // Nobody ahead: free; overlapping: never.
    assert!(road_free(None, 12.0, Some(10.0)) && !road_free(Some(-0.5), 0.0, Some(10.0)));
    // Nothing non-finite makes the road free.
    assert!(!road_free(Some(50.0), f64::NAN, Some(10.0)));
    assert!(!road_free(None, f64::NAN, None));
    assert!(!road_free(Some(f64::NAN), 8.0, Some(10.0)));
}

#[test]
fn a_planned_standstill_counts_as_on_a_free_road_only_without_a_queue_ahead() {
    let sc = two_lane_scene(0.0, 6);
    let mut obs = RunObserver::new(&sc, 1, 3.0, 1.4);
    // Live traffic in the ego's lane at 10 m/s (one car behind, out of contact), and the ego
    // at 10 m/s planning to end at 1 m/s (< 0.3 × 10): slow, planned.
    let behind = car(-30.0, 0.0, 0.0, 10.0);
    // Step 0: a car 10 m ahead (bumper gap 6 m < 2 s × 10 m/s): a queue, not a free road.
    let (m0, _, _) = obs.observe(
        0,
        [0.0, 0.0, 0.0, 10.0],
        -5.0,
        1.0,
        &[behind, car(10.0, 0.0, 0.0, 10.0)],
    );
    assert!(m0.slow_planned && !m0.slow_planned_free);
    assert!((m0.lead_gap.expect("ahead") - 6.0).abs() < 1e-12);
    // Step 1: the car ahead 30 m on (bumper gap 26 m ≥ 20 m): free.
    let (m1, _, _) = obs.observe(
        1,
        [0.0, 0.0, 0.0, 10.0],
        -5.0,
        1.0,
        &[behind, car(30.0, 0.0, 0.0, 10.0)],
    );
    assert!(m1.slow_planned && m1.slow_planned_free);
    // Step 2: nobody ahead, and the plan keeps speed: neither.
    let (m2, _, _) = obs.observe(2, [0.0, 0.0, 0.0, 10.0], 0.0, 10.0, &[behind]);
    assert!(!m2.slow_planned && !m2.slow_planned_free && m2.lead_gap.is_none());
    let (_, m) = obs.finish(false);
    assert_eq!((m.slow_planned_steps, m.slow_planned_free_steps), (2, 1));
}

#[test]
fn kinematics_and_comfort_by_hand() {
    let dt = DT;
    let k0 = kinematics([0.0, 0.0, 0.0, 10.0], [3.0, 0.0, 0.03, 12.0], 1.0, None);
    assert!((k0.yaw_rate - 0.1).abs() < 1e-12);
    assert!((k0.lat_accel - 0.1 * 11.0).abs() < 1e-12);
    assert_eq!((k0.jerk, k0.yaw_accel), (None, None));
    let k1 = kinematics(
        [3.0, 0.0, 0.03, 12.0],
        [6.0, 0.0, 0.0, 12.0],
        -2.0,
        Some((1.0, 0.1)),
    );
    assert!((k1.jerk.expect("second step") - (-3.0 / dt)).abs() < 1e-12);
    assert!((k1.yaw_rate - (-0.1)).abs() < 1e-12);
    assert!((k1.yaw_accel.expect("second step") - (-0.2 / dt)).abs() < 1e-12);
    let c = Comfort::of(&[k0, k1], &[1.0, -2.0]);
    assert!((c.max_abs_jerk - 10.0).abs() < 1e-9 && (c.rms_jerk - 10.0).abs() < 1e-9);
    assert!((c.max_abs_yaw_rate - 0.1).abs() < 1e-12);
    let rms_lat = ((1.1_f64.powi(2) + 1.2_f64.powi(2)) / 2.0).sqrt();
    assert!((c.rms_lat_accel - rms_lat).abs() < 1e-12);
    assert_eq!(c.accel_range, (-2.0, 1.0));
    // A jerk of 10 m/s³ exceeds nuPlan's 4.13.
    assert!(!c.comfortable);
    let smooth = kinematics(
        [3.0, 0.0, 0.03, 12.0],
        [6.0, 0.0, 0.03, 12.0],
        0.5,
        Some((1.0, 0.1)),
    );
    assert!(Comfort::of(&[k0, smooth], &[1.0, 0.5]).comfortable);
    assert!(
        !Comfort::of(&[k0], &[-4.1]).comfortable,
        "braking beyond −4.05"
    );
}

#[test]
fn score_gates_and_weights() {
    let mut m = RunMetrics {
        comfort: Comfort {
            comfortable: true,
            ..Comfort::default()
        },
        progress_ratio: Some(0.8),
        min_ttc: Some(2.0),
        slow_steps: 2,
        ..RunMetrics::default()
    };
    // (5·1 + 5·0.8 + 5·1 + 4·(1 − 2/10) + 2·1) / 21.
    let expected = (5.0 + 4.0 + 5.0 + 3.2 + 2.0) / 21.0;
    assert!((score(&m, true, 10) - expected).abs() < 1e-12);
    // Failure and a TTC below 0.95 s drop their parts.
    m.min_ttc = Some(0.9);
    assert!((score(&m, false, 10) - (4.0 + 3.2 + 2.0) / 21.0).abs() < 1e-12);
    // Progress beyond the log counts as full.
    m.progress_ratio = Some(1.7);
    m.min_ttc = None;
    assert!((score(&m, true, 10) - (5.0 + 5.0 + 5.0 + 3.2 + 2.0) / 21.0).abs() < 1e-12);
    // The gates.
    m.collisions_at_fault = 1;
    assert_eq!(score(&m, true, 10), 0.0);
    m.collisions_at_fault = 0;
    m.collisions_not_at_fault = 1;
    assert!(
        score(&m, false, 10) > 0.0,
        "a collision that is not the ego's fault"
    );
    m.off_road_steps = 1;
    assert_eq!(score(&m, true, 10), 0.0);
}

/// A two-lane scene: the ego (4 × 2 m) at x = 0 in lane 0 at 10 m/s, logged to move 3 m per
/// step; in lane 1 a car ahead at 20 m and one behind at −15 m; `future` logged steps.
fn two_lane_scene(ego_y: f64, future: usize) -> Scenario {
    let n = 3;
    let starts = [(0.0, ego_y), (20.0, 3.5), (-15.0, 3.5)];
    let mut history = Vec::new();
    for (x, y) in starts {
        for t in 0..T_OBS {
            history.extend([x - 3.0 * (T_OBS - 1 - t) as f64, y]);
        }
    }
    let mut fut = Vec::new();
    for (x, y) in starts {
        for k in 1..=future {
            fut.extend([x + 3.0 * k as f64, y]);
        }
    }
    Scenario {
        name: "two-lane".into(),
        n_agents: n,
        history,
        heading: vec![0.0; n],
        speed: vec![10.0; n],
        size: vec![[4.0, 2.0], [5.0, 2.0], [4.0, 2.0]],
        n_future: future,
        future: fut,
        future_valid: vec![true; n * future],
        lane_centres: vec![0.0, 3.5],
        lane_bounds: vec![-1.75, 1.75, 5.25],
        ego_lane: 0,
        agent_ids: vec![10, 11, 12],
        lane_extents: None,
        metadata: HashMap::new(),
    }
}

#[test]
fn free_gap_is_bumper_to_bumper_around_the_ego() {
    let sc = two_lane_scene(0.0, 6);
    // Rear of the car ahead 20 − 2.5, front of the one behind −15 + 2.
    assert!((free_gap(&sc, 1) - (17.5 + 13.0)).abs() < 1e-12);
    // Nobody else in lane 0: both ends at 60 m.
    assert!((free_gap(&sc, 0) - 2.0 * FREE_GAP_RANGE_M).abs() < 1e-12);
}

#[test]
fn the_observer_judges_a_lane_change_run() {
    // The ego starts 0.3 m over the right edge (its 1 m half width below −1.75: y = −1.05),
    // drives 2.7 m per step and moves 1 m left per step up to lane 1's centre (3.5 m).
    let sc = two_lane_scene(-1.05, 4);
    let mut obs = RunObserver::new(&sc, 1, 3.0, 1.4);
    assert!((obs.off_road_tolerance() - 0.4).abs() < 1e-12);
    let others_at = |k: usize| {
        let d = 3.0 * k as f64;
        vec![
            car(20.0 + d, 3.5, 0.0, 10.0),
            car(-15.0 + d, 3.5, 0.0, 10.0),
        ]
    };
    let mut lanes = Vec::new();
    for k in 1..=6 {
        let ego = [3.0 * k as f64 * 0.9, (-1.05 + k as f64).min(3.5), 0.0, 9.0];
        let (m, touching, near) = obs.observe(k - 1, ego, -0.5, 9.0, &others_at(k));
        assert!(touching.is_empty() && near.is_some());
        assert!(!m.off_road);
        lanes.push((m.straddle, m.in_target_lane));
    }
    // y after each step: −0.05, 0.95, 1.95, 2.95, 3.5, 3.5 (box ±1 m): straddles the line
    // at 1.75 while y ∈ (0.75, 2.75); the centre enters lane 1 at step 3 (y = 1.95).
    let straddle: Vec<bool> = lanes.iter().map(|l| l.0).collect();
    assert_eq!(straddle, [false, true, true, false, false, false]);
    let (collisions, m) = obs.finish(true);
    assert!(collisions.is_empty());
    assert_eq!(m.steps_to_lane, Some(3));
    assert_eq!(m.straddle_steps, 2);
    assert!((m.start_overhang - 0.3).abs() < 1e-12);
    assert!((m.progress - 16.2).abs() < 1e-12);
    // The log covers 4 steps (12 m); the ego made 10.8 m by then.
    assert!((m.progress_ratio.expect("logged") - 0.9).abs() < 1e-12);
    assert!((m.free_gap - 30.5).abs() < 1e-12);
    assert_eq!(m.min_ttc, None);
    assert!(m.score > 0.0);
    // Straight, and never beyond the target centre (3.5 m).
    assert_eq!((m.max_abs_heading, m.max_overshoot), (0.0, 0.0));
}

#[test]
fn one_event_per_contact_and_off_road_beyond_the_tolerance() {
    let sc = two_lane_scene(0.0, 6);
    let mut obs = RunObserver::new(&sc, 1, 3.0, 1.4);
    // Steps 0-1: a car behind rams the ego (two steps of contact, one event); step 2: apart;
    // step 3: contact again (a second event), with the ego off the road.
    let ego = |y: f64| [0.0, y, 0.0, 10.0];
    let rammer = |x: f64| [car(x, 0.0, 0.0, 12.0)];
    let (_, t0, _) = obs.observe(0, ego(0.0), -1.0, 10.0, &rammer(-3.9));
    let (_, t1, _) = obs.observe(1, ego(0.0), -1.0, 10.0, &rammer(-3.5));
    let (_, t2, _) = obs.observe(2, ego(0.0), -1.0, 10.0, &rammer(-10.0));
    let (m3, t3, _) = obs.observe(3, ego(-1.0), -5.0, 10.0, &[car(-3.0, -1.0, 0.0, 12.0)]);
    assert_eq!(
        (t0, t1, t2, t3.clone()),
        (vec![1], vec![1], vec![], vec![1])
    );
    assert!(m3.off_road && (m3.road_excess - 0.25).abs() < 1e-12);
    let (events, m) = obs.finish(false);
    assert_eq!(events.len(), 2);
    assert!(!events[0].at_fault && events[0].step == 0);
    // The second: braking at −5 m/s² and off the road: at fault.
    assert!(events[1].at_fault && events[1].step == 3 && !events[1].ego_in_lane);
    assert_eq!((m.collisions_at_fault, m.collisions_not_at_fault), (1, 1));
    assert_eq!(m.off_road_steps, 1);
    assert_eq!(m.score, 0.0);
}

#[test]
fn heading_and_overshoot_of_a_run() {
    // Target lane 1 (centre 3.5) to the left of the ego at y = 0: the ego swings to 3.9 m at
    // heading 0.12 rad, comes back to 3.5 m turned −0.05 rad.
    let sc = two_lane_scene(0.0, 6);
    let mut obs = RunObserver::new(&sc, 1, 3.0, 1.4);
    for (k, (y, psi)) in [(1.5, 0.1), (3.9, 0.12), (3.5, -0.05)]
        .into_iter()
        .enumerate()
    {
        let _ = obs.observe(k, [3.0 * (k + 1) as f64, y, psi, 10.0], 0.0, 10.0, &[]);
    }
    let (_, m) = obs.finish(true);
    assert!((m.max_abs_heading - 0.12).abs() < 1e-12);
    assert!((m.max_overshoot - 0.4).abs() < 1e-12);
    // To the right (target lane 0 from y = 3.5): overshooting means going below 0.
    let mut sc = two_lane_scene(3.5, 6);
    sc.ego_lane = 1;
    let mut obs = RunObserver::new(&sc, 0, 3.0, 1.4);
    let _ = obs.observe(0, [3.0, -0.25, 0.0, 10.0], 0.0, 10.0, &[]);
    let (_, m) = obs.finish(false);
    assert!((m.max_overshoot - 0.25).abs() < 1e-12);
}
