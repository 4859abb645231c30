//! The `nudge` command of the Python package: the Rust command line itself
//! ([`nudge::cli::run`]), so its subcommands, messages and exit statuses are the binary's.

use std::ffi::OsString;
use std::path::PathBuf;

use pyo3::prelude::*;

use crate::args::guard;

/// Runs the `nudge` command line on `argv` (the program name first, as `sys.argv`) with the
/// shipped assets at `assets` (the installed package's, overridden by `$NUDGE_ASSETS`) and
/// returns its exit status: 0 every run ran (or help / version printed), 1 refused before any
/// run, 2 the command line does not parse, 3 some runs could not run. Prints to the process's
/// stdout and stderr; runs with the GIL released.
#[pyfunction]
pub fn cli_main(py: Python<'_>, argv: Vec<OsString>, assets: PathBuf) -> PyResult<u8> {
    guard(|| Ok(py.detach(|| nudge::cli::run(argv, &assets)).code()))
}
