//! A validated scene history: the last `T_OBS` positions of every agent, ego first.

use crate::error::{PredictorError, Result};
use crate::{MAX_AGENTS, T_OBS};

/// The observed past of one scene.
///
/// Layout: `positions` is `[n_agents, T_OBS, 2]` row-major, metres in the road frame
/// (x along travel, y lateral positive left), oldest step first, one step = 0.3 s.
/// Agent 0 is the ego vehicle.
#[derive(Debug, Clone, PartialEq)]
pub struct History {
    pub(crate) positions: Vec<f64>,
    pub(crate) n_agents: usize,
}

impl History {
    /// Validates and wraps a `[n_agents, T_OBS, 2]` buffer.
    ///
    /// # Errors
    /// [`PredictorError::AgentCount`] if `n_agents` is 0 or above [`MAX_AGENTS`],
    /// [`PredictorError::InputShape`] if the buffer length is not `n_agents * T_OBS * 2`,
    /// [`PredictorError::NonFiniteInput`] on NaN or infinity,
    /// [`PredictorError::InputOutOfRange`] when a coordinate, a per-step displacement or the
    /// distance between two agents at the last observed step is beyond the ranges the
    /// networks represent (see [`crate::limits`]).
    pub fn new(positions: Vec<f64>, n_agents: usize) -> Result<Self> {
        if n_agents == 0 || n_agents > MAX_AGENTS {
            return Err(PredictorError::AgentCount {
                got: n_agents,
                max: MAX_AGENTS,
            });
        }
        check_len("history", &positions, &[n_agents, T_OBS, 2])?;
        check_finite("history", &positions)?;
        crate::limits::check_history(&positions, n_agents)?;
        Ok(Self {
            positions,
            n_agents,
        })
    }

    /// Number of agents, ego included (1..=47).
    #[must_use]
    pub fn n_agents(&self) -> usize {
        self.n_agents
    }

    /// The whole `[n_agents, T_OBS, 2]` buffer (metres).
    #[must_use]
    pub fn positions(&self) -> &[f64] {
        &self.positions
    }

    /// Position `[x, y]` (metres) of `agent` at observed step `t` (0 = oldest, `T_OBS-1` = now).
    ///
    /// # Panics
    /// If `agent >= n_agents()` or `t >= T_OBS` (an index out of bounds, like slice indexing).
    #[must_use]
    pub fn at(&self, agent: usize, t: usize) -> [f64; 2] {
        let k = (agent * T_OBS + t) * 2;
        [self.positions[k], self.positions[k + 1]]
    }

    /// A copy with the non-ego agents reordered: new agent `i` (i ≥ 1) is old agent `perm[i-1]`.
    /// `perm` must be a permutation of `1..n_agents`; used by property tests and callers that
    /// sort neighbours.
    ///
    /// # Panics
    /// If `perm` is not a permutation of `1..n_agents` (a caller bug, like an index out of
    /// bounds).
    #[must_use]
    pub fn permuted(&self, perm: &[usize]) -> Self {
        let mut seen = vec![false; self.n_agents];
        assert!(
            perm.len() + 1 == self.n_agents
                && perm.iter().all(|&p| p >= 1
                    && p < self.n_agents
                    && !std::mem::replace(&mut seen[p], true)),
            "History::permuted: {perm:?} is not a permutation of 1..{}",
            self.n_agents
        );
        let mut positions = Vec::with_capacity(self.positions.len());
        positions.extend_from_slice(&self.positions[..T_OBS * 2]);
        for &p in perm {
            positions.extend_from_slice(&self.positions[p * T_OBS * 2..(p + 1) * T_OBS * 2]);
        }
        Self {
            positions,
            n_agents: self.n_agents,
        }
    }
}

/// Checks that `buf` holds exactly the product of `shape` elements.
pub(crate) fn check_len(what: &'static str, buf: &[f64], shape: &[usize]) -> Result<()> {
    let expected = shape
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .unwrap_or(usize::MAX);
    if buf.len() != expected {
        return Err(PredictorError::InputShape {
            what,
            shape: format!("{shape:?}"),
            expected,
            got: buf.len(),
        });
    }
    Ok(())
}

/// Checks that every element of `buf` is finite.
pub(crate) fn check_finite(what: &'static str, buf: &[f64]) -> Result<()> {
    if let Some((index, &value)) = buf.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(PredictorError::NonFiniteInput { what, index, value });
    }
    Ok(())
}
