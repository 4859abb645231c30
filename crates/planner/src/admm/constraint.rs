//! The safety constraint b_i of one MPC call: which vehicles are checked, and b for the ego
//! at a position and heading against one of them at its (predicted or observed) position.
//! The planner evaluates it on every trial point ([`SafetyEval`]); the closed-loop simulator
//! evaluates the very same function on the executed step
//! ([`SafetyConstraint::executed_min_b`]).

use nudge_predictor::{Predictor, T_OBS};

use crate::error::PlannerError;
use crate::model::State;
use crate::safety::{Ellipse, motion_direction};
use crate::settings::PlannerSettings;

use super::problem::PlanningProblem;

/// One vehicle the safety constraint checks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckedVehicle {
    /// Agent index (≥ 1).
    pub index: usize,
    /// (length, width) (m).
    pub size: [f64; 2],
    /// Last observed position (m, road frame).
    pub last: [f64; 2],
    /// (|cos ψ|, |sin ψ|) of its last observed motion ([`motion_direction`], heading 0 when it
    /// barely moved): its heading wherever a later motion is too short to read one from.
    pub direction: [f64; 2],
}

/// The safety constraint of one MPC call: the vehicles within `check_range` of the ego's
/// measured position, and the ellipse b_i of [`Ellipse::oriented`] sized by both vehicles'
/// bounding boxes at their headings (the ego's from its heading ψ, the other's from the
/// direction of its motion since the previous step).
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyConstraint {
    vehicles: Vec<CheckedVehicle>,
    ego_size: [f64; 2],
    scale: f64,
    margins: [f64; 2],
}

impl SafetyConstraint {
    /// The constraint of `problem` (checked with [`PlanningProblem::check`]) under `settings`.
    #[must_use]
    pub fn new(problem: &PlanningProblem<'_>, settings: &PlannerSettings) -> Self {
        let origin = [problem.ego.x, problem.ego.y];
        let mut vehicles = Vec::new();
        for i in 1..problem.history.n_agents() {
            let p = problem.history.at(i, T_OBS - 1);
            let d = ((p[0] - origin[0]).powi(2) + (p[1] - origin[1]).powi(2)).sqrt();
            if d <= settings.check_range {
                let q = problem.history.at(i, T_OBS - 2);
                vehicles.push(CheckedVehicle {
                    index: i,
                    size: problem.sizes[i],
                    last: [p[0], p[1]],
                    direction: motion_direction([q[0], q[1]], [p[0], p[1]], [1.0, 0.0]),
                });
            }
        }
        Self {
            vehicles,
            ego_size: problem.sizes[0],
            scale: settings.ellipse_scale,
            margins: [settings.margin_x, settings.margin_y],
        }
    }

    /// The checked vehicles, in agent order.
    #[must_use]
    pub fn vehicles(&self) -> &[CheckedVehicle] {
        &self.vehicles
    }

    /// The ellipse around `vehicle` at `other` (m), which was at `previous` one step earlier,
    /// for an ego whose heading has direction `ego_direction` = (|cos ψ|, |sin ψ|).
    #[must_use]
    pub fn ellipse(
        &self,
        vehicle: &CheckedVehicle,
        ego_direction: [f64; 2],
        previous: [f64; 2],
        other: [f64; 2],
    ) -> Ellipse {
        Ellipse::oriented(
            self.ego_size,
            ego_direction,
            vehicle.size,
            motion_direction(previous, other, vehicle.direction),
            self.scale,
            self.margins[0],
            self.margins[1],
        )
    }

    /// The minimum b_i over the checked vehicles at the step the vehicles actually drove: the
    /// ego at `ego` = (x, y, ψ) (m, m, rad) and every agent at `positions[agent]` (m, agent 0
    /// unused), each having moved from its last observed position. This is the value the
    /// constraint gives step 1 of a candidate equal to that motion. `None` when no vehicle is
    /// checked; −∞ when b is NaN.
    #[must_use]
    pub fn executed_min_b(&self, ego: [f64; 3], positions: &[[f64; 2]]) -> Option<f64> {
        if self.vehicles.is_empty() {
            return None;
        }
        let ego_direction = heading_direction(ego[2]);
        let min_b = self
            .vehicles
            .iter()
            .map(|v| {
                let other = positions[v.index];
                self.ellipse(v, ego_direction, v.last, other)
                    .value([ego[0], ego[1]], other)
            })
            .fold(f64::INFINITY, min_or_nan);
        Some(never_nan(min_b))
    }
}

/// (|cos ψ|, |sin ψ|).
fn heading_direction(psi: f64) -> [f64; 2] {
    let (sn, cs) = psi.sin_cos();
    [cs.abs(), sn.abs()]
}

/// The minimum of `a` and `b`, NaN when either is (`f64::min` would drop a NaN `b`).
fn min_or_nan(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.min(b)
    }
}

/// A NaN minimum is never safe: −∞.
fn never_nan(min_b: f64) -> f64 {
    if min_b.is_nan() {
        f64::NEG_INFINITY
    } else {
        min_b
    }
}

/// b over a candidate: min b_i and the total violation Σ max(0, threshold − b).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Evaluation {
    /// Minimum b over checked vehicles and steps (`None` when none is checked).
    pub min_b: Option<f64>,
    /// Σ (threshold − b) over the pairs with b ≤ threshold.
    pub violation: f64,
}

impl Evaluation {
    /// Safe at `threshold`: nothing checked, or min b > threshold.
    pub(crate) fn is_safe(&self, threshold: f64) -> bool {
        self.min_b.is_none_or(|b| b > threshold)
    }
}

/// Runs the predictor on candidate states and evaluates the constraint at every checked
/// vehicle and step, counting predictor calls. Buffers are allocated once per call.
pub(crate) struct SafetyEval<'c> {
    constraint: &'c SafetyConstraint,
    origin: [f64; 2],
    horizon: usize,
    /// The Z-update's threshold b_min (safety_min + plan_buffer) for the violation.
    threshold: f64,
    /// Ego candidate `[T, 2]` in the road frame (m).
    candidate: Vec<f64>,
    /// Prediction `[n − 1, T, 2]` (m).
    prediction: Vec<f64>,
    /// (|cos ψ_k|, |sin ψ_k|) of the candidate, per step.
    ego_direction: Vec<[f64; 2]>,
    /// ∂(total violation)/∂(x_k, y_k) at the last evaluated point, prediction and ellipse
    /// sizes frozen.
    pub violation_gradient: Vec<[f64; 2]>,
    /// Predictor calls so far.
    pub calls: usize,
}

impl<'c> SafetyEval<'c> {
    /// An evaluator of `constraint` for candidates in the frame centred at `origin`.
    pub(crate) fn new(
        constraint: &'c SafetyConstraint,
        origin: [f64; 2],
        horizon: usize,
        n_agents: usize,
        threshold: f64,
    ) -> Self {
        Self {
            constraint,
            origin,
            horizon,
            threshold,
            candidate: vec![0.0; horizon * 2],
            prediction: vec![0.0; n_agents.saturating_sub(1) * horizon * 2],
            ego_direction: vec![[1.0, 0.0]; horizon],
            violation_gradient: vec![[0.0; 2]; horizon],
            calls: 0,
        }
    }

    /// The threshold of the violation (b_min).
    pub(crate) fn threshold(&self) -> f64 {
        self.threshold
    }

    /// Evaluates the candidate states `z` (`[T]`, this call's frame); no predictor call when
    /// nothing is checked.
    pub(crate) fn eval(
        &mut self,
        predictor: &mut dyn Predictor,
        z: &[State],
    ) -> Result<Evaluation, PlannerError> {
        let checked = self.constraint.vehicles();
        if checked.is_empty() {
            return Ok(Evaluation {
                min_b: None,
                violation: 0.0,
            });
        }
        let t = self.horizon;
        for (k, zk) in z.iter().enumerate().take(t) {
            self.candidate[2 * k] = zk[0] + self.origin[0];
            self.candidate[2 * k + 1] = zk[1] + self.origin[1];
            self.violation_gradient[k] = [0.0; 2];
            self.ego_direction[k] = heading_direction(zk[2]);
        }
        predictor.predict(&self.candidate, &mut self.prediction)?;
        self.calls += 1;
        let mut min_b = f64::INFINITY;
        let mut violation = 0.0;
        for v in checked {
            let base = (v.index - 1) * t * 2;
            let mut previous = v.last;
            for k in 0..t {
                let ego = [self.candidate[2 * k], self.candidate[2 * k + 1]];
                let other = [
                    self.prediction[base + 2 * k],
                    self.prediction[base + 2 * k + 1],
                ];
                let ellipse = self
                    .constraint
                    .ellipse(v, self.ego_direction[k], previous, other);
                previous = other;
                let b = ellipse.value(ego, other);
                min_b = min_or_nan(min_b, b);
                if b <= self.threshold {
                    violation += self.threshold - b;
                    let g = ellipse.gradient(ego, other);
                    self.violation_gradient[k][0] -= g[0];
                    self.violation_gradient[k][1] -= g[1];
                }
            }
        }
        if min_b.is_nan() {
            return Ok(Evaluation {
                min_b: Some(f64::NEG_INFINITY),
                violation: f64::INFINITY,
            });
        }
        Ok(Evaluation {
            min_b: Some(min_b),
            violation,
        })
    }
}
