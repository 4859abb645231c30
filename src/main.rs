//! The `nudge` command-line tool.
//!
//! `nudge simulate`: closed-loop lane changes of the interaction-aware planner on real
//! scenario files (see `nudge simulate --help`). Exit codes: 0 every run ran; 1 refused before
//! any run; 2 the command line does not parse; 3 some runs could not run.
#![allow(clippy::print_stdout)]

mod cli;

use clap::{Parser, Subcommand};

/// Interaction-aware motion planning with neural (teacher / distilled student) predictions.
#[derive(Debug, Parser)]
#[command(name = "nudge", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Closed-loop lane-change simulations of the ADMM MPC planner on scenario files.
    #[command(
        after_help = "Exit status: 0 every run ran; 1 refused before any run (the \
                            message names the argument, setting or file); 2 the command line \
                            does not parse; 3 some runs could not run (each reported, the others' \
                            records written)."
    )]
    Simulate(cli::simulate::SimulateArgs),
}

/// Exit codes: 0 every run ran; 1 refused before any run (the message names the argument,
/// setting or file); 2 the command line does not parse (clap); 3 some runs could not run
/// (reported on stderr, the others' records written).
fn main() -> std::process::ExitCode {
    let args = Cli::parse();
    let result = match args.command {
        Command::Simulate(a) => cli::simulate::run(&a),
    };
    match result {
        Ok(0) => std::process::ExitCode::SUCCESS,
        Ok(_) => std::process::ExitCode::from(3),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
