//! [`Checked`]: any [`Predictor`] with this crate's output checks applied to every prediction.
//!
//! The teacher, the student and the constant-velocity baseline check their own predictions
//! ([`limits`](crate::limits)); a predictor implemented elsewhere may not. Wrapping it in
//! [`Checked`] guarantees that a prediction handed on is finite and physically plausible (no
//! agent moves more than [`MAX_STEP`](crate::limits::MAX_STEP) in one step), or a
//! [`PredictorError::NonFiniteOutput`] / [`PredictorError::ImplausibleOutput`] naming the
//! predictor, the candidate, the agent and the step. The planner wraps every predictor it is
//! given, so nothing non-finite is ever evaluated as safe.

use crate::error::{PredictorError, Result};
use crate::{History, Predictor, T_OBS, limits};

/// A predictor whose every prediction is checked to be finite and plausible (see the module
/// documentation). Costs one pass over the output per [`Predictor::predict`].
pub struct Checked<'p> {
    inner: &'p mut dyn Predictor,
    /// Last observed positions `[n, 2]` of the scene set (m).
    last: Vec<f64>,
    n_agents: usize,
    scene: bool,
}

impl<'p> Checked<'p> {
    /// Wraps `inner`.
    pub fn new(inner: &'p mut dyn Predictor) -> Self {
        Self {
            inner,
            last: Vec::new(),
            n_agents: 0,
            scene: false,
        }
    }
}

impl Predictor for Checked<'_> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn horizon(&self) -> usize {
        self.inner.horizon()
    }

    fn set_scene(&mut self, history: &History) -> Result<()> {
        self.scene = false;
        self.inner.set_scene(history)?;
        let n = history.n_agents();
        self.last.clear();
        self.last
            .extend((0..n).flat_map(|a| history.at(a, T_OBS - 1)));
        self.n_agents = n;
        self.scene = true;
        Ok(())
    }

    /// Delegates, then checks `out` (`[batch, n − 1, horizon, 2]`, batch = candidates per
    /// `[horizon, 2]`): its length, and every position finite and within
    /// [`MAX_STEP`](crate::limits::MAX_STEP) of the agent's previous one (its last observed
    /// position for step 1).
    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> Result<()> {
        if !self.scene {
            return Err(PredictorError::NoScene);
        }
        self.inner.predict(candidates, out)?;
        let horizon = self.inner.horizon();
        let others = self.n_agents.saturating_sub(1);
        let per = others * horizon * 2;
        let batch = candidates.len() / (2 * horizon).max(1);
        if out.len() != batch * per {
            return Err(PredictorError::InputShape {
                what: "out",
                shape: format!("[{batch}, {others}, {horizon}, 2]"),
                expected: batch * per,
                got: out.len(),
            });
        }
        if per == 0 {
            return Ok(());
        }
        let name = self.inner.name();
        for (b, prediction) in out.chunks_exact(per).enumerate() {
            limits::check_output(name, b, &self.last, prediction, horizon)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::ConstantVelocity;

    /// Constant velocity with one value replaced.
    struct Poke(ConstantVelocity, usize, f64);

    impl Predictor for Poke {
        fn name(&self) -> &'static str {
            "poke"
        }
        fn horizon(&self) -> usize {
            self.0.horizon()
        }
        fn set_scene(&mut self, history: &History) -> Result<()> {
            self.0.set_scene(history)
        }
        fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> Result<()> {
            self.0.predict(candidates, out)?;
            out[self.1] = self.2;
            Ok(())
        }
    }

    #[test]
    fn checks_every_value_of_a_foreign_prediction() {
        let (history, cand) = limits::canonical_scene(6);
        let n = history.n_agents();
        let mut out = vec![0.0; 4 * (n - 1) * 6 * 2];
        // Untouched: passes, and equals the inner prediction.
        let mut honest = ConstantVelocity::new(6).unwrap();
        let mut want = out.clone();
        honest.set_scene(&history).unwrap();
        honest.predict(&cand, &mut want).unwrap();
        let mut inner = Poke(ConstantVelocity::new(6).unwrap(), 0, want[0]);
        let mut c = Checked::new(&mut inner);
        assert!(matches!(
            c.predict(&cand, &mut out),
            Err(PredictorError::NoScene)
        ));
        c.set_scene(&history).unwrap();
        c.predict(&cand, &mut out).unwrap();
        assert_eq!(out, want);
        // Candidate 2, agent 3, step 5, y: NaN, then 1e30.
        let at = 2 * (n - 1) * 12 + 2 * 12 + 4 * 2 + 1;
        for (value, non_finite) in [(f64::NAN, true), (1e30, false)] {
            let mut inner = Poke(ConstantVelocity::new(6).unwrap(), at, value);
            let mut c = Checked::new(&mut inner);
            c.set_scene(&history).unwrap();
            match c.predict(&cand, &mut out) {
                Err(PredictorError::NonFiniteOutput {
                    predictor: "poke",
                    candidate: 2,
                    agent: 3,
                    step: 5,
                    ..
                }) if non_finite => {}
                Err(PredictorError::ImplausibleOutput {
                    predictor: "poke",
                    candidate: 2,
                    agent: 3,
                    step: 5,
                    ..
                }) if !non_finite => {}
                other => panic!("{value}: {other:?}"),
            }
        }
    }
}
