//! Log replay past the end of a vehicle's log: its speed along the road is held and its
//! sideways motion fades by `SimConfig::replay_lateral_decay` per step. Checked against the
//! closed form of the geometric series, in the simulator's own world (through each step's
//! nearest-vehicle record). `nudge-research` checks its oracle's `LoggedTraffic` against the
//! same runs (`research/tests/oracle.rs`).
#![allow(clippy::unwrap_used)]

use nudge_planner::PlannerSettings;
use nudge_predictor::{ConstantVelocity, DT};
use nudge_sim::{SimConfig, World, WorldModel, simulate};

mod logged;

/// Logged future steps of the drifting vehicle before its log ends.
const LOG: usize = 5;
/// Its sideways displacement over each of its last two logged steps (m, towards the ego).
const DY: f64 = -0.1;

/// An ego at 10 m/s in lane 0 and, 30 m ahead in lane 1 at 10 m/s, a vehicle whose log ends
/// after [`LOG`] steps, the last two of them moving it [`DY`] sideways each.
fn scene() -> nudge_planner::Scenario {
    logged::drifting_at_log_end(LOG, DY)
}

/// Where agent 1 is after closed-loop step `s` (0-based; the log gives future step k = s + 1),
/// for lateral decay `rho`: x at 10 m/s throughout; y = 3.5 up to step LOG − 2 of the log,
/// then 3.5 + DY and 3.5 + 2·DY, then j = k − LOG steps past its end
/// 3.5 + 2·DY + DY·(ρ + ρ² + … + ρʲ).
fn expected(s: usize, rho: f64) -> [f64; 2] {
    let k = s + 1;
    let x = 30.0 + 10.0 * DT * k as f64;
    let y = if k + 1 < LOG {
        3.5
    } else if k <= LOG {
        3.5 + DY * (k + 2 - LOG) as f64
    } else {
        let j = (k - LOG) as i32;
        let sum = if rho == 1.0 {
            f64::from(j)
        } else {
            rho * (1.0 - rho.powi(j)) / (1.0 - rho)
        };
        3.5 + 2.0 * DY + DY * sum
    };
    [x, y]
}

#[test]
fn past_its_log_a_vehicle_keeps_its_speed_and_its_sideways_motion_fades() {
    let sc = scene();
    let s = PlannerSettings::default();
    for rho in [0.0, 0.5, SimConfig::default().replay_lateral_decay, 1.0] {
        let cfg = SimConfig {
            world: World::LogReplay,
            max_steps: 20,
            settle_steps: SimConfig::MAX_STEPS,
            replay_lateral_decay: rho,
            ..SimConfig::default()
        };
        let mut cv = ConstantVelocity::default();
        let run = simulate(&sc, &s, &cfg, 0, &mut cv, WorldModel::LogReplay).unwrap();
        assert_eq!(run.steps.len(), 20, "rho {rho}: the run goes the distance");
        for (k, st) in run.steps.iter().enumerate() {
            let want = expected(k, rho);
            let (agent, dx, dy) = st.nearest.unwrap();
            assert_eq!(agent, 1);
            let p = [st.ego[0] + dx, st.ego[1] + dy];
            assert!(
                (p[0] - want[0]).abs() < 1e-9 && (p[1] - want[1]).abs() < 1e-9,
                "rho {rho}, step {k}: {p:?} vs {want:?}"
            );
        }
    }
    // The default keeps a wobble within its bound: at most DY·ρ/(1 − ρ) beyond the log.
    let rho = SimConfig::default().replay_lateral_decay;
    assert!((expected(19, rho)[1] - (3.5 + 2.0 * DY)).abs() <= DY.abs() * rho / (1.0 - rho));
    assert!((expected(19, 1.0)[1] - (3.5 + 2.0 * DY)).abs() > 1.0);
}
