//! The generated reference pages are up to date: `docs/reference/settings.md` is exactly what
//! `nudge settings --format markdown` prints from the Rust settings (regenerate it with
//! `make reference-docs`).

use std::path::Path;
use std::process::Command;

use nudge::sim::describe::{settings_json, settings_markdown};

const PAGE: &str = "docs/reference/settings.md";

#[test]
fn settings_page_is_up_to_date() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(PAGE);
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == settings_markdown(),
        "{PAGE} is out of date with the Rust settings: run `make reference-docs` and commit it"
    );
}

#[test]
fn settings_command_prints_the_page_and_the_json() {
    let run = |format: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_nudge"))
            .args(["settings", "--format", format])
            .output()
            .expect("run nudge settings");
        assert!(out.status.success(), "nudge settings --format {format}");
        String::from_utf8(out.stdout).expect("UTF-8")
    };
    assert_eq!(run("markdown"), settings_markdown());
    let json: serde_json::Value = serde_json::from_str(&run("json")).expect("JSON");
    assert_eq!(json, settings_json());
    assert_eq!(json["SimConfig"].as_array().map(Vec::len), Some(14));
}
