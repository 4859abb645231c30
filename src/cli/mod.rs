//! The `nudge` command line as a library: the `nudge` binary (`src/main.rs`) and the `nudge`
//! command of the Python package (`nudge._native.cli_main`) both run [`run`], so they take the
//! same arguments, print the same text and end with the same [`ExitStatus`]. They differ only
//! in where their shipped assets lie (the `shipped_assets` of [`run`]).
//!
//! `nudge simulate`: closed-loop lane changes of the interaction-aware planner on real
//! scenario files (see `nudge simulate --help`). `nudge settings`: the reference of every
//! setting (see `nudge settings --help`).
#![allow(clippy::print_stdout)]

mod commonroad;
mod settings;
mod simulate;

use std::ffi::OsString;
use std::io::Write;
use std::path::Path;

use clap::{Parser, Subcommand};

/// Interaction-aware motion planning with neural (teacher / distilled student) predictions.
#[derive(Debug, Parser)]
#[command(name = "nudge", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

// One command is parsed per process: the variants' sizes do not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
enum Command {
    /// Closed-loop lane-change simulations of the ADMM MPC planner on scenario files.
    #[command(
        after_help = "Exit status: 0 every run ran; 1 refused before any run (the \
                            message names the argument, setting or file); 2 the command line \
                            does not parse; 3 some runs could not run (each reported, the others' \
                            records written); 4 the runs ran but an output (records, solution, \
                            animation) could not be written (the message names it)."
    )]
    Simulate(simulate::SimulateArgs),
    /// Every planner and closed-loop setting with its unit, default, valid values and meaning
    /// (the page docs/reference/settings.md), or the defaults as settings files.
    Settings(settings::SettingsArgs),
}

/// How a `nudge` command ended: the process's exit status.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ExitStatus {
    /// 0: every run ran (a lane change that did not succeed is a result, not a failure), or
    /// the help or version was printed.
    Success = 0,
    /// 1: refused before any run; the message on stderr names the argument, setting or file.
    Refused = 1,
    /// 2: the command line does not parse (clap's usage error on stderr).
    Usage = 2,
    /// 3: some runs could not run (each reported on stderr, the others' records written).
    RunsFailed = 3,
    /// 4: the runs ran but an output (records, solution, animation) could not be written or
    /// made; the message on stderr names the file.
    OutputFailed = 4,
}

impl ExitStatus {
    /// The exit code (0 to 4).
    #[must_use]
    pub const fn code(self) -> u8 {
        self as u8
    }
}

impl From<ExitStatus> for std::process::ExitCode {
    fn from(status: ExitStatus) -> Self {
        Self::from(status.code())
    }
}

/// Runs the `nudge` command line `args` (the program name first, as in `std::env::args_os`),
/// printing to stdout and stderr, and returns how it ended.
///
/// `shipped_assets` is the assets directory (`models/`, `scenes/`) of this distribution of
/// nudge: `assets` of a checkout for the binary, the installed package's for the Python
/// package's command. The defaults of `--assets` and `--scenes` resolve through
/// [`nudge_predictor::assets_dir`] of it (so `$NUDGE_ASSETS` overrides it).
pub fn run<I, T>(args: I, shipped_assets: &Path) -> ExitStatus
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let status = match Cli::try_parse_from(args) {
        Ok(cli) => match cli.command {
            Command::Simulate(a) => finish(simulate::run(&a, shipped_assets)),
            Command::Settings(a) => {
                print!("{}", settings::render(&a));
                ExitStatus::Success
            }
        },
        Err(e) => {
            // Help and version go to stdout with status 0, usage errors to stderr with 2.
            let _ = e.print();
            if e.use_stderr() {
                ExitStatus::Usage
            } else {
                ExitStatus::Success
            }
        }
    };
    // Nothing may stay buffered when the caller is not a Rust `main` (the Python command).
    let _ = std::io::stdout().flush();
    status
}

/// The exit status of a subcommand's result (the number of runs that could not run, or why it
/// stopped), the message printed on stderr.
fn finish(result: Result<usize, simulate::Stop>) -> ExitStatus {
    match result {
        Ok(0) => ExitStatus::Success,
        Ok(_) => ExitStatus::RunsFailed,
        Err(e) => {
            eprintln!("error: {}", e.message());
            e.status()
        }
    }
}
