//! The wall-clock budget and the cancel flag of one MPC call (issue 49, class 7): every
//! valid setting keeps `PlannerSettings::MAX_SECONDS`, a call ends within its budget plus one
//! predictor call, the limit reached is recorded on the plan, and a cancel flag ends a call
//! within one predictor call.
#![allow(clippy::unwrap_used)]

use std::time::{Duration, Instant};

use nudge_predictor::{ConstantVelocity, History, Predictor};

use super::tests::{problem, scene};
use super::*;

/// Constant velocity, `delay` per prediction; sets `cancel` (when given) at its
/// `cancel_at`-th call.
struct Slow {
    cv: ConstantVelocity,
    delay: Duration,
    calls: usize,
    cancel: Option<(Cancel, usize)>,
}

impl Slow {
    fn new(delay_ms: u64) -> Self {
        Self {
            cv: ConstantVelocity::default(),
            delay: Duration::from_millis(delay_ms),
            calls: 0,
            cancel: None,
        }
    }
}

impl Predictor for Slow {
    fn name(&self) -> &'static str {
        "slow"
    }
    fn horizon(&self) -> usize {
        self.cv.horizon()
    }
    fn set_scene(&mut self, history: &History) -> nudge_predictor::Result<()> {
        self.cv.set_scene(history)
    }
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        self.calls += 1;
        if let Some((c, at)) = &self.cancel
            && self.calls == *at
        {
            c.cancel();
        }
        std::thread::sleep(self.delay);
        self.cv.predict(candidates, out)
    }
}

/// Settings at the ends of their ranges that call the predictor as often as the work cap
/// allows (as `every_valid_setting_keeps_the_work_cap`).
fn endless() -> PlannerSettings {
    let mut s = PlannerSettings::default();
    s.admm.max_iter = PlannerSettings::MAX_ITER;
    s.admm.pgd_steps = 100;
    s.admm.pgd_halvings = 30;
    s.admm.eps_primal = 1e-9;
    s.admm.eps_change = 1e-9;
    s.repair.refine_iters = 20;
    s
}

/// Plans with `s` and `predictor`; the plan and the call's wall time.
fn timed(s: &PlannerSettings, predictor: &mut Slow) -> (Plan, Duration) {
    let (h, sizes) = scene(12.0, 0.0, &[(-12.0, 3.7, 12.0), (25.0, 0.0, 11.0)]);
    let p = problem(&h, &sizes, 12.0);
    let t0 = Instant::now();
    let plan = Planner::new(s.clone())
        .unwrap()
        .plan(&p, predictor)
        .unwrap();
    (plan, t0.elapsed())
}

/// Slack for the QP work of the execution check after the deadline and a loaded machine.
const SLACK: Duration = Duration::from_millis(500);

/// With no `budget.seconds` set, settings that would call a 50 ms predictor 5,000 times
/// (over 4 min) end within `PlannerSettings::MAX_SECONDS` plus one call, with a finite plan
/// that records the wall-clock limit.
#[test]
fn every_valid_setting_keeps_the_wall_clock_cap() {
    let mut slow = Slow::new(50);
    let (plan, took) = timed(&endless(), &mut slow);
    let cap = Duration::from_secs_f64(PlannerSettings::MAX_SECONDS);
    assert!(took <= cap + slow.delay + SLACK, "{took:?}");
    assert!(took >= cap / 2, "the cap binds here: {took:?}");
    assert_eq!(plan.budget_reached, Some(BudgetLimit::Seconds));
    assert!(plan.states.iter().flatten().all(|v| v.is_finite()));
    assert_eq!(plan.predictor_calls, slow.calls);
    let mut s = PlannerSettings::default();
    s.budget.seconds = PlannerSettings::MAX_SECONDS * 1.01;
    assert!(s.validate().is_err(), "a budget beyond the cap is refused");
}

/// A small `budget.seconds` holds for settings at the ends of their ranges: the call ends
/// within it plus one predictor call (and the slack), records `Seconds`, and its plan is the
/// roll-out of its inputs.
#[test]
fn a_small_wall_budget_holds_at_the_ends_of_the_ranges() {
    for (budget, delay_ms) in [(0.3, 20), (0.05, 1)] {
        let mut s = endless();
        s.budget.seconds = budget;
        let mut slow = Slow::new(delay_ms);
        let (plan, took) = timed(&s, &mut slow);
        let limit = Duration::from_secs_f64(budget) + slow.delay + SLACK;
        assert!(took <= limit, "budget {budget} s: {took:?}");
        assert_eq!(plan.budget_reached, Some(BudgetLimit::Seconds), "{budget}");
        assert!(plan.states.iter().flatten().all(|v| v.is_finite()));
    }
}

/// The call budget records `Calls`; a call that ends before either limit records none.
#[test]
fn the_limit_reached_is_recorded_on_the_plan() {
    let mut s = endless();
    s.budget.calls = 20;
    let (plan, _) = timed(&s, &mut Slow::new(0));
    assert_eq!(plan.budget_reached, Some(BudgetLimit::Calls));
    assert!(plan.predictor_calls <= 20);
    let (plan, _) = timed(&PlannerSettings::default(), &mut Slow::new(0));
    assert_eq!(plan.budget_reached, None);
}

/// A cancel flag set during the call ends it with `Cancelled` and no further predictor call;
/// the planner keeps its warm start. A flag never set changes nothing (the same plan, bit for
/// bit, as without one); a flag set before the call ends it before any predictor call.
#[test]
fn a_cancel_flag_ends_the_call_within_one_predictor_call() {
    let (h, sizes) = scene(12.0, 0.0, &[(-12.0, 3.7, 12.0), (25.0, 0.0, 11.0)]);
    let p = problem(&h, &sizes, 12.0);
    let s = PlannerSettings::default();
    let mut free = Planner::new(s.clone()).unwrap();
    let expected = free.plan(&p, &mut Slow::new(0)).unwrap();
    assert!(expected.predictor_calls > 5);
    let cancel = Cancel::new();
    let mut planner = Planner::new(s).unwrap();
    planner.set_cancel(Some(cancel.clone()));
    let plan = planner.plan(&p, &mut Slow::new(0)).unwrap();
    assert_eq!(
        plan,
        Plan {
            timings: plan.timings.clone(),
            ..expected.clone()
        }
    );
    let mut slow = Slow::new(0);
    slow.cancel = Some((cancel.clone(), 3));
    match planner.plan(&p, &mut slow) {
        Err(PlannerError::Cancelled) => {}
        other => panic!("{other:?}"),
    }
    assert_eq!(slow.calls, 3, "no predictor call after the flag was set");
    let mut later = Slow::new(0);
    assert!(matches!(
        planner.plan(&p, &mut later),
        Err(PlannerError::Cancelled)
    ));
    assert_eq!(later.calls, 0);
    // The cancelled calls left the warm start of the first call: once the flag is removed, the
    // next call is the second call of a planner that was never cancelled.
    planner.set_cancel(None);
    let second = planner.plan(&p, &mut Slow::new(0)).unwrap();
    let expected = free.plan(&p, &mut Slow::new(0)).unwrap();
    assert_eq!(
        second,
        Plan {
            timings: second.timings.clone(),
            ..expected
        }
    );
}
