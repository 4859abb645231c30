//! # nudge-planner
//!
//! The interaction-aware planner of the paper (Algorithm 1): an MPC over T = 6 steps of
//! 0.3 s solved by ADMM, whose steering and acceleration updates are Clarabel QPs and whose
//! state update is projected gradient descent with every trial point checked for safety by
//! running a [`nudge_predictor::Predictor`] on the candidate ego trajectory ([`Planner`]; the
//! phases are described in its module). Plus the scenario reader ("nudge.scenario/1" and "/2"
//! safetensors files, [`Scenario`]), lanes that begin and end ([`extents`]), the lane-change
//! logic a closed loop applies around the planner ([`lane`]) and the settings reference
//! ([`describe`]). The closed-loop simulator that drives the planner (worlds, metrics,
//! records, batches) is a crate of its own, built on this one.
//!
//! Conventions: road frame, x along travel (m), y lateral positive left (m), heading ψ (rad,
//! 0 = +x), speed v (m/s); agent 0 is the ego; one step = 0.3 s.

mod ablation;
mod admm;
mod cancel;
pub mod describe;
mod error;
pub mod extents;
pub mod fit;
pub mod lane;
mod model;
mod qp;
mod safety;
pub mod scenario;
pub mod settings;

pub use ablation::keep_lane_path;
pub use admm::BudgetLimit;
pub use admm::{
    BindingVehicle, CheckedVehicle, DecidedBy, EgoState, Family, JointSolution, PairGeometry,
    PhaseTimings, Plan, PlanStatus, Planner, PlanningProblem, RANK_ORDER, RankKey,
    SafetyConstraint, StepStatus, Violation,
};
pub use cancel::Cancel;
pub use error::{PlannerError, ScenarioError, SettingsError};
pub use extents::{LaneViolation, LaneViolationKind, Lanes, StopRule};
pub use model::{Bicycle, Jac4, Linearisation, State};
pub use qp::{QpName, QpStatus};
pub use safety::{
    Ellipse, MAX_MOTION_HEADING, MIN_MOTION_DX, OrientedBox, bounding_half_extents, box_separation,
    clip_segment_to_box, motion_axis, motion_direction, motion_heading,
};
pub use scenario::{LaneExtent, SCHEMA, SCHEMA_EXTENTS, Scenario};
pub use settings::PlannerSettings;
