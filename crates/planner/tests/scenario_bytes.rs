//! The scenario writer ([`Scenario::to_bytes`]) and the reader agree: every shipped scene
//! ("nudge.scenario/1" and the "/2" merges with lane extents) reads back equal from its image,
//! and a scene that breaks a reader check is refused from its image by that check.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};

use nudge_planner::{Scenario, ScenarioError};

fn shipped() -> Vec<PathBuf> {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/scenes");
    let mut paths = Scenario::paths_in(&assets).unwrap();
    paths.extend(Scenario::paths_in(assets.join("merge")).unwrap_or_default());
    paths
}

#[test]
fn every_shipped_scene_reads_back_from_its_image() {
    let paths = shipped();
    assert!(paths.len() >= 10);
    let mut with_extents = 0;
    for p in &paths {
        let sc = Scenario::from_file(p).unwrap();
        with_extents += usize::from(sc.lane_extents.is_some());
        let bytes = sc.to_bytes().unwrap();
        let back = Scenario::from_bytes(&bytes, p).unwrap();
        assert_eq!(back, sc, "{}", p.display());
    }
    assert!(
        with_extents > 0,
        "no \"nudge.scenario/2\" scene among {}",
        paths.len()
    );
}

#[test]
fn the_image_of_a_bad_scene_is_refused_by_the_reader() {
    let sc = Scenario::from_file(&shipped()[0]).unwrap();
    let mut fast = sc.clone();
    fast.speed[1] = 70.0;
    let err = Scenario::from_bytes(&fast.to_bytes().unwrap(), Path::new("fast")).unwrap_err();
    assert!(
        matches!(
            err,
            ScenarioError::Implausible {
                agent: 1,
                field: "speed",
                ..
            }
        ),
        "{err}"
    );
    let mut short = sc.clone();
    short.history.pop();
    let err = short.to_bytes().unwrap_err();
    assert!(
        matches!(
            err,
            ScenarioError::BadValue {
                tensor: "history",
                ..
            }
        ),
        "{err}"
    );
}
