//! The interaction-unaware baseline.

use crate::error::{PredictorError, Result};
use crate::{History, Predictor, T_OBS, check_batch};

/// Constant-velocity prediction: every other agent keeps its last observed displacement per
/// step, whatever the ego does. Ignores the candidates except for their shape.
#[derive(Debug, Clone)]
pub struct ConstantVelocity {
    horizon: usize,
    /// `[n_agents - 1, horizon, 2]` prediction of the current scene (candidate-independent).
    cached: Vec<f64>,
    n_agents: usize,
}

impl ConstantVelocity {
    /// A baseline with prediction horizon `horizon` steps.
    #[must_use]
    pub fn new(horizon: usize) -> Self {
        Self {
            horizon,
            cached: Vec::new(),
            n_agents: 0,
        }
    }
}

impl Default for ConstantVelocity {
    fn default() -> Self {
        Self::new(6)
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
        self.n_agents = n;
        self.cached.clear();
        for a in 1..n {
            let last = history.at(a, T_OBS - 1);
            let prev = history.at(a, T_OBS - 2);
            let v = [last[0] - prev[0], last[1] - prev[1]];
            for k in 1..=self.horizon {
                let s = k as f64;
                self.cached.push(last[0] + s * v[0]);
                self.cached.push(last[1] + s * v[1]);
            }
        }
        Ok(())
    }

    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> Result<()> {
        if self.n_agents == 0 {
            return Err(PredictorError::NoScene);
        }
        let batch = check_batch(candidates, out, self.horizon, self.n_agents)?;
        let per = self.cached.len();
        for b in 0..batch {
            out[b * per..(b + 1) * per].copy_from_slice(&self.cached);
        }
        Ok(())
    }
}
