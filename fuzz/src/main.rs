//! The fuzzing suite of nudge's input files (weights, scenarios, settings) and planning
//! problems: structure-aware mutations, seeded and deterministic, judged by per-target oracles
//! (see the library, `lib.rs`).
//!
//! ```text
//! cargo run --release -p nudge-fuzz -- [--seconds S] [--tries N] [--seed K]
//!     [--target weights|scenarios|settings|plan|commonroad|world]... [--replay TARGET:TRY]
//!     [--lenient-rollout]
//! ```
//!
//! A plan whose states are not the nonlinear roll-out of its inputs (speed clamped at 0) is a
//! defect: the planner guarantees it. `--lenient-rollout` counts such plans apart instead.
//!
//! `--seconds` is the budget per target (default 60), `--tries` caps the tries per target.
//! Prints the counts per target and exits 1 when any defect was found (a hang exits 3 from
//! the watchdog). `make fuzz FUZZ_SECONDS=…` runs it; `make test` runs the short mode
//! (`fuzz/tests/short_mode.rs`).
#![allow(clippy::print_stdout, clippy::print_stderr)]

use nudge_fuzz::{Config, Target};

fn main() {
    let repo = nudge_fuzz::repo_root();
    let mut cfg = Config {
        seconds_per_target: 60.0,
        max_tries: None,
        verbose: true,
        ..Config::short(repo.clone())
    };
    let mut targets = Vec::new();
    let mut replay = None;
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut it = args.iter();
    let fail = |msg: String| -> ! {
        eprintln!("fuzz: {msg}");
        std::process::exit(2)
    };
    let target_of = |s: &str| {
        Target::ALL
            .into_iter()
            .find(|t| t.name() == s)
            .unwrap_or_else(|| {
                fail(format!(
                    "unknown target {s:?} (weights, scenarios, settings, plan, commonroad, world)"
                ))
            })
    };
    while let Some(a) = it.next() {
        let mut value = || {
            it.next()
                .cloned()
                .unwrap_or_else(|| fail(format!("{a} needs a value")))
        };
        match a.as_str() {
            "--seconds" => {
                cfg.seconds_per_target = value()
                    .parse()
                    .unwrap_or_else(|e| fail(format!("--seconds: {e}")));
            }
            "--tries" => {
                cfg.max_tries = Some(
                    value()
                        .parse()
                        .unwrap_or_else(|e| fail(format!("--tries: {e}"))),
                );
            }
            "--seed" => {
                cfg.seed = value()
                    .parse()
                    .unwrap_or_else(|e| fail(format!("--seed: {e}")));
            }
            "--target" => targets.push(target_of(&value())),
            "--lenient-rollout" => cfg.strict_rollout = false,
            "--replay" => {
                let v = value();
                let (t, i) = v
                    .split_once(':')
                    .unwrap_or_else(|| fail("--replay takes TARGET:TRY".into()));
                let i: u64 = i.parse().unwrap_or_else(|e| fail(format!("--replay: {e}")));
                replay = Some((target_of(t), i));
            }
            other => fail(format!("unknown argument {other:?}")),
        }
    }
    if !targets.is_empty() {
        cfg.targets = targets;
    }
    if let Some((t, i)) = replay {
        println!("{}", nudge_fuzz::replay(&repo, cfg.seed, t, i));
        return;
    }
    println!(
        "fuzzing {} for {} s each (seed {}, tries {})",
        cfg.targets
            .iter()
            .map(|t| t.name())
            .collect::<Vec<_>>()
            .join(", "),
        cfg.seconds_per_target,
        cfg.seed,
        cfg.max_tries
            .map_or("unbounded".to_owned(), |n| n.to_string())
    );
    let report = nudge_fuzz::run(&cfg);
    print!("{}", report.render());
    if report.defects() > 0 {
        std::process::exit(1);
    }
}
