//! The short mode of the fuzzing suite (`nudge-fuzz`): a few seconds of seeded mutations of
//! weights, scenario and settings files and planning problems, the same tries on every machine,
//! every outcome a typed error or a valid result.
#![allow(clippy::print_stderr)]

use nudge_fuzz::{Config, repo_root, run};

#[test]
fn fuzz_short_mode_finds_no_defect() {
    let cfg = Config::short(repo_root());
    let report = run(&cfg);
    eprint!("{}", report.render());
    assert_eq!(report.defects(), 0, "{}", report.render());
    for (target, stats) in &report.targets {
        assert_eq!(
            stats.tries,
            Config::SHORT_TRIES,
            "{}: every machine runs the same tries",
            target.name()
        );
    }
}
