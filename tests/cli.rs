//! The `nudge simulate` CLI writes exactly the shared columns (`nudge::sim::columns`)
//! of the runs the library computes for the same scenes, seeds and settings (wall-clock
//! timings excepted), and refuses bad arguments with the library's typed messages.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use nudge::planner::{PlannerSettings, Scenario};
use nudge::sim::{
    COLLISION_COLUMNS, RUN_COLUMNS, STEP_COLUMNS, Table, collision_table, run_table, step_table,
};
use nudge::sim::{Cancel, Keep, Predictors, SimConfig, World, run_specs, simulate_many};

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
    let outputs = simulate_many(
        &loaded,
        &specs,
        &settings,
        &cfg,
        &predictors,
        Keep::default(),
        &Cancel::new(),
    );
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
        (vec!["--stall-progress", "2"], "stall_progress"),
        (vec!["--start-abort-after", "5000"], "start_abort_after"),
        (vec!["--crawl-fraction", "2"], "crawl_fraction"),
        (
            vec!["--replay-lateral-decay", "1.5"],
            "replay_lateral_decay",
        ),
        (vec!["--crawl-fraction", "NaN"], "crawl_fraction"),
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

/// Runs `nudge simulate` on the two scenes of `dir` with `args`; (exit code, stdout, stderr).
fn simulate_in(dir: &Path, args: &[&str]) -> (Option<i32>, String, String) {
    let scenes = dir.join("scenes");
    let mut all = vec![
        "simulate",
        "--scenes",
        scenes.to_str().unwrap(),
        "--threads",
        "1",
        "--max-steps",
        "2",
    ];
    all.extend(args);
    let o = nudge(&all);
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Settings that do not fit the predictors (a horizon other than the student's 6 steps, a
/// time step other than the 0.3 s of the networks and scenes) are refused before any run
/// starts, with exit code 1 and the setting named; nothing is printed as a summary.
#[test]
fn cli_refuses_settings_that_do_not_fit_the_predictors_before_any_run() {
    let dir = two_scenes("fit");
    for (json, field, predictor) in [
        (r#"{"horizon": 7}"#, "horizon", "student"),
        (r#"{"horizon": 10}"#, "horizon", "student"),
        (r#"{"dt": 0.5}"#, "dt", "teacher"),
        (r#"{"dt": 0.5}"#, "dt", "student"),
        (r#"{"dt": 0.2}"#, "dt", "constant_velocity"),
    ] {
        let path = dir.join("settings.json");
        std::fs::write(&path, json).unwrap();
        let (code, stdout, stderr) = simulate_in(
            &dir,
            &[
                "--settings",
                path.to_str().unwrap(),
                "--predictor",
                predictor,
            ],
        );
        assert_eq!(code, Some(1), "{json}: {stdout}{stderr}");
        assert!(
            stderr.contains(&format!("`{field}`")),
            "{json}: the message does not name {field}: {stderr}"
        );
        assert!(
            !stdout.contains("runs "),
            "{json}: runs were started: {stdout}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A copy of scene `name` in `dir/scenes` whose agent 1 jumps 50 m forward in its logged
/// future at step 1: the scene loads (logged futures are only checked for finite, in-range
/// coordinates), but a log-replay run on it cannot plan its second step (the shifted history
/// moves 50 m in one step, which the predictors refuse).
fn jumping_future_scene(dir: &Path, name: &str) {
    let path = dir.join("scenes").join(format!("{name}.safetensors"));
    let mut bytes = std::fs::read(&path).unwrap();
    let n = usize::try_from(u64::from_le_bytes(bytes[..8].try_into().unwrap())).unwrap();
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let future = &header["future"];
    assert_eq!(future["dtype"], "F64");
    let start = 8 + n + usize::try_from(future["data_offsets"][0].as_u64().unwrap()).unwrap();
    let steps = usize::try_from(future["shape"][1].as_u64().unwrap()).unwrap();
    // future[1, 0, 0] (agent 1, step 1, x).
    let at = start + (steps * 2) * 8;
    let x = f64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    bytes[at..at + 8].copy_from_slice(&(x + 50.0).to_le_bytes());
    std::fs::write(&path, bytes).unwrap();
    let sc = Scenario::from_file(&path).unwrap();
    assert!(sc.future_at(1, 1).is_some(), "agent 1's step 1 is logged");
}

/// A run that could not run is a failure: the records of the runs that did run are written,
/// the summary says how many could not run and why, and the exit code is 3.
#[test]
fn cli_exits_non_zero_when_a_run_could_not_run() {
    let dir = two_scenes("failing");
    jumping_future_scene(&dir, "us101-11_1-t02.1-ego144");
    let out = dir.join("out");
    let args = [
        "--predictor",
        "constant_velocity",
        "--world",
        "log_replay",
        "--settle-steps",
        "3",
    ];
    let mut with_out = args.to_vec();
    with_out.extend(["--out", out.to_str().unwrap()]);
    let (code, stdout, stderr) = simulate_in(&dir, &with_out);
    assert_eq!(code, Some(3), "{stdout}{stderr}");
    assert!(stdout.contains("(+1 that could not run)"), "{stdout}");
    assert!(
        stderr.contains("1 of 2 runs could not run")
            && stderr.contains("us101-11_1-t02.1-ego144")
            && stderr.contains("observed steps"),
        "the summary does not say which run failed and why: {stderr}"
    );
    let runs = std::fs::read_to_string(out.join("runs.csv")).unwrap();
    assert_eq!(runs.lines().count(), 3, "{runs}");
    // Every run could not run: exit 3 as well, never 0.
    std::fs::remove_file(dir.join("scenes/us101-8_1-t02.1-ego56.safetensors")).unwrap();
    let (code, stdout, stderr) = simulate_in(&dir, &args);
    assert_eq!(code, Some(3), "{stdout}{stderr}");
    assert!(stderr.contains("1 of 1 runs could not run"), "{stderr}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--out` naming an existing file is refused before any run (it used to fail only after
/// every run had finished).
#[test]
fn cli_refuses_an_output_path_that_is_a_file_before_any_run() {
    let dir = two_scenes("outfile");
    let file = dir.join("taken");
    std::fs::write(&file, "x").unwrap();
    let (code, stdout, stderr) = simulate_in(&dir, &["--out", file.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stdout}{stderr}");
    assert!(stderr.contains("taken"), "{stderr}");
    assert!(!stdout.contains("runs "), "runs were started: {stdout}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Settings and closed-loop settings files: a repeated key is refused naming it, and a file
/// larger than the documented bound is refused before it is read.
#[test]
fn cli_reads_settings_files_bounded_and_refuses_repeated_keys() {
    let dir = two_scenes("files");
    let dup = dir.join("dup.json");
    std::fs::write(&dup, r#"{"max_steps": 1, "max_steps": 2}"#).unwrap();
    let (code, _, stderr) = simulate_in(&dir, &["--config", dup.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("duplicate") && stderr.contains("max_steps"),
        "{stderr}"
    );
    let sdup = dir.join("sdup.json");
    std::fs::write(&sdup, r#"{"w_y": 1.0, "w_y": 2.0}"#).unwrap();
    let (code, _, stderr) = simulate_in(&dir, &["--settings", sdup.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("duplicate") && stderr.contains("w_y"),
        "{stderr}"
    );
    let big = dir.join("big.json");
    let mut text = String::from("{\"max_steps\": 2");
    text.push_str(&" ".repeat(2 << 20));
    text.push('}');
    std::fs::write(&big, text).unwrap();
    for flag in ["--config", "--settings"] {
        let (code, _, stderr) = simulate_in(&dir, &[flag, big.to_str().unwrap()]);
        assert_eq!(code, Some(1), "{stderr}");
        assert!(
            stderr.contains("big.json") && stderr.contains("limit"),
            "{flag}: {stderr}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--animate` traces the runs (records.json gains each step's trace) and writes one GIF per
/// animated run into <out>/animations; without `--out` it is refused before any run.
#[test]
fn cli_animates_traced_runs_into_the_output_directory() {
    let dir = two_scenes("animate");
    let (code, stdout, stderr) = simulate_in(&dir, &["--animate"]);
    assert_eq!(code, Some(1), "{stdout}{stderr}");
    assert!(stderr.contains("--animate needs --out"), "{stderr}");
    assert!(!stdout.contains("runs "), "runs were started: {stdout}");
    let out = dir.join("out");
    let args = [
        "--out",
        out.to_str().unwrap(),
        "--animate",
        "--animate-runs",
        "1",
    ];
    let (code, stdout, stderr) = simulate_in(&dir, &args);
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    let gifs: Vec<_> = std::fs::read_dir(out.join("animations"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.ends_with(".gif"))
        .collect();
    assert_eq!(gifs, ["us101-11_1-t02.1-ego144-seed0.gif"]);
    assert!(stdout.contains("animation: "), "{stdout}");
    let records = std::fs::read_to_string(out.join("records.json")).unwrap();
    assert_eq!(records.matches("\"trace\"").count(), 4, "2 runs × 2 steps");
    // The GIF: one frame per state (2 steps + the end).
    let mut d = gif::DecodeOptions::new()
        .read_info(std::fs::File::open(out.join("animations").join(&gifs[0])).unwrap())
        .unwrap();
    let mut frames = 0;
    while d.read_next_frame().unwrap().is_some() {
        frames += 1;
    }
    assert_eq!(frames, 3);
    // Without --animate the records carry no trace.
    let plain = dir.join("plain");
    let (code, _, _) = simulate_in(&dir, &["--out", plain.to_str().unwrap()]);
    assert_eq!(code, Some(0));
    let records = std::fs::read_to_string(plain.join("records.json")).unwrap();
    assert!(!records.contains("\"trace\""));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--ablate-reaction` runs the library's runs with `ablate_reaction` on (over the settings
/// file): the same columns, and the planner calls its predictor at most once per step (the
/// keep-lane path), while the aware planner calls it for every candidate.
#[test]
fn cli_ablate_reaction_is_the_setting() {
    let dir = two_scenes("ablate");
    let scenes = dir.join("scenes");
    let calls = |ablate: bool| {
        let out = dir.join(if ablate { "ablated" } else { "aware" });
        let mut args = vec![
            "simulate",
            "--scenes",
            scenes.to_str().unwrap(),
            "--predictor",
            "student",
            "--max-steps",
            "3",
            "--threads",
            "1",
            "--out",
            out.to_str().unwrap(),
        ];
        if ablate {
            args.push("--ablate-reaction");
        }
        let o = nudge(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let steps = std::fs::read_to_string(out.join("steps.csv")).unwrap();
        let rows = without_timing(&steps);
        let col = rows[0].iter().position(|c| c == "predictor_calls").unwrap();
        let calls: Vec<usize> = rows[1..].iter().map(|r| r[col].parse().unwrap()).collect();
        (rows, calls)
    };
    let (ablated, ablated_calls) = calls(true);
    let (_, aware_calls) = calls(false);
    assert!(ablated_calls.iter().all(|&c| c <= 1), "{ablated_calls:?}");
    assert!(aware_calls.iter().any(|&c| c > 1), "{aware_calls:?}");

    let (loaded, bad) = Scenario::load_dir(&scenes).unwrap();
    assert!(bad.is_empty());
    let settings = {
        let mut s = PlannerSettings::default();
        s.safety.ablate_reaction = true;
        s
    };
    let cfg = SimConfig {
        max_steps: 3,
        ..SimConfig::default()
    };
    let specs = run_specs(loaded.len(), 1, 0, None).unwrap();
    let predictors =
        Predictors::resolve("student", cfg.world, None, None, &repo().join("assets"), 6).unwrap();
    let outputs = simulate_many(
        &loaded,
        &specs,
        &settings,
        &cfg,
        &predictors,
        Keep::default(),
        &Cancel::new(),
    );
    assert_eq!(ablated, without_timing(&csv(&step_table(&outputs))));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue 49 class 8: the records are written to temporary files and renamed into place, so a
/// symbolic link planted at an output name is replaced, its target untouched (before: the
/// target was overwritten); the set carries a `outputs.sha256` manifest of every file.
#[cfg(unix)]
#[test]
fn cli_replaces_planted_symlinks_and_writes_a_verified_set() {
    let dir = two_scenes("symlink");
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, "precious").unwrap();
    for name in [
        "records.json",
        "steps.csv",
        "runs.csv",
        "collisions.csv",
        "provenance.json",
    ] {
        std::os::unix::fs::symlink(&victim, out.join(name)).unwrap();
    }
    let (code, stdout, stderr) = simulate_in(&dir, &["--out", out.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    for name in [
        "records.json",
        "steps.csv",
        "runs.csv",
        "collisions.csv",
        "provenance.json",
    ] {
        let meta = std::fs::symlink_metadata(out.join(name)).unwrap();
        assert!(meta.file_type().is_file(), "{name} is still a link");
    }
    let manifest = std::fs::read_to_string(out.join("outputs.sha256")).unwrap();
    assert_eq!(manifest.lines().count(), 5, "{manifest}");
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| {
            let n = e.unwrap().file_name().to_string_lossy().into_owned();
            n.contains(".tmp").then_some(n)
        })
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue 49 class 12: a failure after the runs (here the animations folder cannot be made)
/// exits 4, "the runs ran but an output could not be written", not 1, which the help
/// reserves for "refused before any run"; the records are written.
#[test]
fn cli_output_failure_after_the_runs_is_not_a_refusal() {
    let dir = two_scenes("animfail");
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("animations"), "in the way").unwrap();
    let args = ["--out", out.to_str().unwrap(), "--animate"];
    let (code, stdout, stderr) = simulate_in(&dir, &args);
    assert_eq!(code, Some(4), "{stdout}{stderr}");
    assert!(stderr.contains("animations"), "{stderr}");
    assert!(out.join("records.json").is_file());
    std::fs::remove_dir_all(&dir).unwrap();
}
