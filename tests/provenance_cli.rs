//! `nudge simulate --out` writes `provenance.json` beside the records (what made them), prints
//! its per-step listing without Rust debug text, and draws no progress bar on a stderr that is
//! not a terminal.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn sha(path: &std::path::Path) -> String {
    nudge::provenance::sha256_hex(&std::fs::read(path).unwrap())
}

#[test]
fn simulate_out_carries_provenance_and_plain_output() {
    let dir = std::env::temp_dir().join(format!("nudge-provenance-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let name = "us101-11_1-t02.1-ego144.safetensors";
    std::fs::copy(repo().join("assets/scenes").join(name), scenes.join(name)).unwrap();
    let idm = repo().join("assets/worlds/idm.json");
    let out = dir.join("out");
    let args = [
        "simulate",
        "--scenes",
        scenes.to_str().unwrap(),
        "--world",
        "idm",
        "--idm",
        idm.to_str().unwrap(),
        "--seed",
        "7",
        "--max-steps",
        "2",
        "--threads",
        "1",
        "--out",
        out.to_str().unwrap(),
    ];
    let o = Command::new(env!("CARGO_BIN_EXE_nudge"))
        .current_dir(repo())
        .args(args)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    // One run: its listing is printed; two steps cannot settle (settle_steps is 3).
    assert!(
        stdout.contains("success false (not settled in the target lane), collision"),
        "{stdout}"
    );
    assert!(
        !stdout.contains("Some(") && !stdout.contains("None"),
        "{stdout}"
    );
    // stderr is a pipe here: no progress bar.
    assert!(!stderr.contains("runs,"), "{stderr}");

    let p: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("provenance.json")).unwrap())
            .unwrap();
    assert_eq!(p["schema"], "nudge.provenance/1");
    assert_eq!(p["nudge_version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(p["git_sha"], nudge::GIT_SHA);
    let command: Vec<&str> = p["command"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(&command[1..], &args);
    assert_eq!(p["sim_config"]["world"], "idm");
    assert_eq!(p["sim_config"]["max_steps"], 2);
    assert_eq!(p["world"]["file"]["sha256"], sha(&idm));
    assert_eq!(
        p["predictor"]["file"]["sha256"],
        sha(&repo().join("assets/models/student.safetensors"))
    );
    assert_eq!(p["scenes"]["count"], 1);
    assert_eq!(p["scenes"]["files"][0]["sha256"], sha(&scenes.join(name)));
    let list = format!("{name} {}\n", sha(&scenes.join(name)));
    assert_eq!(
        p["scenes"]["list_sha256"],
        nudge::provenance::sha256_hex(list.as_bytes())
    );
    assert_eq!(p["seeds"]["runs"], serde_json::json!([7]));
    assert_eq!(p["threads"], 1);
    assert!(p["machine"]["cores"].as_u64().unwrap() >= 1);
    std::fs::remove_dir_all(&dir).unwrap();
}
