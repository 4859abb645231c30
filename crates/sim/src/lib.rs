//! # nudge-sim
//!
//! Closed-loop simulation of lane changes on real scenes, and the one contract both front ends
//! (the `nudge` CLI and `nudge.simulate`) share. It drives the ego through a [`Policy`]
//! (observation in, plan out), which nudge's [`nudge_planner::Planner`] implements.
//!
//! * [`policy`]: the [`Policy`] trait that plans the ego's motion at every step;
//! * [`config`]: [`SimConfig`] and the [`World`] that moves the other vehicles;
//! * [`world`]: the model of a run's world ([`WorldModel`]: the teacher, the IDM driver
//!   population, or nothing for log replay);
//! * [`idm`]: the `idm` world ([`IdmPopulation`], fitted to real car-following, and the
//!   per-run [`IdmTraffic`] with its intrusion rule);
//! * [`run`]: one run ([`simulate`]): plan, apply the first input to the vehicle
//!   ([`nudge_planner::Bicycle::advance`]), move the others, shift the histories, judge the step,
//!   repeat;
//! * [`session`]: the closed loop one step at a time ([`Session`]: plan, advance, finish),
//!   the one implementation of a run that [`simulate_policy`] and the Gymnasium environment
//!   both step, and why a run ends ([`EndReason`]);
//! * [`metrics`]: what a run is judged by (collisions at fault or not, off-road, straddling,
//!   slow steps in a live lane, time to collision, progress, comfort, the score, the density
//!   of the target lane), computed from the run's states;
//! * [`records`]: what a run records ([`RunRecord`], [`StepRecord`], [`StepStatus`]);
//! * [`batch`]: the run-spec rule ([`run_specs`]), the predictors of a batch loaded once
//!   ([`Predictors`]) and [`simulate_many`] (or [`Runs`], with a planning predictor built per
//!   run by the caller);
//! * [`columns`]: records → named columns ([`run_table`], [`step_table`],
//!   [`collision_table`]), the [`Summary`] and the per-step listing;
//! * [`request`]: the one validation of a batch both front ends call ([`BatchRequest`]),
//!   before any run starts; a [`Cancel`] flag stops a running batch;
//! * [`describe`]: the reference of [`SimConfig`] and the whole settings reference page;
//! * [`error`]: the simulator's typed errors ([`SimError`], [`SimConfigError`],
//!   [`WorldFileError`]).
//!
//! Conventions: road frame, x along travel (m), y lateral positive left (m), heading ψ (rad,
//! 0 = +x), speed v (m/s); agent 0 is the ego; one step = 0.3 s.

// SimError carries the planner's and predictor's errors by value; they are rare, cold paths.
#![allow(clippy::result_large_err)]

pub mod batch;
pub mod columns;
pub mod config;
pub mod describe;
pub mod error;
pub mod idm;
pub mod metrics;
pub mod policy;
pub mod records;
pub mod request;
pub mod run;
pub mod session;
pub mod world;

pub use batch::{
    Keep, MAX_RUNS, MAX_THREADS, PlanningFactory, PolicyFactory, Predictors, Progress, RunOutput,
    RunSpec, Runs, WorldSpec, defaults, run_specs, simulate_many, thread_pool,
};
pub use columns::{
    COLLISION_COLUMNS, Column, RUN_COLUMNS, STEP_COLUMNS, Summary, Table, collision_table,
    run_table, step_listing, step_table,
};
pub use config::{SimConfig, World};
pub use error::{SimConfigError, SimError, WorldFileError};
pub use idm::{IdmPopulation, IdmTraffic, LaneEndMerge, idm_path};
pub use metrics::{Collision, RunMetrics, StepMetrics};
pub use policy::Policy;
pub use records::{RunOutcome, RunRecord, StepRecord, StepStatus, StepTrace};
pub use request::{Batch, BatchRequest};
pub use run::{
    Cancel, RunControl, simulate, simulate_policy, simulate_with, target_lane, target_reach,
};
pub use session::{EndReason, Session};
pub use world::WorldModel;
