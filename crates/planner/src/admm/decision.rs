//! What decided a plan ([`DecidedBy`]): the stage of the MPC call, and for a fallback the
//! candidate family ([`Family`]) and the rank key ([`RankKey`], compared in the order
//! [`RANK_ORDER`]) that chose it. Plain data, shared by the plan and the repair stage.

use std::fmt;

use serde::{Deserialize, Serialize};

/// Where a fallback candidate comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Family {
    /// The nominal: the previous plan shifted by one step.
    Nominal,
    /// A constant acceleration profile with the steering that aligns the ego with the road.
    KeepLane,
    /// A constant acceleration profile with the steering towards the lateral goal.
    SteerToGoal,
    /// The braking profile that stops before the end of a lane that ends, with the steering
    /// that keeps the lane, returns to the own lane's centre or steers to the goal.
    Stop,
    /// A constant acceleration profile with the steering towards the retreat lane's centre.
    Retreat,
    /// The input lattice: blocks of steering and acceleration rate choices.
    Lattice,
}

impl Family {
    /// The family's name in records and docs (snake case).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Nominal => "nominal",
            Self::KeepLane => "keep_lane",
            Self::SteerToGoal => "steer_to_goal",
            Self::Stop => "stop",
            Self::Retreat => "retreat",
            Self::Lattice => "lattice",
        }
    }
}

impl fmt::Display for Family {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One key of the ranking of candidates. An admissible candidate has every inadmissible
/// key at its best value (false or 0), so only [`RankKey::Admissible`], [`RankKey::LaneBegun`]
/// and [`RankKey::Value`] (its cost J) ever separate two admissible ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RankKey {
    /// Admissible (safe by the predictor at `safety_min` and within the state bounds) first.
    Admissible,
    /// Within the state bounds (heading, corridor, speed, road edge, lane extents, stopping
    /// rule; excess at most `bounds_slack`) first: predicted contact never buys a swerve past
    /// the heading bound or off the road.
    WithinBounds,
    /// Less predicted box overlap with the other vehicles (m, Σ over vehicles and steps).
    Contact,
    /// Less road-edge excess of the box's corners (m, Σ over the horizon).
    RoadEdge,
    /// While the lead rule applies (ego at least `lead_min_speed` and wholly inside one lane at
    /// the start), a roll-out whose box stays off every lane line first.
    KeepsLane,
    /// While the lead rule applies, less safety violation against the vehicles ahead of the
    /// ego in its path (units of b).
    Ahead,
    /// A roll-out that never puts its centre in a lane before that lane begins first.
    LaneBegun,
    /// An inadmissible roll-out whose path is clear (violations only from vehicles beside the
    /// ego) and that ends at or above `fallback_speed_floor` · v_ref first.
    ClearPath,
    /// Smaller value: the cost J of an admissible candidate, the total violation (safety
    /// violation + 10 × bound excess) of an inadmissible one.
    Value,
}

/// The keys of the ranking, in the order they are compared.
pub const RANK_ORDER: [RankKey; 9] = [
    RankKey::Admissible,
    RankKey::WithinBounds,
    RankKey::Contact,
    RankKey::RoadEdge,
    RankKey::KeepsLane,
    RankKey::Ahead,
    RankKey::LaneBegun,
    RankKey::ClearPath,
    RankKey::Value,
];

impl RankKey {
    /// The key's name in records and docs (snake case).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Admissible => "admissible",
            Self::WithinBounds => "within_bounds",
            Self::Contact => "contact",
            Self::RoadEdge => "road_edge",
            Self::KeepsLane => "keeps_lane",
            Self::Ahead => "ahead",
            Self::LaneBegun => "lane_begun",
            Self::ClearPath => "clear_path",
            Self::Value => "value",
        }
    }
}

impl fmt::Display for RankKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// What decided the applied plan's inputs: the stage of the MPC call that produced them and,
/// for a fallback, its candidate family and the rank key that chose it. `Admm` exactly when
/// the ADMM iterate's inputs were applied unchanged (whatever the [`crate::PlanStatus`] says of their
/// safety); `External` for a plan that no nudge planner made (a policy from outside nudge,
/// e.g. a Python planner in nudge's closed loop).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DecidedBy {
    /// The ADMM iterate's inputs, unchanged.
    Admm,
    /// The ADMM iterate's inputs with the steering governed to the heading bound.
    AdmmGoverned,
    /// The refinement's SQP steps from the ADMM inputs ([`crate::PlanStatus::Refined`]).
    Refined,
    /// The ADMM inputs pulled towards the nominal ([`crate::PlanStatus::Backtracked`]).
    Backtracked,
    /// The nominal (the shifted previous plan), checked with the budget's reserved call.
    Nominal,
    /// A fallback candidate.
    Fallback {
        /// The family that generated it.
        family: Family,
        /// The rank key by which it beat the best before it; `None` for the nominal when
        /// nothing beat it.
        key: Option<RankKey>,
    },
    /// A planner outside nudge made the plan (a foreign policy in the closed loop, e.g.
    /// `nudge.simulate(..., planner=obj)`); nudge only checked it.
    External,
}

impl DecidedBy {
    /// The label in records (`steps.csv`'s `decided_by`): `admm`, `admm_governed`, `refined`,
    /// `backtracked`, `nominal`, `fallback:<family>[:<rank key>]`, or `external`.
    #[must_use]
    pub fn label(&self) -> String {
        match self {
            Self::Admm => "admm".to_owned(),
            Self::AdmmGoverned => "admm_governed".to_owned(),
            Self::Refined => "refined".to_owned(),
            Self::Backtracked => "backtracked".to_owned(),
            Self::Nominal => "nominal".to_owned(),
            Self::Fallback { family, key: None } => format!("fallback:{family}"),
            Self::Fallback {
                family,
                key: Some(key),
            } => format!("fallback:{family}:{key}"),
            Self::External => "external".to_owned(),
        }
    }

    /// The plan is the ADMM iterate's, unchanged.
    #[must_use]
    pub fn is_admm(&self) -> bool {
        matches!(self, Self::Admm)
    }
}

impl std::fmt::Display for DecidedBy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.label())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_foreign_plan_is_labelled_external_in_tables_and_json() {
        assert_eq!(DecidedBy::External.label(), "external");
        assert_eq!(DecidedBy::External.to_string(), "external");
        assert!(!DecidedBy::External.is_admm());
        let json = serde_json::to_string(&DecidedBy::External).unwrap();
        assert_eq!(json, "\"external\"");
        let back: DecidedBy = serde_json::from_str(&json).unwrap();
        assert_eq!(back, DecidedBy::External);
        // The labels of nudge's own stages are unchanged.
        assert_eq!(DecidedBy::Admm.label(), "admm");
        assert_eq!(serde_json::to_string(&DecidedBy::Admm).unwrap(), "\"admm\"");
    }
}
