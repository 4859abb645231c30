//! Accepted input ranges, the plausibility bound on predictions, and the load-time self-check.
//!
//! The networks run in f32 on differences of f64 positions (displacements, offsets between
//! agents; see the crate documentation). Inputs beyond the ranges below are refused with
//! [`PredictorError::InputOutOfRange`] stating the range; predictions that are non-finite or
//! move an agent farther than [`MAX_STEP`] in one step are refused with
//! [`PredictorError::NonFiniteOutput`] / [`PredictorError::ImplausibleOutput`]. Every
//! predictor (teacher, student, constant velocity) applies the same checks, so the planner
//! never sees a prediction it cannot trust.
//!
//! How the ranges were chosen (`cargo run --release -p nudge-predictor --example input_range`,
//! shipped and golden random weights, a 5-agent highway scene, f32 fast path against the f64
//! [`reference`](crate::reference)):
//!
//! | quantity | finite up to | agrees with the f64 reference to ≤ 1e-5 m up to | accepted | real scenes (7,590) |
//! |---|---|---|---|---|
//! | coordinate \|x\|, \|y\| (all agents shifted) | 1e300 (but the translation error is 3e-6 m at 1e10, 0.2 m at 1e15) | 1e9 (translation error 5e-7 m) | [`MAX_ABS_POSITION`] = 1e6 m (error 5e-11 m) | ≤ 262 m |
//! | displacement per 0.3 s step | 1e300 (saturating gates) | 2e3 m (student: 2.7e-5 m at 5e3) | history: [`MAX_STEP`] = 30 m (100 m/s); ego candidates: [`MAX_CANDIDATE_STEP`] = 1 km | ≤ 8.9 m |
//! | distance between agents | 1e38 (student NaN from 1e39: f32 overflow) | 2e3 m (teacher: 2.9e-5 m at 1e4, student 1.3e-3 m at 1e6) | [`MAX_AGENT_OFFSET`] = 1,000 m | ≤ 120 m |
//!
//! The accepted ranges of observed input are the physical ones (no road vehicle covers 30 m in
//! 0.3 s; nudge scenes keep neighbours within 60 m of the ego), well inside what the networks
//! represent. Ego candidates are the planner's trial points, whose steps may overshoot while it
//! optimises: they are bounded by the representable range only. During `predict` the ego
//! candidate's distance to the other agents then stays far inside the finite range (< 1e38 m);
//! the reference agreement is ≤ 7e-6 m up to 5 km (6 steps at 30 m plus 1 km apart: 1.36 km).
//!
//! Predictions use the same bound: an agent whose predicted position moves more than
//! [`MAX_STEP`] in one step (from its last observed position for step 1) is implausible. The
//! shipped networks move agents at most about 9 m per step on real scenes.

use std::path::Path;

use crate::error::{PredictorError, Quantity, Result};
use crate::{History, Predictor, T_OBS};

/// Largest accepted |x| or |y| of any position, history or candidate (m). At this magnitude
/// f64 differences are exact to 1.2e-10 m.
pub const MAX_ABS_POSITION: f64 = 1e6;
/// Largest distance an agent may move in one 0.3 s step (m), observed (history) or predicted:
/// 30 m per step is 100 m/s (360 km/h).
pub const MAX_STEP: f64 = 30.0;
/// Largest distance the ego may move in one step of a candidate (m). Candidates are the
/// planner's hypothetical trial points, not observed motion, so this is the networks'
/// representable range (agreement with the f64 reference ≤ 6e-6 m at 1 km per step), not a
/// physical bound: an optimiser step that overshoots gets a prediction, not an error. ADMM's
/// trial points can still overshoot it (by 1.05 km in one step on a train-split closed-loop
/// run with `heading_max` 0.15): the planner checks every candidate with
/// [`check_candidates`] first and judges one beyond it unsafe without a prediction.
pub const MAX_CANDIDATE_STEP: f64 = 1000.0;
/// Largest distance between two agents at the last observed step (m).
pub const MAX_AGENT_OFFSET: f64 = 1000.0;
/// Largest accepted |z| of a noise component (standard-normal units; a draw beyond 100
/// standard deviations is not noise).
pub const MAX_NOISE: f64 = 100.0;

fn out_of_range(
    what: &'static str,
    quantity: Quantity,
    location: String,
    value: f64,
    max: f64,
) -> PredictorError {
    PredictorError::InputOutOfRange {
        what,
        quantity,
        location,
        value,
        max,
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Squared distance (cheap; `hypot` only for messages).
fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (a[0] - b[0], a[1] - b[1]);
    dx * dx + dy * dy
}

/// Checks a finite `[n, T_OBS, 2]` history: coordinates, per-step displacements, distances
/// between agents at the last observed step.
pub(crate) fn check_history(positions: &[f64], n: usize) -> Result<()> {
    let at = |a: usize, t: usize| {
        let k = (a * T_OBS + t) * 2;
        [positions[k], positions[k + 1]]
    };
    for a in 0..n {
        for t in 0..T_OBS {
            let p = at(a, t);
            let m = p[0].abs().max(p[1].abs());
            if m > MAX_ABS_POSITION {
                return Err(out_of_range(
                    "history",
                    Quantity::Coordinate,
                    format!("agent {a}, observed step {t}"),
                    m,
                    MAX_ABS_POSITION,
                ));
            }
            if t > 0 && dist2(p, at(a, t - 1)) > MAX_STEP * MAX_STEP {
                return Err(out_of_range(
                    "history",
                    Quantity::StepDisplacement,
                    format!("agent {a}, observed steps {} to {t}", t - 1),
                    dist(p, at(a, t - 1)),
                    MAX_STEP,
                ));
            }
        }
    }
    for i in 0..n {
        for j in i + 1..n {
            let (p, q) = (at(i, T_OBS - 1), at(j, T_OBS - 1));
            if dist2(p, q) > MAX_AGENT_OFFSET * MAX_AGENT_OFFSET {
                return Err(out_of_range(
                    "history",
                    Quantity::AgentOffset,
                    format!("agents {i} and {j} at the last observed step"),
                    dist(p, q),
                    MAX_AGENT_OFFSET,
                ));
            }
        }
    }
    Ok(())
}

/// Checks finite candidates `[batch, horizon, 2]`: coordinates and per-step displacements,
/// step 1 measured from the ego's last observed position `ego_last` (m). Every predictor runs
/// this on its input; a caller may run it first to keep a trial point the predictors would
/// refuse away from them.
///
/// # Errors
/// [`PredictorError::InputOutOfRange`] naming the candidate and step: a coordinate beyond
/// [`MAX_ABS_POSITION`] or a step longer than [`MAX_CANDIDATE_STEP`].
pub fn check_candidates(candidates: &[f64], horizon: usize, ego_last: [f64; 2]) -> Result<()> {
    for (b, cand) in candidates.chunks_exact(2 * horizon).enumerate() {
        let mut prev = ego_last;
        for (k, p) in cand.chunks_exact(2).enumerate() {
            let p = [p[0], p[1]];
            let m = p[0].abs().max(p[1].abs());
            if m > MAX_ABS_POSITION {
                return Err(out_of_range(
                    "candidates",
                    Quantity::Coordinate,
                    format!("candidate {b}, step {}", k + 1),
                    m,
                    MAX_ABS_POSITION,
                ));
            }
            if dist2(p, prev) > MAX_CANDIDATE_STEP * MAX_CANDIDATE_STEP {
                return Err(out_of_range(
                    "candidates",
                    Quantity::StepDisplacement,
                    format!("candidate {b}, step {}", k + 1),
                    dist(p, prev),
                    MAX_CANDIDATE_STEP,
                ));
            }
            prev = p;
        }
    }
    Ok(())
}

/// Checks a finite noise vector.
pub(crate) fn check_noise(z: &[f64]) -> Result<()> {
    if let Some((i, v)) = z.iter().enumerate().find(|(_, v)| v.abs() > MAX_NOISE) {
        return Err(out_of_range(
            "noise",
            Quantity::Noise,
            format!("component {i}"),
            v.abs(),
            MAX_NOISE,
        ));
    }
    Ok(())
}

/// Checks the predictions of one candidate: `out` is `[n - 1, horizon, 2]` (agents 1..n),
/// `last` the last observed positions `[n, 2]`. Every position must be finite and at most
/// [`MAX_STEP`] from the agent's previous one.
pub(crate) fn check_output(
    predictor: &'static str,
    candidate: usize,
    last: &[f64],
    out: &[f64],
    horizon: usize,
) -> Result<()> {
    let max2 = MAX_STEP * MAX_STEP;
    for (i, traj) in out.chunks_exact(2 * horizon).enumerate() {
        let agent = i + 1;
        let mut prev = [last[2 * agent], last[2 * agent + 1]];
        for (k, p) in traj.chunks_exact(2).enumerate() {
            let step = k + 1;
            if let Some(&value) = p.iter().find(|v| !v.is_finite()) {
                return Err(PredictorError::NonFiniteOutput {
                    predictor,
                    candidate,
                    agent,
                    step,
                    value,
                });
            }
            let (dx, dy) = (p[0] - prev[0], p[1] - prev[1]);
            if dx * dx + dy * dy > max2 {
                return Err(PredictorError::ImplausibleOutput {
                    predictor,
                    candidate,
                    agent,
                    step,
                    displacement: dx.hypot(dy),
                    max: MAX_STEP,
                });
            }
            prev = [p[0], p[1]];
        }
    }
    Ok(())
}

/// `(x, y, metres per step)` of the canonical scene's agents at the last observed step, ego
/// first: a three-lane highway at 22–27 m/s with neighbours ahead, behind and on both sides.
const CANONICAL: [(f64, f64, f64); 5] = [
    (0.0, 0.0, 7.5),
    (25.0, 0.0, 7.0),
    (-20.0, 0.0, 8.0),
    (10.0, 3.7, 7.2),
    (-5.0, -3.7, 7.8),
];

/// The canonical scene of the load-time self-check: five agents on a three-lane highway at
/// 22–27 m/s with neighbours ahead, behind and on both sides (constant speeds), and four ego
/// candidates `[4, horizon, 2]` (keep lane, change left, change right, brake).
#[must_use]
pub fn canonical_scene(horizon: usize) -> (History, Vec<f64>) {
    let mut pos = Vec::with_capacity(CANONICAL.len() * T_OBS * 2);
    for &(x, y, v) in &CANONICAL {
        for t in 0..T_OBS {
            pos.push(x - v * (T_OBS - 1 - t) as f64);
            pos.push(y);
        }
    }
    let v = CANONICAL[0].2;
    let mut cand = Vec::with_capacity(4 * horizon * 2);
    for (lat, brake) in [(0.0, 0.0), (0.6, 0.0), (-0.6, 0.0), (0.0, 0.1)] {
        for k in 1..=horizon {
            let s = k as f64;
            cand.push(v * s - brake * s * s);
            cand.push(lat * s);
        }
    }
    let history = History {
        positions: pos,
        n_agents: CANONICAL.len(),
    };
    (history, cand)
}

/// Runs `p` on the canonical scene and checks its predictions (every predictor does on every
/// `predict`); a failure names `path`. Leaves `p` with the canonical scene set.
pub(crate) fn self_check(p: &mut dyn Predictor, path: &Path) -> Result<()> {
    let (history, cand) = canonical_scene(p.horizon());
    let n = history.n_agents();
    let mut out = vec![0.0; cand.len() / 2 * (n - 1) * 2];
    p.set_scene(&history)
        .and_then(|()| p.predict(&cand, &mut out))
        .map_err(|e| PredictorError::SelfCheck {
            path: path.to_path_buf(),
            source: Box::new(e),
        })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn output_check_names_candidate_agent_and_step() {
        // 3 agents, horizon 2: last positions, then agent 2's step 2 is NaN.
        let last = [0.0, 0.0, 10.0, 0.0, 20.0, 0.0];
        let mut out = vec![17.0, 0.0, 24.0, 0.0, 27.0, 0.0, 34.0, 0.0];
        check_output("student", 3, &last, &out, 2).unwrap();
        out[7] = f64::NAN;
        match check_output("student", 3, &last, &out, 2) {
            Err(PredictorError::NonFiniteOutput {
                predictor: "student",
                candidate: 3,
                agent: 2,
                step: 2,
                value,
            }) => assert!(value.is_nan()),
            other => panic!("{other:?}"),
        }
        // Agent 1 jumping 30.5 m at step 1.
        out[7] = 0.0;
        out[0] = 40.5;
        match check_output("teacher", 0, &last, &out, 2) {
            Err(PredictorError::ImplausibleOutput {
                agent: 1,
                step: 1,
                displacement,
                ..
            }) => assert!((displacement - 30.5).abs() < 1e-12),
            other => panic!("{other:?}"),
        }
        // Exactly MAX_STEP is accepted.
        out[0] = 40.0;
        check_output("teacher", 0, &last, &out, 2).unwrap();
    }

    #[test]
    fn canonical_scene_is_inside_every_range() {
        for horizon in [1, 6, crate::MAX_HORIZON] {
            let (h, c) = canonical_scene(horizon);
            check_history(h.positions(), h.n_agents()).unwrap();
            check_candidates(&c, horizon, h.at(0, T_OBS - 1)).unwrap();
        }
    }
}
