//! Embed your own predictor: anything that implements `nudge::predictor::Predictor` can check
//! the planner's candidates. This one is a cautious constant-velocity model that also assumes
//! every other vehicle drifts towards the ego's lateral position by 0.2 m per step (a vehicle
//! that might cut in). The planner is run with it and with plain constant velocity on a shipped
//! scene with dense traffic and the plans are compared: expecting vehicles to cut in, the
//! planner moves the ego less far towards the target lane.
//!
//! Run from the repository root: `cargo run --release --example custom_predictor`.
#![allow(clippy::print_stdout)]

use nudge::planner::{Planner, PlannerSettings, PlanningProblem, Scenario};
use nudge::predictor::{
    ConstantVelocity, History, Predictor, PredictorError, T_OBS, default_assets_dir,
};
use nudge::sim::{SimConfig, target_lane};

/// Constant velocity plus a lateral drift of `drift` m per step towards the ego candidate.
struct CuttingIn {
    horizon: usize,
    drift: f64,
    /// Last two observed positions of every agent (set per scene).
    last: Vec<[[f64; 2]; 2]>,
}

impl Predictor for CuttingIn {
    fn name(&self) -> &'static str {
        "cutting_in"
    }

    fn horizon(&self) -> usize {
        self.horizon
    }

    fn set_scene(&mut self, history: &History) -> nudge::predictor::Result<()> {
        self.last = (0..history.n_agents())
            .map(|i| [history.at(i, T_OBS - 2), history.at(i, T_OBS - 1)])
            .collect();
        Ok(())
    }

    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> nudge::predictor::Result<()> {
        let n = self.last.len();
        let per_candidate = self.horizon * 2;
        if n == 0 {
            return Err(PredictorError::NoScene);
        }
        for (b, cand) in candidates.chunks_exact(per_candidate).enumerate() {
            for (i, [prev, now]) in self.last.iter().enumerate().skip(1) {
                let (vx, vy) = (now[0] - prev[0], now[1] - prev[1]);
                let mut y = now[1];
                for k in 0..self.horizon {
                    let towards = (cand[2 * k + 1] - y).clamp(-self.drift, self.drift);
                    y += vy + towards;
                    let o = ((b * (n - 1) + i - 1) * self.horizon + k) * 2;
                    out[o] = now[0] + vx * (k + 1) as f64;
                    out[o + 1] = y;
                }
            }
        }
        Ok(())
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let sc = Scenario::from_file(
        default_assets_dir().join("scenes/us101-11_1-t02.1-ego132.safetensors"),
    )?;
    let history = History::new(sc.history.clone(), sc.n_agents)?;
    let y_target =
        sc.lane_centres[target_lane(&sc, 0, &PlannerSettings::default(), &SimConfig::default())?];
    let problem = PlanningProblem::at_scenario_start(&sc, &history, y_target);
    let mut cautious = CuttingIn {
        horizon: 6,
        drift: 0.2,
        last: Vec::new(),
    };
    let mut plain = ConstantVelocity::default();
    for (name, predictor) in [
        ("constant velocity", &mut plain as &mut dyn Predictor),
        ("cutting in", &mut cautious as &mut dyn Predictor),
    ] {
        let plan = Planner::new(PlannerSettings::default())?.plan(&problem, predictor)?;
        let last = plan.states[5];
        println!(
            "{name:>17}: status {:<13} lateral move {:+.2} m, speed {:.2} m/s after 1.8 s, \
             min b {:.2}, {} predictor calls",
            plan.status.name(),
            last[1] - problem.ego.y,
            last[3],
            plan.min_safety.unwrap_or(f64::INFINITY),
            plan.predictor_calls
        );
        assert!(plan.predictor_calls > 0, "the custom predictor was asked");
    }
    Ok(())
}
