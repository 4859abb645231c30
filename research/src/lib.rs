//! # nudge-research
//!
//! Research tools around the nudge planner, kept out of the published crates (not published
//! itself): they answer questions about the planner's results rather than plan.
//!
//! * [`oracle`]: could a log-replay collision have been avoided at all, and from which step? A
//!   search over the ego's inputs against the known logged future ([`oracle::avoid`]);
//! * the `avoidability` binary (`src/bin/avoidability.rs`): the oracle asked about every
//!   collision of given log-replay runs, one markdown row per collision
//!   (`docs/results/avoidability.md`).
//!
//! Conventions as in `nudge-planner`: road frame, x along travel (m), y lateral positive left
//! (m), heading ψ (rad), speed v (m/s); agent 0 is the ego; one step = 0.3 s.

pub mod oracle;
