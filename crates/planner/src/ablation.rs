//! The reaction ablation (`PlannerSettings::ablate_reaction`): the path the planner's
//! predictor sees instead of each candidate, so that the predicted traffic cannot depend on
//! the ego's plan.

use crate::admm::EgoState;

/// The ego's keep-lane path `[T, 2]` (flattened x, y per step; road frame, m): the ego at its
/// measured speed along the road on its measured lateral position, x_k = x_0 + k·dt·v_0,
/// y_k = y_0 for k = 1..=`horizon` (`dt` in s, `ego` the measured state; its heading is
/// ignored). The candidate format of [`nudge_predictor::Predictor::predict`].
#[must_use]
pub fn keep_lane_path(ego: &EgoState, horizon: usize, dt: f64) -> Vec<f64> {
    (1..=horizon)
        .flat_map(|k| [ego.x + k as f64 * dt * ego.v, ego.y])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keep_lane_path_is_constant_speed_in_the_lane() {
        let ego = EgoState {
            x: 10.0,
            y: -1.5,
            psi: 0.1,
            v: 12.0,
        };
        let p = keep_lane_path(&ego, 3, 0.3);
        let want = [13.6, -1.5, 17.2, -1.5, 20.8, -1.5];
        assert_eq!(p.len(), want.len());
        for (a, b) in p.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{p:?}");
        }
    }
}
