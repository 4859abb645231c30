//! `PlannerSettings::ablate_reaction` through the public planner: the predictor sees only the
//! ego's keep-lane path (computed here by hand), the plan's safety is judged under the
//! teacher's prediction for that path (computed here by calling the teacher directly) whatever
//! the plan, and a constant-velocity planner, whose prediction never depends on the ego, plans
//! the same with and without the ablation.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

mod common;

use common::{problem, scene};
use nudge_planner::{Planner, PlannerSettings, SafetyConstraint};
use nudge_predictor::{ConstantVelocity, History, Predictor, PredictorSpec};

/// Dense: target-lane (y = 3.7 m) vehicles alongside the ego's rear and front.
const DENSE: [(f64, f64, f64); 4] = [
    (0.0, 0.0, 12.0),
    (-4.0, 3.7, 12.5),
    (6.0, 3.7, 11.5),
    (22.0, 0.0, 11.0),
];
/// A gap in the target lane.
const OPEN: [(f64, f64, f64); 3] = [(0.0, 0.0, 12.0), (-25.0, 3.7, 12.0), (20.0, 0.0, 10.0)];

fn teacher() -> Box<dyn Predictor> {
    let assets = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets");
    PredictorSpec::resolve("teacher", &assets, 6)
        .unwrap()
        .build()
}

/// A predictor that records every candidate it is asked about.
struct Recorder {
    inner: Box<dyn Predictor>,
    seen: Vec<Vec<f64>>,
}

impl Predictor for Recorder {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn horizon(&self) -> usize {
        self.inner.horizon()
    }
    fn set_scene(&mut self, h: &History) -> nudge_predictor::Result<()> {
        self.inner.set_scene(h)
    }
    fn predict(&mut self, c: &[f64], out: &mut [f64]) -> nudge_predictor::Result<()> {
        self.seen.push(c.to_vec());
        self.inner.predict(c, out)
    }
}

fn ablated() -> PlannerSettings {
    {
        let mut s = PlannerSettings::default();
        s.safety.ablate_reaction = true;
        s
    }
}

#[test]
fn ablated_teacher_planner_sees_only_the_keep_lane_path() {
    let (h, sizes) = scene(&DENSE);
    // By hand: 12 m/s along the road on y = 0, steps of 0.3 s.
    let keep: Vec<f64> = (1..=6).flat_map(|k| [3.6 * k as f64, 0.0]).collect();
    let mut direct = teacher();
    direct.set_scene(&h).unwrap();
    let mut want = vec![0.0; 3 * 12];
    direct.predict(&keep, &mut want).unwrap();
    let mut plans = Vec::new();
    for y_target in [3.7, 0.0] {
        let p = problem(&h, &sizes, y_target);
        let mut rec = Recorder {
            inner: teacher(),
            seen: Vec::new(),
        };
        let plan = Planner::new(ablated()).unwrap().plan(&p, &mut rec).unwrap();
        assert_eq!(rec.seen.len(), 1, "one prediction per call");
        for (a, b) in rec.seen[0].iter().zip(&keep) {
            assert!((a - b).abs() < 1e-12, "{:?} vs {keep:?}", rec.seen[0]);
        }
        assert_eq!(plan.predictor_calls, 1);
        // The plan's safety is judged under the keep-lane prediction, bit for bit.
        let constraint = SafetyConstraint::new(&p, &ablated());
        let b = constraint.binding(&plan.states, &want).unwrap().b;
        assert_eq!(plan.min_safety.map(f64::to_bits), Some(b.to_bits()));
        plans.push(plan.states);
    }
    assert_ne!(plans[0], plans[1], "two different plans, one prediction");
}

#[test]
fn aware_teacher_planner_sees_its_candidates() {
    let (h, sizes) = scene(&DENSE);
    let p = problem(&h, &sizes, 3.7);
    let mut rec = Recorder {
        inner: teacher(),
        seen: Vec::new(),
    };
    let plan = Planner::new(PlannerSettings::default())
        .unwrap()
        .plan(&p, &mut rec)
        .unwrap();
    assert_eq!(plan.predictor_calls, rec.seen.len());
    let sideways = rec
        .seen
        .iter()
        .filter(|c| c.iter().skip(1).step_by(2).any(|y| y.abs() > 0.05))
        .count();
    assert!(sideways > 0, "{} candidates, none sideways", rec.seen.len());
}

#[test]
fn constant_velocity_planner_is_unaffected() {
    for agents in [&DENSE[..], &OPEN[..]] {
        let (h, sizes) = scene(agents);
        for y_target in [3.7, 0.0] {
            let p = problem(&h, &sizes, y_target);
            let mut cv = ConstantVelocity::new(6).unwrap();
            let on = Planner::new(ablated()).unwrap().plan(&p, &mut cv).unwrap();
            let off = Planner::new(PlannerSettings::default())
                .unwrap()
                .plan(&p, &mut cv)
                .unwrap();
            assert_eq!(on.states, off.states);
            assert_eq!(on.delta, off.delta);
            assert_eq!(on.accel, off.accel);
            assert_eq!(on.status, off.status);
            assert_eq!(
                on.min_safety.map(f64::to_bits),
                off.min_safety.map(f64::to_bits)
            );
        }
    }
}
