//! The record set of a batch of closed-loop runs, written to a folder: `steps.csv`,
//! `runs.csv`, `collisions.csv` (the columns of [`nudge_sim::columns`]), `records.json` (every
//! run that ran) and the caller's extra files (`provenance.json`, CommonRoad solutions), as one
//! atomic set with its manifest ([`crate::files::write_set`]). The one writer of
//! `nudge simulate --out` and of Python's `nudge.simulate(..., out=...)`; the schema is
//! `docs/records.md`.

use std::path::Path;

use nudge_planner::Scenario;
use nudge_sim::{RunOutput, RunRecord, collision_table, run_table, step_table};

/// Creates the output directory `dir` before any run, so that a path that cannot hold the
/// records is refused before the work is done. `name` is how the caller names the argument
/// (`--out`, `out`) in the message.
///
/// # Errors
/// `"<name> <dir>: ..."` when `dir` exists and is not a directory, or cannot be created.
pub fn prepare_dir(dir: &Path, name: &str) -> Result<(), String> {
    if dir.exists() && !dir.is_dir() {
        return Err(format!(
            "{name} {}: exists and is not a directory",
            dir.display()
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| format!("{name} {}: {e}", dir.display()))
}

/// Writes steps.csv, runs.csv, collisions.csv (the shared columns), records.json (the runs
/// that ran, in run order) and the `extra` files (name, bytes) into the directory `dir` (made
/// by [`prepare_dir`]) as one set with its manifest ([`crate::files::write_set`]: temporary
/// files renamed into place, never through a symbolic link). `scenes` are the batch's scenes
/// (`outputs[i].spec.scene` indexes them).
///
/// # Errors
/// A message naming the file that could not be made or written.
pub fn write_records(
    dir: &Path,
    scenes: &[Scenario],
    outputs: &[RunOutput],
    extra: &[(String, Vec<u8>)],
) -> Result<(), String> {
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    for (name, table) in [
        ("steps.csv", step_table(outputs)),
        ("runs.csv", run_table(scenes, outputs)),
        ("collisions.csv", collision_table(scenes, outputs)),
    ] {
        let mut bytes = Vec::new();
        table
            .write_csv(&mut bytes)
            .map_err(|e| format!("{}: {e}", dir.join(name).display()))?;
        files.push((name.to_string(), bytes));
    }
    let records: Vec<&RunRecord> = outputs
        .iter()
        .filter_map(|o| o.result.as_ref().ok())
        .collect();
    let json = serde_json::to_string_pretty(&records)
        .map_err(|e| format!("{}: {e}", dir.join("records.json").display()))?;
    files.push(("records.json".to_string(), json.into_bytes()));
    files.extend(extra.iter().cloned());
    let set: Vec<(&str, &[u8])> = files
        .iter()
        .map(|(n, b)| (n.as_str(), b.as_slice()))
        .collect();
    crate::files::write_set(dir, &set).map_err(|e| e.to_string())
}
