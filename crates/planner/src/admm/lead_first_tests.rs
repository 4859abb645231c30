//! The lead rule: among fallbacks without an admissible plan of an ego at least as fast as
//! `repair.lead_min_speed` and wholly inside one lane, a roll-out that keeps the lane ranks
//! first ([`super::RankKey::KeepsLane`]), then the safety violation against the vehicles ahead
//! of the ego in its path ([`super::RankKey::Ahead`]), before the total violation.

#![allow(clippy::unwrap_used)]

use nudge_predictor::{ConstantVelocity, Predictor};

use nudge_predictor::{History, T_OBS};

use super::tests::{model, problem};
use super::*;

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

/// The settings with the lead rule off: its speed floor above every ego's speed.
fn lead_off() -> PlannerSettings {
    let mut s = PlannerSettings::default();
    s.repair.lead_min_speed = 100.0;
    s
}

/// The squeezed scene with two lanes split by a line at `line` (m).
fn plan_in_lanes(line: f64, s: PlannerSettings) -> Plan {
    let (h, sizes) = squeezed();
    let (bounds, extents) = two_lanes(line);
    let p = PlanningProblem {
        lanes: Some(crate::extents::Lanes {
            bounds: &bounds,
            extents: &extents,
        }),
        ..problem(&h, &sizes, 20.0)
    };
    plan_cv(s, &p)
}

/// The ego at 20 m/s in its lane, squeezed: a slower leader (16 m/s) 14 m ahead in its lane,
/// a faster follower (24 m/s) 12 m behind in its lane, and a car beside it in the target
/// lane (y = 3.7) at its speed. Every vehicle 4.5 m × 1.9 m, observed at constant velocity.
fn squeezed() -> (nudge_predictor::History, Vec<[f64; 2]>) {
    scene_of(&[
        (14.0, 0.0, 16.0, 0.0),
        (-12.0, 0.0, 24.0, 0.0),
        (0.0, 3.7, 20.0, 0.0),
    ])
}

/// The plan of `p` under `s` with the constant-velocity prediction.
fn plan_cv(s: PlannerSettings, p: &PlanningProblem<'_>) -> Plan {
    Planner::new(s)
        .unwrap()
        .plan(p, &mut ConstantVelocity::new(6).unwrap())
        .unwrap()
}

/// The safety evaluation of `accel` (held steering 0) from the call on `p` under `s`, with
/// the constant-velocity prediction.
fn evaluation(
    s: &PlannerSettings,
    p: &PlanningProblem<'_>,
    accel: &[f64],
) -> super::constraint::Evaluation {
    let m = model(s);
    let lp = LinearisedProblem::new(s, &m, None, p);
    let constraint = SafetyConstraint::new(p, s);
    let mut safety = SafetyEval::new(&constraint, lp.origin, 6, p.history.n_agents(), 0.0);
    let mut rollout = vec![crate::model::State::zeros(); 6];
    m.rollout(&lp.start, &[0.0; 6], accel, &mut rollout);
    let mut cv = ConstantVelocity::new(6).unwrap();
    cv.set_scene(p.history).unwrap();
    safety.eval(&mut cv, &rollout).unwrap()
}

/// The violation against vehicles ahead is the part of the path violation whose vehicle is
/// ahead of the ego: a follower alone adds none, a leader alone all of it, a car beside
/// none (it is not in the path).
#[test]
fn ahead_violation_counts_only_the_vehicles_ahead_in_the_path() {
    let s = PlannerSettings::default();
    let hold = [0.0; 6];
    for (others, ahead_is_all) in [
        (vec![(-6.0, 0.0, 22.0, 0.0)], false),
        (vec![(12.0, 0.0, 17.0, 0.0)], true),
        (vec![(0.0, 2.6, 20.0, 0.0)], false),
    ] {
        let (h, sizes) = scene_of(&others);
        let p = problem(&h, &sizes, 20.0);
        let e = evaluation(&s, &p, &hold);
        assert!(e.violation > 0.0, "{others:?}: the pair is violated: {e:?}");
        if ahead_is_all {
            assert!(
                (e.ahead_violation - e.path_violation).abs() < 1e-12,
                "{e:?}"
            );
            assert!((e.ahead_violation - e.violation).abs() < 1e-12, "{e:?}");
        } else {
            assert_eq!(e.ahead_violation, 0.0, "{others:?}: {e:?}");
        }
    }
    // All three together: the leader's share alone.
    let (h, sizes) = scene_of(&[(12.0, 0.0, 17.0, 0.0)]);
    let leader = evaluation(&s, &problem(&h, &sizes, 20.0), &hold).ahead_violation;
    let (h, sizes) = scene_of(&[
        (-6.0, 0.0, 22.0, 0.0),
        (12.0, 0.0, 17.0, 0.0),
        (0.0, 2.6, 20.0, 0.0),
    ]);
    let all = evaluation(&s, &problem(&h, &sizes, 20.0), &hold);
    assert!((all.ahead_violation - leader).abs() < 1e-12, "{all:?}");
    assert!(all.violation > all.ahead_violation + 1e-6, "{all:?}");
}

/// The rank's order: `ahead` decides after the state bounds, contact, the road edge and the
/// lane keeping, and before the unbegun lane, the speed floor and the total violation.
#[test]
fn ahead_ranks_after_contact_and_edge_before_the_total_violation() {
    use super::repair::{Rank, Violations};
    let v = |contact: f64, edge: f64, ahead: f64, clear: bool, value: f64| Violations {
        unbegun: false,
        clear,
        value,
        bound_excess: 0.0,
        contact,
        edge,
        ahead,
        leaves_lane: false,
    };
    let s = PlannerSettings::default();
    let rank = |x: Violations| Rank::inadmissible(&s, &x);
    // Less violation ahead beats a smaller total violation and the speed floor.
    let brake = v(0.0, 0.0, 0.1, false, 2.0);
    let speed_up = v(0.0, 0.0, 0.5, true, 1.0);
    assert_eq!(rank(brake).decide(&rank(speed_up)), (RankKey::Ahead, true));
    // Without a violation ahead (the rule not applying) the speed floor decides.
    let (brake0, speed_up0) = (v(0.0, 0.0, 0.0, false, 2.0), v(0.0, 0.0, 0.0, true, 1.0));
    assert_eq!(
        rank(speed_up0).decide(&rank(brake0)),
        (RankKey::ClearPath, true)
    );
    // Contact and the road edge still decide first.
    let touches = v(0.3, 0.0, 0.0, false, 0.5);
    let over_edge = v(0.0, 0.2, 0.0, false, 0.5);
    assert_eq!(rank(brake).decide(&rank(touches)), (RankKey::Contact, true));
    assert_eq!(
        rank(brake).decide(&rank(over_edge)),
        (RankKey::RoadEdge, true)
    );
    // Equal ahead: the total violation decides.
    assert_eq!(
        rank(v(0.0, 0.0, 0.1, false, 1.0)).decide(&rank(brake)),
        (RankKey::Value, true)
    );
}

/// The squeezed ego inside its lane: nothing is admissible. Without the lead rule the fallback
/// speeds up towards the slower leader, away from the follower; with it (the default) it
/// brakes and ends farther from the leader (bumper gap at the constant-velocity positions),
/// with less violation against it. An ego slower than `lead_min_speed` is ranked as without
/// it.
#[test]
fn lead_rule_brakes_a_squeezed_ego_instead_of_speeding_up_towards_its_leader() {
    let (h, sizes) = squeezed();
    let plan_at = |lead_min_speed: f64| {
        let mut s = PlannerSettings::default();
        s.repair.lead_min_speed = lead_min_speed;
        plan_in_lanes(1.85, s)
    };
    let (off, on) = (
        plan_at(100.0),
        plan_at(PlannerSettings::default().repair.lead_min_speed),
    );
    // At its speed floor the rule applies; just above it, it does not.
    assert_eq!(plan_at(20.5).accel, off.accel);
    assert_eq!(plan_at(20.0).accel, on.accel);
    for plan in [&off, &on] {
        assert_eq!(plan.status, PlanStatus::Unsafe, "{:?}", plan.accel);
    }
    let v_end = |plan: &Plan| plan.states.last().unwrap()[3];
    assert!(v_end(&off) > 20.0, "off: speeds up: {:?}", off.accel);
    assert!(
        on.accel.iter().all(|&a| a <= 0.0) && v_end(&on) < 20.0,
        "on: brakes: {:?}",
        on.accel
    );
    // The leader at constant velocity: 14 m ahead at 16 m/s.
    let gap = |plan: &Plan| {
        let k = plan.states.len();
        14.0 + 16.0 * 0.3 * k as f64 - plan.states[k - 1][0] - 4.5
    };
    assert!(gap(&on) > gap(&off) + 1.0, "{} vs {}", gap(&on), gap(&off));
    let s = PlannerSettings::default();
    let p = problem(&h, &sizes, 20.0);
    let ahead = |plan: &Plan| evaluation(&s, &p, &plan.accel).ahead_violation;
    assert!(
        ahead(&on) < ahead(&off),
        "{} vs {}",
        ahead(&on),
        ahead(&off)
    );
}

/// Two lanes, both open along the whole scene, split by a line at `line` (m); the road's
/// edges as [`problem`]'s.
fn two_lanes(line: f64) -> ([f64; 3], [crate::scenario::LaneExtent; 2]) {
    let open = crate::scenario::LaneExtent {
        begin: -500.0,
        end: 2000.0,
        begins: false,
        ends: false,
    };
    ([-1.85, line, 5.55], [open, open])
}

/// Whether the ego's box starts within one lane: its extent across the road at its heading
/// against the interior lane lines only; never without a layout.
#[test]
fn starts_in_one_lane_tests_the_box_across_the_road_at_its_heading() {
    let s = PlannerSettings::default();
    let m = model(&s);
    let (h, sizes) = scene_of(&[(40.0, 0.0, 20.0, 0.0)]);
    let (bounds, extents) = two_lanes(1.85);
    let lanes = crate::extents::Lanes {
        bounds: &bounds,
        extents: &extents,
    };
    let at = |y: f64, psi: f64, with_lanes: bool| {
        let mut p = problem(&h, &sizes, 20.0);
        p.ego.y = y;
        p.ego.psi = psi;
        if with_lanes {
            p.lanes = Some(lanes);
        }
        LinearisedProblem::new(&s, &m, None, &p).starts_in_one_lane()
    };
    // The ego is 4.5 m × 1.9 m (problem's sizes[0]): half width 0.95 m.
    assert!(at(0.0, 0.0, true));
    assert!(
        !at(0.0, 0.0, false),
        "no layout: unknown, so not in one lane"
    );
    // 0.6 + 0.95 = 1.55 < 1.85 straight; turned by 0.2 rad the half extent is
    // ½(4.5 sin 0.2 + 1.9 cos 0.2) = 1.378 m, so its corner reaches 1.978 > 1.85.
    assert!(at(0.6, 0.0, true));
    assert!(!at(0.6, 0.2, true));
    assert!(!at(1.85, 0.0, true), "on the line");
    // Against the road's edge (not a lane line) it is still in its lane.
    assert!(at(-1.5, 0.0, true));
    assert!(!lanes.spans_line(-1.85, 1.85) && lanes.spans_line(1.84, 1.86));
}

/// The lead rule applies only to an ego wholly inside one lane: with the lane line through
/// the squeezed ego's box the plan is bit for bit the plan without the rule; inside its lane
/// the rule changes it.
#[test]
fn the_lead_rule_applies_only_to_an_ego_within_one_lane() {
    // The ego's box spans y ∈ [-0.95, 0.95]: within the lane below 1.85, across a line at 0.5.
    let (within, across) = (1.85, 0.5);
    let plan = |line: f64, s: PlannerSettings| plan_in_lanes(line, s).accel;
    let on = PlannerSettings::default;
    assert_ne!(plan(within, on()), plan(within, lead_off()));
    assert_eq!(plan(across, on()), plan(across, lead_off()));
}

/// The lane keeping's rank: staying off the lane lines decides before the violation ahead,
/// after contact and the road edge.
#[test]
fn keeping_the_lane_ranks_before_the_violation_ahead() {
    use super::repair::{Rank, Violations};
    let v = |contact: f64, ahead: f64, leaves_lane: bool| Violations {
        unbegun: false,
        clear: false,
        value: 1.0,
        bound_excess: 0.0,
        contact,
        edge: 0.0,
        ahead,
        leaves_lane,
    };
    let s = PlannerSettings::default();
    let rank = |x: Violations| Rank::inadmissible(&s, &x);
    let keeps = v(0.0, 0.5, false);
    let leaves = v(0.0, 0.1, true);
    assert_eq!(
        rank(keeps).decide(&rank(leaves)),
        (RankKey::KeepsLane, true)
    );
    // Contact still decides first.
    assert_eq!(
        rank(leaves).decide(&rank(v(0.2, 0.5, false))),
        (RankKey::Contact, true)
    );
}

/// The squeezed ego inside its lane: no state of the plan puts its box across the lane line,
/// and the fallback that chose it says so.
#[test]
fn the_lead_rule_keeps_a_braking_ego_off_the_lane_lines() {
    let on = plan_in_lanes(1.85, PlannerSettings::default());
    let (h, sizes) = squeezed();
    let (bounds, extents) = two_lanes(1.85);
    let p = PlanningProblem {
        lanes: Some(crate::extents::Lanes {
            bounds: &bounds,
            extents: &extents,
        }),
        ..problem(&h, &sizes, 20.0)
    };
    let s = PlannerSettings::default();
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let rel: Vec<crate::model::State> = on
        .states
        .iter()
        .map(|z| crate::model::State::new(z[0], z[1], z[2], z[3]))
        .collect();
    assert!(!lp.spans_line(&rel), "{:?}", on.states);
    assert!(
        matches!(on.decided_by, DecidedBy::Fallback { .. }),
        "{:?}",
        on.decided_by
    );
}
