//! # nudge-planner
//!
//! Interaction-aware ADMM MPC (Clarabel QPs for steering and acceleration, projected gradient
//! descent with network-checked safety for the states) and a closed-loop simulator.
