//! `fallback_match_speed`: fallback profiles that brake to the speed of a slower vehicle
//! ahead and then hold it, instead of braking at a_min towards a standstill.

#![allow(clippy::unwrap_used)]

use nudge_predictor::Predictor;

use super::constraint::SafetyEval;
use super::linearised::LinearisedProblem;
use super::repair::{fallback_accels, match_speed_accels, unwind_loss};
use super::tests::{Gate, model, plain_repairer, problem, repairs_only, rollout_world, scene};
use super::*;

/// The speeds (m/s) of the ego along `accel` (m/s²) from `v0`: v_{k+1} = max(v_k + a_k·dt, 0).
fn speeds(v0: f64, accel: &[f64], dt: f64) -> Vec<f64> {
    let mut v = v0;
    accel
        .iter()
        .map(|a| {
            v = (v + a * dt).max(0.0);
            v
        })
        .collect()
}

/// The speed still lost while a brake unwinds at the jerk bound, written out by hand.
#[test]
fn the_unwinding_loss_sums_the_brake_left_at_each_step() {
    // From −4.5 at 1.5 per step: −3.0, −1.5, then 0 → (3.0 + 1.5) · 0.3.
    assert!((unwind_loss(-4.5, 1.5, 0.3) - 1.35).abs() < 1e-12);
    // From −1.5 the next step is already 0.
    assert_eq!(unwind_loss(-1.5, 1.5, 0.3), 0.0);
    // −2: −0.5, then 0.
    assert!((unwind_loss(-2.0, 1.5, 0.3) - 0.15).abs() < 1e-12);
    assert_eq!(unwind_loss(0.0, 1.5, 0.3), 0.0);
    assert_eq!(unwind_loss(2.0, 1.5, 0.3), 0.0);
}

/// Over a horizon long enough to get there, the profile brakes from 12 to 8 m/s and holds:
/// its speed (integrated independently) never falls below 8, ends within 0.05 of it with
/// the brake released, and every step is within the box and jerk bounds. With a start speed
/// of 20 and a goal of 0 it brakes at a_min as soon as the jerk bound allows.
#[test]
fn the_match_speed_profile_brakes_to_the_goal_and_holds_it() {
    let s = PlannerSettings {
        horizon: 14,
        ..PlannerSettings::default()
    };
    let (h, sizes) = scene(12.0, 0.0, &[(40.0, 3.7, 8.0)]);
    let p = problem(&h, &sizes, 12.0);
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let a = match_speed_accels(&s, &lp, 8.0);
    assert_eq!(a.len(), 14);
    let v = speeds(12.0, &a, s.dt);
    assert!(v.iter().all(|&v| v >= 8.0 - 1e-9), "{v:?}");
    assert!((v[13] - 8.0).abs() < 0.05, "{v:?}");
    assert!(a[13].abs() < 1e-6, "{a:?}");
    assert!(a.iter().any(|&a| a < -3.0), "it brakes hard first: {a:?}");
    let mut prev = lp.accel_box.prev;
    for &ak in &a {
        assert!(ak >= s.a_min - 1e-12 && ak <= s.a_max + 1e-12, "{a:?}");
        assert!((ak - prev).abs() <= s.da_max + 1e-9, "{a:?}");
        prev = ak;
    }
    // To a standstill from 20 m/s the profile is the ramp to a_min (as fast as the jerk bound
    // allows) and then a_min.
    let (h, sizes) = scene(20.0, 0.0, &[(40.0, 3.7, 0.0)]);
    let p = problem(&h, &sizes, 20.0);
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    let a = match_speed_accels(&s, &lp, 0.0);
    assert_eq!(&a[..6], &[-1.5, -3.0, -4.5, -5.0, -5.0, -5.0]);
}

/// The speeds the profiles brake to: of the vehicles ahead whose box reaches into the band
/// between the ego (y = 0) and its goal (y = 3.7), those slower than the ego, nearest first,
/// at most two, none within 0.25 m/s of an earlier one. Behind, faster, two lanes over: not
/// counted. Off by default: none.
#[test]
fn the_lead_speeds_are_those_of_the_nearest_slower_vehicles_ahead_in_the_band() {
    let s = PlannerSettings {
        fallback_match_speed: true,
        ..PlannerSettings::default()
    };
    let others = [
        (40.0, 3.7, 6.0),  // ahead in the target lane, slower: counted
        (20.0, 0.0, 9.0),  // ahead in the own lane, slower: within 0.25 of 9.1
        (-10.0, 0.0, 5.0), // behind
        (30.0, 7.4, 4.0),  // two lanes over: its box is 2.0 m beyond the band
        (25.0, 3.7, 14.0), // faster
        (15.0, 0.9, 9.1),  // nearest: counted first
        (45.0, 0.0, 3.0),  // slower, but beyond the first two
    ];
    let (h, sizes) = scene(12.0, 0.0, &others);
    let p = problem(&h, &sizes, 12.0);
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    assert_eq!(lp.lead_speeds.len(), 2, "{:?}", lp.lead_speeds);
    assert!(
        (lp.lead_speeds[0] - 9.1).abs() < 1e-9,
        "{:?}",
        lp.lead_speeds
    );
    assert!(
        (lp.lead_speeds[1] - 6.0).abs() < 1e-9,
        "{:?}",
        lp.lead_speeds
    );
    // Its box just reaching into the band: a vehicle at y = −1.8 (0.1 m of overlap) counts.
    let (h, sizes) = scene(12.0, 0.0, &[(20.0, -1.8, 7.0)]);
    let p = problem(&h, &sizes, 12.0);
    let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
    assert_eq!(lp.lead_speeds.len(), 1);
    let off = PlannerSettings::default();
    assert!(!off.fallback_match_speed);
    let lp = LinearisedProblem::new(&off, &model(&off), None, &p);
    assert!(lp.lead_speeds.is_empty());
}

/// A slower car (6 m/s) 40 m ahead in the ego's lane (the goal) and a gate ahead of the ego
/// placed so that of the constant profiles only a_min ends short of it. Without the setting
/// the fallback brakes at a_min; with it the fallback takes the profile that brakes to
/// 6 m/s, which also ends short of the gate and keeps more speed: ranked among the constant
/// profiles (`match_admissible_only` off) or checked apart from them (on). Independent check:
/// a candidate is safe iff its road-aligned roll-out ends short of the gate. With the gate
/// moved so that nothing is safe, a match profile is never the least-violating choice while
/// `match_admissible_only` is on.
#[test]
fn the_fallback_brakes_to_the_speed_of_the_slower_car_ahead() {
    let base = PlannerSettings {
        fallback_match_speed: true,
        match_admissible_only: false,
        ..repairs_only()
    };
    let m = model(&base);
    let (h, sizes) = scene(12.0, 0.0, &[(40.0, 0.0, 6.0)]);
    let mut p = problem(&h, &sizes, 12.0);
    p.y_target = 0.0;
    let lp = LinearisedProblem::new(&base, &m, None, &p);
    assert_eq!(lp.lead_speeds.len(), 1);
    let zero_steer = vec![0.0; 6];
    let end = |a: &[f64]| rollout_world(&base, &p, &zero_steer, a)[5];
    let profiles = fallback_accels(&base, &lp);
    assert_eq!(profiles.len(), 5);
    let (half, full, matched) = (&profiles[1], &profiles[2], &profiles[4]);
    let (end_half, end_full, end_match) = (end(half), end(full), end(matched));
    assert!(end_full[0] < end_match[0] && end_match[0] < end_half[0]);
    assert!(end_match[3] >= 6.0 - 1e-9, "{end_match:?}");
    assert!(
        end_match[3] > end_full[3] + 1.0,
        "{end_match:?} vs {end_full:?}"
    );
    let best_of = |s: &PlannerSettings, limit: f64| {
        let lp = LinearisedProblem::new(s, &m, None, &p);
        let constraint = SafetyConstraint::new(&p, s);
        let mut safety = SafetyEval::new(&constraint, lp.origin, 6, 2, s.safety_min);
        let mut gate = Gate::ahead(limit);
        gate.set_scene(&h).unwrap();
        let mut r = plain_repairer(s, &m, &lp, &mut safety, &mut gate);
        for a in [half, full, matched] {
            let c = r.check(zero_steer.clone(), a.clone()).unwrap();
            assert_eq!(c.rank.safe, c.rollout[5][0] <= limit, "{:?}", c.accel);
        }
        r.best_fallback().unwrap()
    };
    let limit = 0.5 * (end_match[0] + end_half[0]);
    for apart in [false, true] {
        let s = PlannerSettings {
            match_admissible_only: apart,
            ..base.clone()
        };
        assert_eq!(fallback_accels(&s, &lp).len(), if apart { 4 } else { 5 });
        let with = best_of(&s, limit);
        assert!(with.rank.safe);
        assert_eq!(&with.accel, matched, "apart: {apart}");
        let without = best_of(
            &PlannerSettings {
                fallback_match_speed: false,
                ..s.clone()
            },
            limit,
        );
        assert!(without.rank.safe);
        assert_eq!(&without.accel, full);
        assert!(with.rollout[5][3] > without.rollout[5][3] + 1.0);
    }
    // Nothing safe: apart, the least-violating fallback is one of the others.
    let s = PlannerSettings {
        match_admissible_only: true,
        ..base.clone()
    };
    let none_safe = best_of(&s, end_full[0] - 1.0);
    assert!(!none_safe.rank.safe);
    assert_ne!(&none_safe.accel, matched);
}

/// `match_min_speed`: below it no match-speed profile is built (a queue, not a free-flowing
/// road); at or above it they are.
#[test]
fn no_match_speed_profile_below_the_minimum_speed() {
    let s = PlannerSettings {
        fallback_match_speed: true,
        ..PlannerSettings::default()
    };
    assert_eq!(s.match_min_speed, 10.0);
    for (v, built) in [(9.5, false), (10.0, true), (12.0, true)] {
        let (h, sizes) = scene(v, 0.0, &[(30.0, 0.0, 4.0)]);
        let p = problem(&h, &sizes, v);
        let lp = LinearisedProblem::new(&s, &model(&s), None, &p);
        assert_eq!(!lp.lead_speeds.is_empty(), built, "v = {v}");
    }
}
