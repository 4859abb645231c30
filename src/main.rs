//! The `nudge` command-line tool.

fn main() {}
