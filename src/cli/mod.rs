//! Subcommands of the `nudge` tool.

pub mod simulate;
