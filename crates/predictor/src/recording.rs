//! The recording predictor used to collect distillation data: it delegates to an inner
//! predictor (the teacher) and keeps every distinct (history, candidate, prediction) the
//! planner asks for.

use std::collections::HashSet;

use crate::{History, Predictor, T_OBS};

/// Everything a [`Recording`] predictor saw, flat (float32, metres, road frame).
///
/// A *context* is one scene history the planner set (one MPC call); an *example* is one
/// candidate evaluated in a context with the inner predictor's output.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Records {
    /// Histories of every context, `[sum of agents, 8, 2]`.
    pub history: Vec<f32>,
    /// Agents (ego included) of each context `[C]`.
    pub context_agents: Vec<usize>,
    /// Context of each example `[E]`.
    pub example_context: Vec<usize>,
    /// Ego candidates `[E, horizon, 2]`.
    pub candidate: Vec<f32>,
    /// Predictions of the other agents `[sum over examples of (agents − 1), horizon, 2]`.
    pub prediction: Vec<f32>,
    /// Candidates asked for again in the same context, equal at float32 precision to one
    /// already stored (not stored twice).
    pub duplicates: usize,
}

impl Records {
    /// Appends `other`'s contexts and examples after this one's (its context indices shifted).
    pub fn append(&mut self, mut other: Records) {
        let base = self.context_agents.len();
        self.history.append(&mut other.history);
        self.context_agents.append(&mut other.context_agents);
        self.example_context
            .extend(other.example_context.iter().map(|c| c + base));
        self.candidate.append(&mut other.candidate);
        self.prediction.append(&mut other.prediction);
        self.duplicates += other.duplicates;
    }
}

/// A predictor that delegates to `inner` and records every candidate per scene that is distinct
/// at float32 precision (projected-gradient steps often move a candidate by less than that).
pub struct Recording {
    inner: Box<dyn Predictor>,
    /// What was recorded so far.
    pub records: Records,
    scene: Vec<f64>,
    n_agents: usize,
    context_open: bool,
    seen: HashSet<Vec<u32>>,
}

impl Recording {
    /// Wraps `inner`.
    #[must_use]
    pub fn new(inner: Box<dyn Predictor>) -> Self {
        Self {
            inner,
            records: Records::default(),
            scene: Vec::new(),
            n_agents: 0,
            context_open: false,
            seen: HashSet::new(),
        }
    }
}

impl Predictor for Recording {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn horizon(&self) -> usize {
        self.inner.horizon()
    }

    fn set_scene(&mut self, history: &History) -> crate::Result<()> {
        self.inner.set_scene(history)?;
        self.scene.clear();
        self.scene.extend_from_slice(history.positions());
        self.n_agents = history.n_agents();
        self.context_open = false;
        self.seen.clear();
        Ok(())
    }

    fn predict(&mut self, candidates: &[f64], out: &mut [f64]) -> crate::Result<()> {
        self.inner.predict(candidates, out)?;
        let h = self.inner.horizon();
        let per_c = h * 2;
        let per_o = (self.n_agents.saturating_sub(1)) * h * 2;
        if per_c == 0 || self.n_agents < 2 {
            return Ok(());
        }
        let batch = candidates.len() / per_c;
        for b in 0..batch {
            let cand = &candidates[b * per_c..(b + 1) * per_c];
            // Distinct at the float32 storage precision.
            if !self
                .seen
                .insert(cand.iter().map(|&v| (v as f32).to_bits()).collect())
            {
                self.records.duplicates += 1;
                continue;
            }
            if !self.context_open {
                debug_assert_eq!(self.scene.len(), self.n_agents * T_OBS * 2);
                self.records
                    .history
                    .extend(self.scene.iter().map(|&v| v as f32));
                self.records.context_agents.push(self.n_agents);
                self.context_open = true;
            }
            self.records
                .example_context
                .push(self.records.context_agents.len() - 1);
            self.records
                .candidate
                .extend(cand.iter().map(|&v| v as f32));
            self.records
                .prediction
                .extend(out[b * per_o..(b + 1) * per_o].iter().map(|&v| v as f32));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ConstantVelocity;

    fn history(n: usize) -> History {
        let mut v = Vec::with_capacity(n * T_OBS * 2);
        for i in 0..n {
            for t in 0..T_OBS {
                v.push(t as f64 * 3.0);
                v.push(i as f64 * 3.5);
            }
        }
        History::new(v, n).expect("valid history")
    }

    #[test]
    fn records_distinct_candidates_with_the_inner_prediction() {
        let mut rec = Recording::new(Box::new(ConstantVelocity::default()));
        let mut plain = ConstantVelocity::default();
        let h = history(3);
        rec.set_scene(&h).expect("scene");
        plain.set_scene(&h).expect("scene");
        let c1: Vec<f64> = (1..13).map(f64::from).collect();
        let c2: Vec<f64> = (1..13).map(|v| f64::from(v) + 0.5).collect();
        let mut out = vec![0.0; 2 * 6 * 2];
        let mut want = vec![0.0; 2 * 6 * 2];
        for c in [&c1, &c2, &c1] {
            rec.predict(c, &mut out).expect("predict");
            plain.predict(c, &mut want).expect("predict");
            assert_eq!(out, want, "the wrapper must not change predictions");
        }
        // Same candidate plus a float32-identical one: duplicates.
        let c3: Vec<f64> = c1.iter().map(|v| v + 1e-12).collect();
        rec.predict(&c3, &mut out).expect("predict");
        let r = &rec.records;
        assert_eq!(r.context_agents, vec![3]);
        assert_eq!(r.example_context, vec![0, 0]);
        assert_eq!(r.duplicates, 2);
        assert_eq!(r.candidate.len(), 2 * 12);
        assert_eq!(r.prediction.len(), 2 * 2 * 12);
        assert_eq!(r.history.len(), 3 * T_OBS * 2);
        // A new scene opens a new context and forgets the seen set.
        rec.set_scene(&history(2)).expect("scene");
        rec.predict(&c1, &mut [0.0; 12]).expect("predict");
        assert_eq!(rec.records.context_agents, vec![3, 2]);
        assert_eq!(rec.records.example_context, vec![0, 0, 1]);
    }

    #[test]
    fn errors_pass_through_and_record_nothing() {
        let mut rec = Recording::new(Box::new(ConstantVelocity::default()));
        rec.set_scene(&history(2)).expect("scene");
        let bad = vec![f64::NAN; 12];
        assert!(rec.predict(&bad, &mut [0.0; 12]).is_err());
        assert!(rec.records.example_context.is_empty());
    }

    #[test]
    fn append_shifts_context_indices() {
        let mut a = Recording::new(Box::new(ConstantVelocity::default()));
        a.set_scene(&history(3)).expect("scene");
        let c1: Vec<f64> = (1..13).map(f64::from).collect();
        a.predict(&c1, &mut [0.0; 2 * 12]).expect("predict");
        let mut b = Recording::new(Box::new(ConstantVelocity::default()));
        b.set_scene(&history(2)).expect("scene");
        b.predict(&c1, &mut [0.0; 12]).expect("predict");
        b.predict(&c1, &mut [0.0; 12]).expect("predict");
        let mut all = a.records.clone();
        all.append(b.records.clone());
        assert_eq!(all.context_agents, vec![3, 2]);
        assert_eq!(all.example_context, vec![0, 1]);
        assert_eq!(all.duplicates, 1);
        assert_eq!(all.history.len(), (3 + 2) * T_OBS * 2);
        assert_eq!(all.prediction.len(), 2 * 12 + 12);
    }
}
