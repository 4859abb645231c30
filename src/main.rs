//! The `nudge` command-line tool.
//!
//! `nudge simulate`: closed-loop lane changes of the interaction-aware planner on real
//! scenario files (see `nudge simulate --help`).
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
    Simulate(cli::simulate::SimulateArgs),
}

fn main() -> std::process::ExitCode {
    let args = Cli::parse();
    let result = match args.command {
        Command::Simulate(a) => cli::simulate::run(&a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
