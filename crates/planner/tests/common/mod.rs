//! Set-ups shared by the planner's integration tests: a straight two-lane road (lanes at
//! y = 0 and 3.7 m, edges at −1.85 and 5.55 m) with agents driving along +x.

use nudge_planner::{EgoState, PlanningProblem};
use nudge_predictor::{History, T_OBS};

/// The observed history of agents `(x, y, speed)` (m, m, m/s) along +x at constant speed,
/// agent 0 the ego, each at (x, y) at the last observed step (steps 0.3 s apart), and their
/// sizes (4.5 m × 1.9 m each).
pub fn scene(agents: &[(f64, f64, f64)]) -> (History, Vec<[f64; 2]>) {
    let mut pos = Vec::new();
    for &(x, y, v) in agents {
        for t in 0..T_OBS {
            pos.extend([x - v * (T_OBS - 1 - t) as f64 * 0.3, y]);
        }
    }
    (
        History::new(pos, agents.len()).expect("a valid history"),
        vec![[4.5, 1.9]; agents.len()],
    )
}

/// The planning problem of the ego at (0, 0) heading along the road at 12 m/s (also the
/// reference speed) towards the lane centre `y_target` (m), starting from zero inputs.
pub fn problem<'a>(h: &'a History, sizes: &'a [[f64; 2]], y_target: f64) -> PlanningProblem<'a> {
    PlanningProblem {
        ego: EgoState {
            x: 0.0,
            y: 0.0,
            psi: 0.0,
            v: 12.0,
        },
        last_delta: 0.0,
        last_accel: 0.0,
        history: h,
        sizes,
        y_target,
        v_ref: 12.0,
        road: [-1.85, 5.55],
        y_retreat: None,
        lanes: None,
    }
}
