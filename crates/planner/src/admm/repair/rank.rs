//! How candidates of the execution check are compared: the ranking is a fixed list of keys
//! ([`RANK_ORDER`]), compared in order, each deciding only on a tie of those before it.

use crate::settings::PlannerSettings;

use super::super::decision::{RANK_ORDER, RankKey};

/// Weight of the state-bound excess (per m, rad or m/s) against the safety violation (units of
/// b) in [`Rank::value`] of an inadmissible candidate.
pub(crate) const EXCESS_WEIGHT: f64 = 10.0;

/// A difference below this (bound excess, overlap, violation) counts as a tie (rounding).
pub(crate) const EXCESS_TOLERANCE: f64 = 1e-9;

/// A candidate's rank: the value of every [`RankKey`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rank {
    /// [`RankKey::Admissible`].
    pub safe: bool,
    /// [`RankKey::LaneBegun`]: a state's centre is in a lane before it begins.
    pub unbegun: bool,
    /// [`RankKey::ClearPath`] (false for an admissible candidate or with the floor off).
    pub clear: bool,
    /// [`RankKey::Value`].
    pub value: f64,
    /// [`RankKey::WithinBounds`] failed: the bound excess exceeds `bounds_slack`.
    pub out_of_bounds: bool,
    /// [`RankKey::Contact`] (m; 0 when admissible).
    pub contact: f64,
    /// [`RankKey::RoadEdge`] (m; 0 when admissible).
    pub edge: f64,
    /// [`RankKey::Ahead`] (units of b; 0 when admissible or the lead rule does not apply).
    pub ahead: f64,
    /// [`RankKey::KeepsLane`] failed (false when admissible or the lead rule does not apply).
    pub leaves_lane: bool,
}

/// `Some(true)` when `mine` wins a boolean key where `false` is better, `None` on a tie.
fn false_first(mine: bool, other: bool) -> Option<bool> {
    (mine != other).then_some(!mine)
}

/// `Some(true)` when `mine` is smaller by more than the tolerance, `None` on a tie (NaN
/// differences, e.g. ∞ − ∞, tie).
fn smaller_first(mine: f64, other: f64) -> Option<bool> {
    ((mine - other).abs() > EXCESS_TOLERANCE).then_some(mine < other)
}

impl Rank {
    /// The rank of an admissible candidate of cost `cost`.
    pub(crate) fn admissible(unbegun: bool, cost: f64) -> Self {
        Self {
            safe: true,
            unbegun,
            clear: false,
            value: cost,
            out_of_bounds: false,
            contact: 0.0,
            edge: 0.0,
            ahead: 0.0,
            leaves_lane: false,
        }
    }

    /// The rank of an inadmissible candidate with `violations`.
    pub(crate) fn inadmissible(s: &PlannerSettings, violations: &Violations) -> Self {
        Self {
            safe: false,
            unbegun: violations.unbegun,
            clear: violations.clear,
            value: violations.value,
            out_of_bounds: violations.bound_excess > s.repair.bounds_slack.max(EXCESS_TOLERANCE),
            contact: violations.contact,
            edge: violations.edge,
            ahead: violations.ahead,
            leaves_lane: violations.leaves_lane,
        }
    }

    /// Compares one key: `Some(true)` when `self` is better by it, `Some(false)` when `other`
    /// is, `None` on a tie.
    fn compare(&self, other: &Rank, key: RankKey) -> Option<bool> {
        match key {
            RankKey::Admissible => false_first(!self.safe, !other.safe),
            RankKey::WithinBounds => false_first(self.out_of_bounds, other.out_of_bounds),
            RankKey::Contact => smaller_first(self.contact, other.contact),
            RankKey::RoadEdge => smaller_first(self.edge, other.edge),
            RankKey::KeepsLane => false_first(self.leaves_lane, other.leaves_lane),
            RankKey::Ahead => smaller_first(self.ahead, other.ahead),
            RankKey::LaneBegun => false_first(self.unbegun, other.unbegun),
            RankKey::ClearPath => false_first(!self.clear, !other.clear),
            RankKey::Value => Some(self.value < other.value),
        }
    }

    /// The first key of [`RANK_ORDER`] that separates `self` from `other`, and whether `self`
    /// wins by it. The last key always decides (a tie on the value keeps `other`).
    pub(crate) fn decide(&self, other: &Rank) -> (RankKey, bool) {
        for key in RANK_ORDER {
            if let Some(wins) = self.compare(other, key) {
                return (key, wins);
            }
        }
        (RankKey::Value, false)
    }

    /// Strictly better than `other`.
    pub(crate) fn beats(&self, other: &Rank) -> bool {
        self.decide(other).1
    }
}

/// What an inadmissible candidate's [`Rank`] is made of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Violations {
    /// A state of the roll-out has its centre in a lane before it begins.
    pub unbegun: bool,
    /// Its path is clear and it keeps the speed floor ([`RankKey::ClearPath`]).
    pub clear: bool,
    /// Total violation: safety violation (units of b) + [`EXCESS_WEIGHT`] × state-bound excess.
    pub value: f64,
    /// State-bound excess of the roll-out (Σ over steps; m, rad and m/s mixed, as
    /// `LinearisedProblem::bound_excess`); 0 within the bounds.
    pub bound_excess: f64,
    /// Predicted box overlap (m, `Evaluation::overlap`).
    pub contact: f64,
    /// Road-edge excess of the box's corners (m, `LinearisedProblem::edge_excess`).
    pub edge: f64,
    /// Safety violation (units of b) against the vehicles ahead of the ego in its path.
    pub ahead: f64,
    /// The box of some state of the roll-out spans a lane line (while the lead rule applies).
    pub leaves_lane: bool,
}
