//! # nudge
//!
//! The facade of the nudge workspace: re-exports [`predictor`] (`nudge-predictor`) and
//! [`planner`] (`nudge-planner`), and hosts the `nudge` command-line tool.

pub use nudge_planner as planner;
pub use nudge_predictor as predictor;
