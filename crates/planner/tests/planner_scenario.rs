//! The scenario reader on the real shipped scenes and on files built here with defects.
#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nudge_planner::{Scenario, ScenarioError};
use safetensors::{Dtype, tensor::TensorView};

fn shipped() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets/scenes")
}

#[test]
fn shipped_scenes_read() {
    let (ok, bad) = Scenario::load_dir(shipped()).unwrap();
    assert!(bad.is_empty(), "{bad:?}");
    assert!(ok.len() >= 5);
    for s in &ok {
        assert!(s.n_agents >= 2 && s.lane_centres.len() >= 2);
        assert_eq!(s.history.len(), s.n_agents * 16);
    }
}

/// Tensors of a valid two-vehicle scene: (name, dtype, shape, little-endian bytes).
fn valid() -> Vec<(String, Dtype, Vec<usize>, Vec<u8>)> {
    let f = |v: &[f64]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let i = |v: &[i64]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let mut hist = Vec::new();
    for (x0, y) in [(0.0, 0.0), (20.0, 3.7)] {
        for t in 0..8 {
            hist.push(x0 + 3.0 * t as f64);
            hist.push(y);
        }
    }
    let future: Vec<f64> = (0..2 * 6 * 2).map(|k| k as f64).collect();
    vec![
        ("history".into(), Dtype::F64, vec![2, 8, 2], f(&hist)),
        ("heading".into(), Dtype::F64, vec![2], f(&[0.0, 0.0])),
        ("speed".into(), Dtype::F64, vec![2], f(&[10.0, 10.0])),
        (
            "size".into(),
            Dtype::F64,
            vec![2, 2],
            f(&[4.5, 1.9, 4.5, 1.9]),
        ),
        ("future".into(), Dtype::F64, vec![2, 6, 2], f(&future)),
        ("future_valid".into(), Dtype::U8, vec![2, 6], vec![1; 12]),
        ("lane_centres".into(), Dtype::F64, vec![2], f(&[0.0, 3.7])),
        (
            "lane_bounds".into(),
            Dtype::F64,
            vec![3],
            f(&[-1.85, 1.85, 5.55]),
        ),
        ("ego_lane".into(), Dtype::I64, vec![1], i(&[0])),
        ("agent_ids".into(), Dtype::I64, vec![2], i(&[7, 9])),
    ]
}

fn write(tensors: &[(String, Dtype, Vec<usize>, Vec<u8>)], schema: Option<&str>) -> Vec<u8> {
    let views: Vec<(String, TensorView<'_>)> = tensors
        .iter()
        .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).unwrap()))
        .collect();
    let mut meta = HashMap::new();
    if let Some(s) = schema {
        meta.insert("schema".to_string(), s.to_string());
    }
    meta.insert("dt".to_string(), "0.3".to_string());
    safetensors::serialize(views, Some(meta)).unwrap()
}

fn read(bytes: &[u8]) -> Result<Scenario, ScenarioError> {
    Scenario::from_bytes(bytes, Path::new("test.safetensors"))
}

#[test]
fn valid_built_scene_reads() {
    let s = read(&write(&valid(), Some("nudge.scenario/1"))).unwrap();
    assert_eq!(s.n_agents, 2);
    assert_eq!(s.position(1, 7), [41.0, 3.7]);
    assert_eq!(s.future_at(0, 1), Some([0.0, 1.0]));
    assert_eq!(s.road(), [-1.85, 5.55]);
}

#[test]
fn defects_are_typed_errors() {
    let ok = valid();
    // Wrong / missing schema.
    assert!(matches!(
        read(&write(&ok, Some("other/2"))),
        Err(ScenarioError::WrongSchema { .. })
    ));
    assert!(matches!(
        read(&write(&ok, None)),
        Err(ScenarioError::WrongSchema { found: None, .. })
    ));
    // Missing tensor.
    let missing: Vec<_> = ok.iter().filter(|t| t.0 != "speed").cloned().collect();
    assert!(matches!(
        read(&write(&missing, Some("nudge.scenario/1"))),
        Err(ScenarioError::MissingTensor {
            tensor: "speed",
            ..
        })
    ));
    // Wrong shape.
    let mut shape = ok.clone();
    shape[1] = ("heading".into(), Dtype::F64, vec![1, 2], shape[1].3.clone());
    assert!(matches!(
        read(&write(&shape, Some("nudge.scenario/1"))),
        Err(ScenarioError::WrongShape {
            tensor: "heading",
            ..
        })
    ));
    // Wrong dtype.
    let mut dtype = ok.clone();
    dtype[8] = (
        "ego_lane".into(),
        Dtype::F64,
        vec![1],
        0.0f64.to_le_bytes().to_vec(),
    );
    assert!(matches!(
        read(&write(&dtype, Some("nudge.scenario/1"))),
        Err(ScenarioError::WrongDtype {
            tensor: "ego_lane",
            ..
        })
    ));
    // NaN.
    let mut nan = ok.clone();
    nan[2].3[8..16].copy_from_slice(&f64::NAN.to_le_bytes());
    assert!(matches!(
        read(&write(&nan, Some("nudge.scenario/1"))),
        Err(ScenarioError::NonFinite {
            tensor: "speed",
            index: 1,
            ..
        })
    ));
    // Ego overlapping the other vehicle: move agent 1 onto the ego's last position.
    let mut overlap = ok.clone();
    let mut hist: Vec<f64> = overlap[0]
        .3
        .chunks(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    hist[16 + 14] = hist[14] + 2.0;
    hist[16 + 15] = hist[15] + 0.5;
    overlap[0].3 = hist.iter().flat_map(|x| x.to_le_bytes()).collect();
    assert!(matches!(
        read(&write(&overlap, Some("nudge.scenario/1"))),
        Err(ScenarioError::EgoOverlap {
            agent: 1,
            id: 9,
            ..
        })
    ));
    // Ego lane out of range.
    let mut lane = ok.clone();
    lane[8].3 = 5i64.to_le_bytes().to_vec();
    assert!(matches!(
        read(&write(&lane, Some("nudge.scenario/1"))),
        Err(ScenarioError::BadValue {
            tensor: "ego_lane",
            ..
        })
    ));
    // Garbage bytes.
    assert!(matches!(
        read(b"not a file"),
        Err(ScenarioError::NotSafetensors { .. })
    ));
    assert!(matches!(
        Scenario::from_file("/nonexistent/x.safetensors"),
        Err(ScenarioError::Io { .. })
    ));
}

/// The valid scene as "nudge.scenario/2": lane 0 (the ego's, x = 21 m now) ends at 60 m, lane 1
/// runs from -50 m to 200 m where the lane map stops.
fn valid_v2(extent: [f64; 4], real: [u8; 4]) -> Vec<(String, Dtype, Vec<usize>, Vec<u8>)> {
    let mut t = valid();
    t.push((
        "lane_extent".into(),
        Dtype::F64,
        vec![2, 2],
        extent.iter().flat_map(|x| x.to_le_bytes()).collect(),
    ));
    t.push((
        "lane_extent_real".into(),
        Dtype::U8,
        vec![2, 2],
        real.to_vec(),
    ));
    t
}

#[test]
fn lane_extents_read_from_version_2_only() {
    let s = read(&write(
        &valid_v2([-50.0, 60.0, -50.0, 200.0], [0, 1, 0, 0]),
        Some("nudge.scenario/2"),
    ))
    .unwrap();
    let ext = s.lane_extents.as_ref().unwrap();
    assert_eq!(ext.len(), 2);
    assert_eq!(
        ext[0],
        nudge_planner::LaneExtent {
            begin: -50.0,
            end: 60.0,
            begins: false,
            ends: true
        }
    );
    assert!(!ext[1].begins && !ext[1].ends && ext[1].end == 200.0);
    // Version 1 has none, even when the tensors are there.
    let v1 = read(&write(
        &valid_v2([-50.0, 60.0, -50.0, 200.0], [0, 1, 0, 0]),
        Some("nudge.scenario/1"),
    ))
    .unwrap();
    assert!(v1.lane_extents.is_none());
    assert_eq!(v1.history, s.history);
}

#[test]
fn lane_extent_defects_are_typed_errors() {
    let v2 = Some("nudge.scenario/2");
    // Version 2 without its extents.
    assert!(matches!(
        read(&write(&valid(), v2)),
        Err(ScenarioError::MissingTensor {
            tensor: "lane_extent",
            ..
        })
    ));
    // A lane that ends before it begins.
    let e = read(&write(&valid_v2([-50.0, 60.0, 200.0, 200.0], [0; 4]), v2)).unwrap_err();
    assert!(
        matches!(
            e,
            ScenarioError::BadValue {
                tensor: "lane_extent",
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("lane 1 begins at 200"), "{e}");
    // A flag that is not 0 or 1.
    assert!(matches!(
        read(&write(
            &valid_v2([-50.0, 60.0, -50.0, 200.0], [0, 2, 0, 0]),
            v2
        )),
        Err(ScenarioError::BadValue {
            tensor: "lane_extent_real",
            ..
        })
    ));
    // Non-finite.
    assert!(matches!(
        read(&write(
            &valid_v2([-50.0, f64::INFINITY, -50.0, 200.0], [0; 4]),
            v2
        )),
        Err(ScenarioError::NonFinite {
            tensor: "lane_extent",
            ..
        })
    ));
    // The ego (x = 21 m) past the end of its lane (10 m).
    let e = read(&write(
        &valid_v2([-50.0, 10.0, -50.0, 200.0], [0, 1, 0, 0]),
        v2,
    ))
    .unwrap_err();
    assert!(
        matches!(
            e,
            ScenarioError::Implausible {
                agent: 0,
                field: "lane_extent",
                ..
            }
        ),
        "{e}"
    );
}
