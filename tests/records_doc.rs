//! `docs/records.md` documents exactly what the record writer emits: every column of
//! `runs.csv`, `steps.csv` and `collisions.csv` (in order), every field of `records.json` and
//! of `provenance.json` — each emitted one is listed, each listed one is emitted.
#![allow(clippy::unwrap_used)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use nudge::planner::{LaneViolation, LaneViolationKind, PlannerSettings, Scenario};
use nudge::provenance::{Inputs, Provenance};
use nudge::sim::metrics::NuplanCollision;
use nudge::sim::{
    COLLISION_COLUMNS, Cancel, Collision, Keep, Predictors, RUN_COLUMNS, STEP_COLUMNS, SimConfig,
    World, collision_table, run_specs, run_table, simulate_many, step_table,
};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The first back-quoted name of every table row of the section `## \`file\`` of
/// docs/records.md, in order.
fn documented(file: &str) -> Vec<String> {
    let text = std::fs::read_to_string(repo().join("docs/records.md")).unwrap();
    let heading = format!("## `{file}`");
    let start = text
        .find(&heading)
        .unwrap_or_else(|| panic!("no section {heading}"));
    let body = &text[start + heading.len()..];
    let body = &body[..body.find("\n## ").unwrap_or(body.len())];
    body.lines()
        .filter(|l| l.starts_with("| `"))
        .map(|l| l[3..].split('`').next().unwrap().to_string())
        .collect()
}

/// Every key path of `v` (`a.b`, `a[].b` for the elements of an array `a`), and the paths at
/// which an object was found (`""` the root); `opaque` paths are not descended into.
fn key_paths(
    v: &serde_json::Value,
    at: &str,
    opaque: &[&str],
    keys: &mut BTreeSet<String>,
    objects: &mut BTreeSet<String>,
) {
    match v {
        serde_json::Value::Object(m) => {
            objects.insert(at.to_string());
            for (k, x) in m {
                let p = if at.is_empty() {
                    k.clone()
                } else {
                    format!("{at}.{k}")
                };
                keys.insert(p.clone());
                if !opaque.contains(&p.as_str()) {
                    key_paths(x, &p, opaque, keys, objects);
                }
            }
        }
        serde_json::Value::Array(a) => {
            for x in a {
                key_paths(x, &format!("{at}[]"), opaque, keys, objects);
            }
        }
        _ => {}
    }
}

/// Every emitted path is documented; every documented path whose parent object was emitted
/// is emitted.
fn check_fields(file: &str, values: &[serde_json::Value], opaque: &[&str]) {
    let (mut keys, mut objects) = (BTreeSet::new(), BTreeSet::new());
    for v in values {
        key_paths(v, "", opaque, &mut keys, &mut objects);
    }
    let doc: BTreeSet<String> = documented(file).into_iter().collect();
    let undocumented: Vec<&String> = keys.difference(&doc).collect();
    assert!(
        undocumented.is_empty(),
        "{file}: emitted but not in docs/records.md: {undocumented:?}"
    );
    let parent = |p: &str| p.rsplit_once('.').map_or("", |(a, _)| a).to_string();
    let missing: Vec<&String> = doc
        .iter()
        .filter(|p| objects.contains(&parent(p)) && !keys.contains(*p))
        .collect();
    assert!(
        missing.is_empty(),
        "{file}: in docs/records.md but not emitted: {missing:?}"
    );
    // Every documented path is reachable: its parent is the root or a documented path.
    for p in &doc {
        let up = parent(p);
        let up = up.strip_suffix("[]").unwrap_or(&up);
        assert!(
            up.is_empty() || doc.contains(up),
            "{file}: {p} has no documented parent"
        );
    }
}

#[test]
fn the_csv_columns_are_documented_in_order() {
    assert_eq!(documented("runs.csv"), RUN_COLUMNS);
    assert_eq!(documented("steps.csv"), STEP_COLUMNS);
    assert_eq!(documented("collisions.csv"), COLLISION_COLUMNS);
}

#[test]
fn records_json_and_provenance_json_fields_are_documented() {
    let scenes_dir = repo().join("assets/scenes");
    let mut paths = Scenario::paths_in(&scenes_dir).unwrap();
    paths.truncate(2);
    let scenes: Vec<Scenario> = paths
        .iter()
        .map(|p| Scenario::from_file(p).unwrap())
        .collect();
    let settings = PlannerSettings::default();
    let cfg = SimConfig {
        max_steps: 4,
        ..SimConfig::default()
    };
    let assets = repo().join("assets");
    let predictors = Predictors::resolve("student", cfg.world, None, None, &assets, 6).unwrap();
    let specs = run_specs(scenes.len(), 1, 0, None).unwrap();
    let keep = Keep {
        examples: false,
        traces: true,
    };
    let outputs = simulate_many(
        &scenes,
        &specs,
        &settings,
        &cfg,
        &predictors,
        keep,
        &Cancel::new(),
    );
    // The tables the CSV files are written from have the documented columns.
    let names =
        |t: nudge::sim::Table| -> Vec<&str> { t.columns().iter().map(|(n, _)| *n).collect() };
    assert_eq!(names(run_table(&scenes, &outputs)), documented("runs.csv"));
    assert_eq!(names(step_table(&outputs)), documented("steps.csv"));
    assert_eq!(
        names(collision_table(&scenes, &outputs)),
        documented("collisions.csv")
    );

    let mut records: Vec<_> = outputs.into_iter().map(|o| o.result.unwrap()).collect();
    // The optional parts these short runs may not reach: a collision event and a plan into a
    // lane that has ended.
    records[0].collisions.push(Collision {
        step: 1,
        other: 1,
        at_fault: true,
        other_behind: false,
        rear_hit: false,
        ego_in_lane: true,
        ego_accel: 0.5,
        dx: 3.0,
        dy: 0.2,
        ego_heading: 0.0,
        other_heading: 0.0,
        ego_v: 20.0,
        other_v: 15.0,
        nuplan_type: NuplanCollision::ActiveFront,
        nuplan_at_fault: true,
    });
    records[0].steps[0].lane_violation = Some(LaneViolation {
        step: 2,
        lane: 0,
        kind: LaneViolationKind::Ended,
        x: 10.0,
    });
    let json: Vec<serde_json::Value> = records
        .iter()
        .map(|r| serde_json::to_value(r).unwrap())
        .collect();
    check_fields("records.json", &json, &[]);

    // provenance.json of a teacher world with settings and config files, and of an idm world.
    let dir = std::env::temp_dir().join(format!("nudge-records-doc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let settings_file = dir.join("settings.json");
    let config_file = dir.join("config.json");
    std::fs::write(&settings_file, "{}").unwrap();
    std::fs::write(&config_file, "{}").unwrap();
    let provenance = |world: World, files: bool| {
        let cfg = SimConfig { world, ..cfg };
        let inputs = Inputs {
            settings: (&settings, files.then_some(settings_file.as_path())),
            config: (&cfg, files.then_some(config_file.as_path())),
            assets: &assets,
            predictor: Path::new("student"),
            world_predictor: None,
            idm: None,
            scene_paths: &paths,
            specs: &specs,
            seed: (0, 1),
            threads: 1,
        };
        let p = Provenance::new(&inputs, vec!["nudge".into(), "simulate".into()]).unwrap();
        serde_json::from_str::<serde_json::Value>(&p.to_json().unwrap()).unwrap()
    };
    let teacher = provenance(World::Teacher, true);
    let idm = provenance(World::Idm, false);
    let sha = |p: &Path| nudge::provenance::sha256_hex(&std::fs::read(p).unwrap());
    assert_eq!(
        teacher["world"]["model"]["file"]["sha256"],
        sha(&assets.join("models/teacher.safetensors"))
    );
    assert_eq!(
        idm["world"]["file"]["sha256"],
        sha(&assets.join("worlds/idm.json"))
    );
    assert_eq!(
        teacher["predictor"]["file"]["sha256"],
        sha(&assets.join("models/student.safetensors"))
    );
    assert_eq!(teacher["scenes"]["files"][1]["sha256"], sha(&paths[1]));
    check_fields(
        "provenance.json",
        &[teacher, idm],
        &["settings", "sim_config"],
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
