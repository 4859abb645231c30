//! The `nudge simulate` CLI writes exactly the shared columns (`nudge::planner::sim::columns`)
//! of the runs the library computes for the same scenes, seeds and settings (wall-clock
//! timings excepted), and refuses bad arguments with the library's typed messages.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use nudge::planner::sim::{
    COLLISION_COLUMNS, RUN_COLUMNS, STEP_COLUMNS, Table, collision_table, run_table, step_table,
};
use nudge::planner::{
    PlannerSettings, Predictors, Scenario, SimConfig, World, run_specs, simulate_many,
};

const TIMING: [&str; 3] = ["mpc_s", "z_s", "z_median_s"];

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A fresh directory holding two shipped scenes.
fn two_scenes(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nudge-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("scenes")).unwrap();
    for name in ["us101-11_1-t02.1-ego144", "us101-8_1-t02.1-ego56"] {
        let file = format!("{name}.safetensors");
        std::fs::copy(
            repo().join("assets/scenes").join(&file),
            dir.join("scenes").join(&file),
        )
        .unwrap();
    }
    dir
}

fn nudge(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_nudge"))
        .current_dir(repo())
        .args(args)
        .output()
        .unwrap()
}

/// The CSV text of a table.
fn csv(table: &Table) -> String {
    let mut out = Vec::new();
    table.write_csv(&mut out).unwrap();
    String::from_utf8(out).unwrap()
}

/// Rows of CSV text with the timing columns blanked.
fn without_timing(text: &str) -> Vec<Vec<String>> {
    let mut rows = text
        .lines()
        .map(|l| l.split(',').map(str::to_string).collect::<Vec<_>>());
    let header = rows.next().unwrap();
    let timing: Vec<usize> = (0..header.len())
        .filter(|&i| TIMING.contains(&header[i].as_str()))
        .collect();
    std::iter::once(header)
        .chain(rows.map(|mut r| {
            for &i in &timing {
                r[i].clear();
            }
            r
        }))
        .collect()
}

#[test]
fn cli_writes_the_shared_columns_of_the_library_runs() {
    let dir = two_scenes("columns");
    let out = dir.join("out");
    let scenes = dir.join("scenes");
    let o = nudge(&[
        "simulate",
        "--scenes",
        scenes.to_str().unwrap(),
        "--predictor",
        "student",
        "--seed",
        "5",
        "--runs",
        "2",
        "--max-steps",
        "3",
        "--settle-steps",
        "3",
        "--threads",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("runs 4 (+0 that could not run), planning steps 12"),
        "{stdout}"
    );

    // The same runs through the library.
    let (loaded, bad) = Scenario::load_dir(&scenes).unwrap();
    assert!(bad.is_empty());
    let settings = PlannerSettings::default();
    let cfg = SimConfig {
        max_steps: 3,
        settle_steps: 3,
        ..SimConfig::default()
    };
    assert_eq!(cfg.world, World::Teacher);
    let specs = run_specs(loaded.len(), 2, 5, None).unwrap();
    let assets = repo().join("assets");
    let predictors = Predictors::resolve("student", cfg.world, None, None, &assets, 6).unwrap();
    let outputs = simulate_many(&loaded, &specs, &settings, &cfg, &predictors, false);
    let runs = run_table(&loaded, &outputs);
    let steps = step_table(&outputs);
    let collisions = collision_table(&loaded, &outputs);
    let names = |t: &Table| t.columns().iter().map(|(n, _)| *n).collect::<Vec<_>>();
    assert_eq!(names(&runs), RUN_COLUMNS);
    assert_eq!(names(&steps), STEP_COLUMNS);
    assert_eq!(names(&collisions), COLLISION_COLUMNS);

    let read = |name: &str| std::fs::read_to_string(out.join(name)).unwrap();
    assert_eq!(read("runs.csv"), csv(&runs));
    assert_eq!(read("collisions.csv"), csv(&collisions));
    assert_eq!(
        without_timing(&read("steps.csv")),
        without_timing(&csv(&steps))
    );
    // Scene-major runs with seed + i·runs + r.
    let seeds: Vec<String> = read("runs.csv")
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(2).unwrap().to_string())
        .collect();
    assert_eq!(seeds, ["5", "6", "7", "8"]);
    let records: serde_json::Value = serde_json::from_str(&read("records.json")).unwrap();
    let first = &records[0];
    assert_eq!(first["world"], "teacher");
    assert_eq!(first["predictor"], "student");
    assert!(
        first["steps"][0]["status"].is_string(),
        "status serialised as its name"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn cli_refuses_bad_arguments_by_name() {
    let dir = two_scenes("bad");
    let scenes = dir.join("scenes");
    let sc = scenes.to_str().unwrap();
    let settle = dir.join("sim.json");
    std::fs::write(&settle, r#"{"settle_y": -1.0}"#).unwrap();
    for (args, message) in [
        (vec!["--world", "log-replay"], "world"),
        (vec!["--world", "predictor"], "world"),
        (
            vec!["--predictor", "constant-velocity"],
            "constant-velocity",
        ),
        (vec!["--runs", "0"], "runs"),
        (vec!["--threads", "0"], "threads"),
        (vec!["--max-steps", "0"], "max_steps"),
        (vec!["--config", settle.to_str().unwrap()], "settle_y"),
        (vec!["--world-predictor", "student"], "teacher"),
        (
            vec!["--world", "log_replay", "--world-predictor", "teacher"],
            "log_replay",
        ),
        (vec!["--idm", "assets/worlds/idm.json"], "idm"),
        (
            vec!["--world", "idm", "--idm", "/nonexistent/idm.json"],
            "/nonexistent/idm.json",
        ),
        (vec!["--fault-brake-limit", "0"], "fault_brake_limit"),
    ] {
        let mut all = vec!["simulate", "--scenes", sc];
        all.extend(&args);
        let o = nudge(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} was accepted");
        assert!(err.contains(message), "{args:?}: {err}");
    }
    assert!(Path::new(&dir).exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
