//! [`Reel`]: everything an animation of one closed-loop run draws, frame by frame, built from
//! a traced run ([`Reel::from_run`]) or handed in (from Python) and checked
//! ([`Reel::validate`]).

use nudge_planner::{BindingVehicle, Scenario, StepStatus, motion_heading};
use nudge_predictor::T_OBS;
use nudge_sim::RunRecord;

use super::error::AnimateError;

/// Largest vehicle length or width a reel may hold (m).
pub const MAX_VEHICLE_M: f64 = 100.0;

/// Most frames a reel may hold: the states of the longest run
/// ([`nudge_sim::SimConfig::MAX_STEPS`] steps, plus the end).
pub const MAX_SHOTS: usize = nudge_sim::SimConfig::MAX_STEPS + 1;

/// What one planning step planned and expected (drawn on the frame of the state it planned
/// from).
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedStep {
    /// How the applied plan came about.
    pub status: StepStatus,
    /// Wall time of the planning call (s).
    pub mpc_s: f64,
    /// The plan z_0..z_T as (x, y, ψ, v) (m, m, rad, m/s), `[T + 1]`, z_0 = the state it
    /// starts from.
    pub plan: Vec<[f64; 4]>,
    /// The planning predictor's predicted positions (m) of agents 1..n at plan steps 1..T
    /// given the plan, `[n − 1][T]`.
    pub predicted: Vec<Vec<[f64; 2]>>,
    /// The vehicle the plan's safety binds on, with its ellipses' semi-axes `[T]` (m).
    pub binding: Option<BindingVehicle>,
}

/// One frame: the state of the run before a planning step (or after the last one).
#[derive(Debug, Clone, PartialEq)]
pub struct Shot {
    /// Every agent as (x, y, heading) (m, m, rad), `[n]`, agent 0 = the ego.
    pub agents: Vec<[f64; 3]>,
    /// The ego's speed (m/s).
    pub ego_speed: f64,
    /// The ego's box overlapped another vehicle's in this state.
    pub collision: bool,
    /// The step planned from this state; `None` on the frame after the last step.
    pub planned: Option<PlannedStep>,
}

/// One run to animate: the road, the vehicles' sizes and one [`Shot`] per state, in order
/// (the states before steps 0..S and the state after the last step: S + 1 shots).
#[derive(Debug, Clone, PartialEq)]
pub struct Reel {
    /// A title line for the caption (scenario, predictors, outcome).
    pub title: String,
    /// Lane-boundary y, ascending, the road edges first and last, `[L + 1]` (m).
    pub lane_bounds: Vec<f64>,
    /// (length, width) of every agent, `[n]` (m).
    pub sizes: Vec<[f64; 2]>,
    /// The frames.
    pub shots: Vec<Shot>,
}

impl Reel {
    /// The reel of `rec`, a run of scenario `sc` simulated with tracing on
    /// ([`nudge_sim::RunControl::trace`]): the first shot is the scene's last observed
    /// state, each later one the state after a step; the others' headings are read off their
    /// motion ([`motion_heading`]).
    ///
    /// # Errors
    /// [`AnimateError::NoTrace`] when a step carries no trace; [`AnimateError::Invalid`] when
    /// the record does not fit the scene ([`Reel::validate`]).
    pub fn from_run(sc: &Scenario, rec: &RunRecord) -> Result<Self, AnimateError> {
        let n = sc.n_agents;
        let first: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                let p = sc.position(i, T_OBS - 1);
                [p[0], p[1], sc.heading[i]]
            })
            .collect();
        let mut shots = vec![Shot {
            agents: first,
            ego_speed: sc.speed[0],
            collision: false,
            planned: None,
        }];
        for (k, step) in rec.steps.iter().enumerate() {
            let trace = step.trace.as_ref().ok_or_else(|| AnimateError::NoTrace {
                scene: rec.scenario.clone(),
                step: k,
            })?;
            if trace.agents.len() != n {
                return Err(invalid(
                    k + 1,
                    "agents",
                    format!("{} agents, the scene has {n}", trace.agents.len()),
                ));
            }
            let last = shots.len() - 1;
            shots[last].planned = Some(PlannedStep {
                status: step.status,
                mpc_s: step.mpc_s,
                plan: trace.plan.clone(),
                predicted: trace.predicted.clone(),
                binding: trace.binding.clone(),
            });
            let previous = &shots[last].agents;
            let mut agents: Vec<[f64; 3]> = trace
                .agents
                .iter()
                .zip(previous)
                .map(|(p, q)| [p[0], p[1], motion_heading([q[0], q[1]], *p, q[2])])
                .collect();
            agents[0] = [step.ego[0], step.ego[1], step.ego[2]];
            shots.push(Shot {
                agents,
                ego_speed: step.ego[3],
                collision: step.collision,
                planned: None,
            });
        }
        let reel = Self {
            title: title(rec),
            lane_bounds: sc.lane_bounds.clone(),
            sizes: sc.size.clone(),
            shots,
        };
        reel.validate()?;
        Ok(reel)
    }

    /// Checks that the reel can be drawn: at least one lane (two ascending finite bounds), at
    /// least one agent, every length and width in (0, [`MAX_VEHICLE_M`]] m, 1..=[`MAX_SHOTS`] shots, and in every shot one
    /// finite (x, y, heading) per agent, a finite speed, and for a planned step a finite plan
    /// of T + 1 ≥ 2 states, finite predictions `[n − 1][T]`, a binding vehicle among agents
    /// 1..n with T positive finite semi-axes and its step below T, a finite non-negative
    /// planning time.
    ///
    /// # Errors
    /// [`AnimateError::Invalid`] naming the first frame and field at fault.
    pub fn validate(&self) -> Result<(), AnimateError> {
        let road = |reason: &str| invalid_item("lane_bounds", reason.to_string());
        if self.lane_bounds.len() < 2 {
            return Err(road("needs at least 2 bounds (one lane)"));
        }
        if !self.lane_bounds.iter().all(|y| y.is_finite())
            || self.lane_bounds.windows(2).any(|w| w[1] <= w[0])
        {
            return Err(road("must be finite and strictly ascending"));
        }
        let n = self.sizes.len();
        if n == 0 {
            return Err(invalid_item("sizes", "no agent".into()));
        }
        if let Some(i) = self
            .sizes
            .iter()
            .position(|s| !s.iter().all(|v| *v > 0.0 && *v <= MAX_VEHICLE_M))
        {
            return Err(invalid_item(
                "sizes",
                format!("agent {i}: length and width must be in (0, {MAX_VEHICLE_M}] m"),
            ));
        }
        if self.shots.is_empty() || self.shots.len() > MAX_SHOTS {
            return Err(invalid_item(
                "shots",
                format!("{} frames, expected 1..={MAX_SHOTS}", self.shots.len()),
            ));
        }
        for (k, shot) in self.shots.iter().enumerate() {
            shot.validate(k, n)?;
        }
        Ok(())
    }
}

impl Shot {
    /// [`Reel::validate`] of frame `k` of a reel with `n` agents.
    fn validate(&self, k: usize, n: usize) -> Result<(), AnimateError> {
        if self.agents.len() != n {
            return Err(invalid(
                k,
                "agents",
                format!("{} agents, the reel has {n} sizes", self.agents.len()),
            ));
        }
        if let Some(i) = self.agents.iter().position(|a| !finite(a)) {
            return Err(invalid(k, "agents", format!("agent {i} is not finite")));
        }
        if !self.ego_speed.is_finite() {
            return Err(invalid(k, "speed", "not finite".into()));
        }
        match &self.planned {
            Some(p) => p.validate(k, n),
            None => Ok(()),
        }
    }
}

impl PlannedStep {
    /// [`Reel::validate`] of the planned step of frame `k` of a reel with `n` agents.
    fn validate(&self, k: usize, n: usize) -> Result<(), AnimateError> {
        if self.plan.len() < 2 || !self.plan.iter().all(|z| finite(z)) {
            return Err(invalid(
                k,
                "plan",
                format!(
                    "needs T + 1 ≥ 2 finite states, got {} (or a non-finite one)",
                    self.plan.len()
                ),
            ));
        }
        let t = self.plan.len() - 1;
        if self.predicted.len() != n - 1 {
            return Err(invalid(
                k,
                "predicted",
                format!(
                    "{} agents, expected n − 1 = {}",
                    self.predicted.len(),
                    n - 1
                ),
            ));
        }
        if let Some(i) = self
            .predicted
            .iter()
            .position(|p| p.len() != t || !p.iter().all(|q| finite(q)))
        {
            return Err(invalid(
                k,
                "predicted",
                format!("agent {}: expected {t} finite positions", i + 1),
            ));
        }
        if !(self.mpc_s.is_finite() && self.mpc_s >= 0.0) {
            return Err(invalid(
                k,
                "mpc_s",
                format!("{} is not a finite time ≥ 0", self.mpc_s),
            ));
        }
        let Some(b) = &self.binding else {
            return Ok(());
        };
        if !(1..n).contains(&b.agent) || b.step >= t {
            return Err(invalid(
                k,
                "binding",
                format!(
                    "agent {} step {} outside agents 1..{n}, steps 0..{t}",
                    b.agent, b.step
                ),
            ));
        }
        if b.semi_axes.len() != t
            || !b
                .semi_axes
                .iter()
                .all(|a| a.iter().all(|v| v.is_finite() && *v > 0.0))
        {
            return Err(invalid(
                k,
                "semi_axes",
                format!("expected {t} positive finite (a_x, a_y)"),
            ));
        }
        if b.b.is_nan() {
            return Err(invalid(k, "binding_b", "NaN".into()));
        }
        Ok(())
    }
}

/// Every component finite.
fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// The error for `field` of frame `k`.
fn invalid(k: usize, field: &str, reason: String) -> AnimateError {
    invalid_item(&format!("frame {k} {field}"), reason)
}

/// The error for `item`.
fn invalid_item(item: &str, reason: String) -> AnimateError {
    AnimateError::Invalid {
        item: item.to_string(),
        reason,
    }
}

/// "scene · predictor in world · lane change to y = … m: outcome".
fn title(rec: &RunRecord) -> String {
    let outcome = if rec.collision {
        "collision".to_string()
    } else if let Some(s) = rec.steps_to_target {
        format!("in the target lane after {s} steps")
    } else {
        "not in the target lane".to_string()
    };
    format!(
        "{} seed {}: {} planner, {} world, target y {:.1} m: {outcome}",
        rec.scenario, rec.seed, rec.predictor, rec.world, rec.y_target
    )
}
