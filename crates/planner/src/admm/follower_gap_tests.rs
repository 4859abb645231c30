//! The follower-gap rule: the violation of roll-outs against followers that do not react, and
//! the planner refusing to enter the path of a faster follower that its predictor expects to
//! yield.

#![allow(clippy::unwrap_used)]

use nudge_predictor::{History, Predictor, T_OBS};

use super::follower_gap::FollowerGap;
use super::tests::{problem, scene};
use super::*;

/// Predicts every other agent from its last observed position driving along +x at `speed`
/// (m/s), whatever it did before: a follower the predictor expects to yield to the ego.
struct Yielding {
    speed: f64,
    last: Vec<[f64; 2]>,
}

impl Predictor for Yielding {
    fn name(&self) -> &'static str {
        "yielding"
    }
    fn horizon(&self) -> usize {
        6
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.last = (1..history.n_agents())
            .map(|i| history.at(i, T_OBS - 1))
            .collect();
        Ok(())
    }
    fn predict(&mut self, _: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        for (i, p) in self.last.iter().enumerate() {
            for k in 0..6 {
                let o = (i * 6 + k) * 2;
                out[o] = p[0] + self.speed * 0.3 * (k + 1) as f64;
                out[o + 1] = p[1];
            }
        }
        Ok(())
    }
}

/// The rule on at the time to collision measured on validation (`follower_ttc` 2 s; off by
/// default), the other settings at their defaults.
fn rule_on() -> PlannerSettings {
    PlannerSettings {
        follower_ttc: 2.0,
        ..PlannerSettings::default()
    }
}

/// The ego at 20 m/s in its lane (y = 0), a follower 12 m behind in the target lane
/// (y = 3.7) observed at `follower_speed` m/s; both 4.5 m × 1.9 m.
fn follower_scene(follower_speed: f64) -> (History, Vec<[f64; 2]>) {
    scene(20.0, 0.0, &[(-12.0, 3.7, follower_speed)])
}

/// States along +x at 20 m/s (call frame) at the lateral positions `ys`.
fn states(ys: &[f64]) -> Vec<State> {
    ys.iter()
        .enumerate()
        .map(|(k, &y)| State::new(6.0 * (k + 1) as f64, y, 0.0, 20.0))
        .collect()
}

/// The smallest lateral clearance (m) between the ego's planned boxes and the follower's lane
/// position y = 3.7 (both 1.9 m wide).
fn least_clearance(plan: &Plan) -> f64 {
    plan.states
        .iter()
        .map(|z| (3.7 - z[1]).abs() - 1.9)
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn a_plan_may_not_narrow_the_clearance_to_a_faster_follower() {
    let s = rule_on();
    let (h, sizes) = follower_scene(25.0);
    let p = problem(&h, &sizes, 20.0);
    let rule = FollowerGap::new(&p, &s).expect("a follower on the goal's side");
    // Start clearance 3.7 − 1.9 = 1.8 m; bumper gap 12 − 4.5 = 7.5 m, needed 0.5 + 5·2 = 10.5 m.
    assert_eq!(rule.violation(&states(&[0.0; 6])), 0.0, "holding the lane");
    assert_eq!(
        rule.violation(&states(&[0.0, -0.2, -0.4, -0.6, -0.8, -1.0])),
        0.0,
        "moving away"
    );
    // Entering: clearance 1.8 − y; steps with y > 1.0 are below 0.8 m.
    let entering = states(&[0.3, 0.7, 1.1, 1.5, 1.9, 2.3]);
    let v = rule.violation(&entering);
    let expected: f64 = [1.1, 1.5, 1.9, 2.3].iter().map(|y| 0.8 - (1.8 - y)).sum();
    assert!((v - expected).abs() < 1e-9, "{v} vs {expected}");
    // A follower 30 m back at 50 m/s passes the ego's centre after step 3: only step 3
    // (y = 1.1, 0.1 m inside the clearance) counts.
    let (h, sizes) = scene(20.0, 0.0, &[(-30.0, 3.7, 50.0)]);
    let p = problem(&h, &sizes, 20.0);
    let passing = FollowerGap::new(&p, &s).unwrap();
    let v = passing.violation(&entering);
    assert!(
        (v - 0.1).abs() < 1e-9,
        "{v}: only the step before it passes"
    );
}

#[test]
fn slow_far_or_own_lane_followers_and_the_rule_off_leave_the_plan_free() {
    let s = rule_on();
    let entering = states(&[0.3, 0.7, 1.1, 1.5, 1.9, 2.3]);
    // As fast as the ego and 7.5 m back: only the 0.5 m minimum gap applies.
    let (h, sizes) = follower_scene(20.0);
    let p = problem(&h, &sizes, 20.0);
    assert_eq!(FollowerGap::new(&p, &s).unwrap().violation(&entering), 0.0);
    // Faster but far behind: 50 m back at 25 m/s, a bumper gap ≥ 45.5 − 5·1.8 > 10.5 m.
    let (h, sizes) = scene(20.0, 0.0, &[(-50.0, 3.7, 25.0)]);
    let p = problem(&h, &sizes, 20.0);
    assert_eq!(FollowerGap::new(&p, &s).unwrap().violation(&entering), 0.0);
    // A tailgater in the ego's own lane, a vehicle ahead, one on the other side: no rule.
    for other in [(-6.0, 0.3, 25.0), (12.0, 3.7, 25.0), (-12.0, -3.7, 25.0)] {
        let (h, sizes) = scene(20.0, 0.0, &[other]);
        let p = problem(&h, &sizes, 20.0);
        assert!(FollowerGap::new(&p, &s).is_none(), "{other:?}");
    }
    // The rule off (the default).
    let (h, sizes) = follower_scene(25.0);
    let p = problem(&h, &sizes, 20.0);
    assert!(FollowerGap::new(&p, &PlannerSettings::default()).is_none());
}

/// The planner with a predictor that expects the follower to yield (slow to 15 m/s): without
/// the rule it cuts in front of a follower observed at 25 m/s 7.5 m behind; with it the plan
/// keeps the lateral clearance it starts with above `follower_clearance`. A follower observed
/// at the ego's speed does not stop the change.
#[test]
fn the_planner_does_not_cut_in_front_of_a_faster_follower() {
    let plan_with = |s: PlannerSettings, follower_speed: f64| {
        let (h, sizes) = follower_scene(follower_speed);
        let p = problem(&h, &sizes, 20.0);
        let mut predictor = Yielding {
            speed: 15.0,
            last: Vec::new(),
        };
        Planner::new(s).unwrap().plan(&p, &mut predictor).unwrap()
    };
    let without = plan_with(PlannerSettings::default(), 25.0);
    assert!(
        least_clearance(&without) < 0.8,
        "without the rule the ego enters: {}",
        least_clearance(&without)
    );
    let with = plan_with(rule_on(), 25.0);
    assert!(
        least_clearance(&with) >= 0.8 - 1e-9,
        "with the rule it keeps out: {} ({:?})",
        least_clearance(&with),
        with.status
    );
    let slow = plan_with(rule_on(), 20.0);
    assert!(
        least_clearance(&slow) < 0.8,
        "a follower at the ego's speed lets it in: {}",
        least_clearance(&slow)
    );
}

/// A two-lane road (centres 0 and 3.7 m): the ego at 20 m/s in lane 0, a car logged at
/// 25 m/s 12 m behind it in lane 1 (the only target lane), both 4.5 m × 1.9 m.
fn faster_follower_scene() -> crate::Scenario {
    let n = 2;
    let agents = [(0.0, 0.0, 20.0), (-12.0, 3.7, 25.0)];
    let mut history = Vec::new();
    for (x, y, v) in agents {
        for t in 0..T_OBS {
            history.extend([x - v * 0.3 * (T_OBS - 1 - t) as f64, y]);
        }
    }
    let n_future = 20;
    let mut future = Vec::new();
    for (x, y, v) in agents {
        for k in 1..=n_future {
            future.extend([x + v * 0.3 * k as f64, y]);
        }
    }
    crate::Scenario {
        name: "faster-follower".into(),
        n_agents: n,
        history,
        heading: vec![0.0; n],
        speed: vec![20.0, 25.0],
        size: vec![[4.5, 1.9]; n],
        n_future,
        future,
        future_valid: vec![true; n * n_future],
        lane_centres: vec![0.0, 3.7],
        lane_bounds: vec![-1.85, 1.85, 5.55],
        ego_lane: 0,
        agent_ids: vec![1, 2],
        lane_extents: None,
        metadata: std::collections::HashMap::new(),
    }
}

/// The closed loop in the log-replay world (the follower never reacts) with a planner whose
/// predictor expects it to yield: without the rule the ego cuts in 7.5 m ahead of it and is
/// run into from behind within the first steps; with it the ego lets the follower pass and
/// no collision happens.
#[test]
fn in_log_replay_the_ego_lets_a_faster_follower_pass() {
    use crate::sim::{SimConfig, World, WorldModel, simulate};
    let sc = faster_follower_scene();
    let cfg = SimConfig {
        world: World::LogReplay,
        max_steps: 12,
        ..SimConfig::default()
    };
    let run = |s: &PlannerSettings| {
        let mut predictor = Yielding {
            speed: 15.0,
            last: Vec::new(),
        };
        simulate(&sc, s, &cfg, 0, &mut predictor, WorldModel::LogReplay).unwrap()
    };
    let without = run(&PlannerSettings::default());
    assert!(
        without
            .collisions
            .iter()
            .any(|c| c.other == 1 && c.other_behind),
        "without the rule the follower runs into the ego: {:?}",
        without.collisions
    );
    let with = run(&rule_on());
    assert!(
        !with.collision,
        "with the rule no collision: {:?}",
        with.collisions
    );
}
