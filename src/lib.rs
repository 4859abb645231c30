//! # nudge
//!
//! The facade of the nudge workspace: re-exports [`predictor`] (`nudge-predictor`),
//! [`planner`] (`nudge-planner`) and [`sim`] (`nudge-sim`, the closed-loop simulator), and hosts the `nudge` command-line tool ([`cli`], run by the
//! `nudge` binary and by the Python package's `nudge` command) and the renderer of run
//! animations ([`animate`], used by `nudge simulate --animate` and Python's `nudge.animate`).

pub mod animate;
pub mod cli;
pub mod commonroad;
pub mod files;
pub mod provenance;
pub mod records;

pub use provenance::GIT_SHA;

pub use nudge_planner as planner;
pub use nudge_predictor as predictor;
pub use nudge_sim as sim;

/// The README's Rust example, compiled and run as a doctest (`cargo test --doc -p nudge`, part of
/// `cargo test --workspace`), from the repository root: the example fails the tests when it stops
/// running.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
