//! Closed-loop simulation of lane changes on real scenes, and the one contract both front ends
//! (the `nudge` CLI and `nudge.simulate`) share.
//!
//! * [`config`]: [`SimConfig`] and the [`World`] that moves the other vehicles;
//! * [`run`]: one run ([`simulate`]): plan, apply the first input to the vehicle
//!   ([`crate::Bicycle::advance`]), move the others, shift the histories, repeat;
//! * [`records`]: what a run records ([`RunRecord`], [`StepRecord`], [`StepStatus`]);
//! * [`batch`]: the run-spec rule ([`run_specs`]), the predictors of a batch loaded once
//!   ([`Predictors`]) and [`simulate_many`];
//! * [`columns`]: records → named columns ([`run_table`], [`step_table`]), the [`Summary`] and
//!   the per-step listing;
//! * [`request`]: the one validation of a batch both front ends call ([`BatchRequest`]),
//!   before any run starts; a [`Cancel`] flag stops a running batch.

// SimError carries the planner's and predictor's errors by value; they are rare, cold paths.
#![allow(clippy::result_large_err)]

pub mod batch;
pub mod columns;
pub mod config;
pub mod records;
pub mod request;
pub mod run;

pub use batch::{
    Cancel, MAX_RUNS, MAX_THREADS, Predictors, RunOutput, RunSpec, defaults, run_specs,
    simulate_many, thread_pool,
};
pub use columns::{
    Column, RUN_COLUMNS, STEP_COLUMNS, Summary, Table, run_table, step_listing, step_table,
};
pub use config::{SimConfig, World};
pub use records::{RunRecord, StepRecord, StepStatus};
pub use request::{Batch, BatchRequest};
pub use run::{simulate, simulate_cancellable, target_lane};
