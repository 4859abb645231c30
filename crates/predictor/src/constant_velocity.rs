//! The interaction-unaware baseline.

use crate::error::{PredictorError, Result};
use crate::{History, Predictor, T_OBS, check_batch, check_horizon, limits};

/// Constant-velocity prediction: every other agent keeps its last observed displacement per
/// step, whatever the ego does. Ignores the candidates except for their shape and range.
#[derive(Debug, Clone)]
pub struct ConstantVelocity {
    horizon: usize,
    /// `[n_agents - 1, horizon, 2]` prediction of the current scene (candidate-independent).
    cached: Vec<f64>,
    n_agents: usize,
    /// The ego's last observed position (m).
    ego_last: [f64; 2],
}

impl ConstantVelocity {
    /// A baseline with prediction horizon `horizon` steps (1..=[`crate::MAX_HORIZON`]).
    ///
    /// # Errors
    /// [`PredictorError::Horizon`] for 0 or a horizon above [`crate::MAX_HORIZON`].
    pub fn new(horizon: usize) -> Result<Self> {
        check_horizon(horizon)?;
        Ok(Self {
            horizon,
            cached: Vec::new(),
            n_agents: 0,
            ego_last: [0.0; 2],
        })
    }
}

impl Default for ConstantVelocity {
    /// The shipped horizon, 6 steps.
    fn default() -> Self {
        Self {
            horizon: 6,
            cached: Vec::new(),
            n_agents: 0,
            ego_last: [0.0; 2],
        }
    }
}

impl Predictor for ConstantVelocity {
    fn name(&self) -> &'static str {
        "constant_velocity"
    }

    fn horizon(&self) -> usize {
        self.horizon
    }

    fn set_scene(&mut self, history: &History) -> Result<()> {
        let n = history.n_agents();
        self.n_agents = 0;
        self.cached.clear();
        let mut last = Vec::with_capacity(2 * n);
        for a in 0..n {
            let p = history.at(a, T_OBS - 1);
            last.extend_from_slice(&p);
            if a == 0 {
                continue;
            }
            let prev = history.at(a, T_OBS - 2);
            let v = [p[0] - prev[0], p[1] - prev[1]];
            for k in 1..=self.horizon {
                let s = k as f64;
                self.cached.push(p[0] + s * v[0]);
                self.cached.push(p[1] + s * v[1]);
            }
        }
        // The prediction does not depend on the candidates: check it once here.
        limits::check_output(self.name(), 0, &last, &self.cached, self.horizon)?;
        self.ego_last = [last[0], last[1]];
        self.n_agents = n;
        Ok(())
    }

    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> Result<()> {
        if self.n_agents == 0 {
            return Err(PredictorError::NoScene);
        }
        let batch = check_batch(candidates, out, self.horizon, self.n_agents, self.ego_last)?;
        let per = self.cached.len();
        for b in 0..batch {
            out[b * per..(b + 1) * per].copy_from_slice(&self.cached);
        }
        Ok(())
    }
}
