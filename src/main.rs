//! The `nudge` command-line tool (run from a checkout's root, its shipped assets in `assets`).
//!
//! `nudge simulate`: closed-loop lane changes of the interaction-aware planner on real
//! scenario files (see `nudge simulate --help`). Exit codes ([`nudge::cli::ExitStatus`]): 0
//! every run ran; 1 refused before any run; 2 the command line does not parse; 3 some runs
//! could not run.

use std::path::Path;
use std::process::ExitCode;

fn main() -> ExitCode {
    let shipped = Path::new(nudge::predictor::CHECKOUT_ASSETS);
    nudge::cli::run(std::env::args_os(), shipped).into()
}
