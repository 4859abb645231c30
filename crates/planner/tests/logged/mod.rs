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
