//! Synthetic logged scenes shared by the integration tests that run the simulator on them:
//! vehicles driving along +x at constant speed for their history and their logged future.

use std::collections::HashMap;

use nudge_planner::Scenario;
use nudge_planner::scenario::LaneExtent;
use nudge_predictor::{DT, T_OBS};

/// Logged steps of every vehicle.
pub const LOGGED_STEPS: usize = 45;

/// A scene `name` of vehicles `(x, y, v)` (m, m, m/s) at the last observed step (agent 0 = the
/// ego, in lane 0), each 4.5 m × 1.9 m, driving at constant speed along +x for its history and
/// [`LOGGED_STEPS`] logged steps of 0.3 s, on the lanes `bounds` (y, m; the centres halfway)
/// with the lane extents `extents` (`None`: schema 1).
pub fn logged_scene(
    name: &str,
    agents: &[(f64, f64, f64)],
    bounds: &[f64],
    extents: Option<Vec<LaneExtent>>,
) -> Scenario {
    let n = agents.len();
    let mut history = Vec::new();
    let mut future = Vec::new();
    for &(x, y, v) in agents {
        for t in 0..T_OBS {
            history.extend([x - v * DT * (T_OBS - 1 - t) as f64, y]);
        }
        for k in 1..=LOGGED_STEPS {
            future.extend([x + v * DT * k as f64, y]);
        }
    }
    Scenario {
        name: name.to_string(),
        n_agents: n,
        history,
        heading: vec![0.0; n],
        speed: agents.iter().map(|a| a.2).collect(),
        size: vec![[4.5, 1.9]; n],
        n_future: LOGGED_STEPS,
        future,
        future_valid: vec![true; n * LOGGED_STEPS],
        lane_centres: bounds.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect(),
        lane_bounds: bounds.to_vec(),
        ego_lane: 0,
        agent_ids: (0..n as i64).collect(),
        lane_extents: extents,
        metadata: HashMap::new(),
    }
}

/// An ego at 10 m/s in lane 0 and, 30 m ahead in lane 1 at 10 m/s, a vehicle whose log ends
/// after `log` (≥ 2) future steps, the last two of them moving it `dy` (m) sideways each: the
/// scene of the log-replay tests past the end of a log (here and in `nudge-research`).
#[allow(
    dead_code,
    reason = "shared by several test crates, not all of which replay a drifting log"
)]
pub fn drifting_at_log_end(log: usize, dy: f64) -> Scenario {
    let mut sc = logged_scene(
        "drift-at-log-end",
        &[(0.0, 0.0, 10.0), (30.0, 3.5, 10.0)],
        &[-1.75, 1.75, 5.25],
        None,
    );
    let nf = sc.n_future;
    for k in log - 1..=log {
        // future step k (1-based) of agent 1
        sc.future[(nf + k - 1) * 2 + 1] = 3.5 + dy * (k + 2 - log) as f64;
    }
    for k in log..nf {
        sc.future_valid[nf + k] = false;
    }
    sc
}
