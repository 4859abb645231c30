//! Physical plausibility of scenario files: every real scene loads; vehicles off the road, an
//! `ego_lane` that is not the ego's lane, absurd headings, speeds, sizes, lane widths and
//! history jumps are refused with an error naming the agent and the field; special and huge
//! files are refused before reading.
#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nudge_planner::{Scenario, ScenarioError};
use safetensors::tensor::TensorView;
use safetensors::{Dtype, SafeTensors};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Every `.safetensors` file under `dir` (empty if `dir` does not exist).
fn scenes_in(dir: &Path) -> Vec<PathBuf> {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "safetensors"))
        .collect();
    v.sort();
    v
}

/// The shipped scenes and, where the processed data set is present, every scene of every
/// split load with the plausibility checks on.
#[test]
fn every_real_scene_loads() {
    let mut dirs = vec![repo().join("assets/scenes")];
    for split in ["train", "val", "test"] {
        dirs.push(repo().join("data/processed/scenes").join(split));
    }
    let mut count = 0;
    for dir in dirs {
        for path in scenes_in(&dir) {
            if let Err(e) = Scenario::from_file(&path) {
                panic!("{e}");
            }
            count += 1;
        }
    }
    assert!(count >= 10, "only {count} scenes found");
    eprintln!("{count} real scenes load");
}

/// A scene file taken apart: tensors and metadata.
#[derive(Clone)]
struct Parts {
    tensors: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
    meta: HashMap<String, String>,
}

impl Parts {
    fn shipped() -> Self {
        let bytes = std::fs::read(repo().join("assets/scenes/us101-11_1-t02.1-ego132.safetensors"))
            .unwrap();
        let st = SafeTensors::deserialize(&bytes).unwrap();
        let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
        Self {
            tensors: st
                .tensors()
                .into_iter()
                .map(|(n, v)| (n, v.dtype(), v.shape().to_vec(), v.data().to_vec()))
                .collect(),
            meta: header.metadata().clone().unwrap_or_default(),
        }
    }

    fn f64s(&self, name: &str) -> Vec<f64> {
        let t = self.tensors.iter().find(|t| t.0 == name).unwrap();
        t.3.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }

    fn set_f64s(&mut self, name: &str, v: &[f64]) -> &mut Self {
        let t = self.tensors.iter_mut().find(|t| t.0 == name).unwrap();
        t.3 = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self
    }

    fn edit(mut self, name: &str, f: impl FnOnce(&mut Vec<f64>)) -> Self {
        let mut v = self.f64s(name);
        f(&mut v);
        self.set_f64s(name, &v);
        self
    }

    fn bytes(&self) -> Vec<u8> {
        let views: Vec<(String, TensorView<'_>)> = self
            .tensors
            .iter()
            .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).unwrap()))
            .collect();
        safetensors::serialize(views, Some(self.meta.clone())).unwrap()
    }

    fn read(&self) -> Result<Scenario, ScenarioError> {
        Scenario::from_bytes(&self.bytes(), Path::new("edited.safetensors"))
    }

    fn ego_lane(&self) -> i64 {
        let t = self.tensors.iter().find(|t| t.0 == "ego_lane").unwrap();
        i64::from_le_bytes(t.3[..8].try_into().unwrap())
    }

    fn set_ego_lane(mut self, lane: i64) -> Self {
        let t = self.tensors.iter_mut().find(|t| t.0 == "ego_lane").unwrap();
        t.3 = lane.to_le_bytes().to_vec();
        self
    }
}

/// Index of `history` value (agent, observed step, coordinate).
fn h(agent: usize, t: usize, c: usize) -> usize {
    (agent * 8 + t) * 2 + c
}

#[test]
fn the_unedited_scene_loads() {
    let s = Parts::shipped().read().unwrap();
    assert!(s.n_agents >= 4, "the edits below need agents 1..=3");
}

/// Each edit makes one scene implausible; the error names the agent (where there is one) and
/// the field.
#[test]
fn implausible_scenes_are_refused_naming_agent_and_field() {
    let base = Parts::shipped();
    let road = base.f64s("lane_bounds");
    let (right, left) = (road[0], road[road.len() - 1]);
    let nl = road.len() as i64 - 1;
    let lane = base.ego_lane();
    let cases: Vec<(&str, Parts, &[&str])> = vec![
        (
            "agent 2 100 m left of the road",
            base.clone().edit("history", |v| {
                for t in 0..8 {
                    v[h(2, t, 1)] = left + 100.0;
                }
            }),
            &["agent 2", "history", "road"],
        ),
        (
            "agent 3 3 m right of the road",
            base.clone().edit("history", |v| {
                for t in 0..8 {
                    v[h(3, t, 1)] = right - 3.0;
                }
            }),
            &["agent 3", "history", "road"],
        ),
        (
            "ego_lane two lanes off",
            base.clone().set_ego_lane((lane + 2) % nl),
            &["ego_lane", "agent 0"],
        ),
        (
            "heading pi",
            base.clone()
                .edit("heading", |v| v[1] = std::f64::consts::PI),
            &["agent 1", "heading"],
        ),
        (
            "heading 1e10",
            base.clone().edit("heading", |v| v[0] = 1e10),
            &["agent 0", "heading"],
        ),
        (
            "speed 1e6",
            base.clone().edit("speed", |v| v[3] = 1e6),
            &["agent 3", "speed"],
        ),
        (
            "vehicle 1 km long",
            base.clone().edit("size", |v| v[2] = 1000.0),
            &["agent 1", "size"],
        ),
        (
            "history jump of 50 m",
            base.clone().edit("history", |v| {
                for t in 4..8 {
                    v[h(1, t, 0)] += 50.0;
                }
            }),
            &["agent 1", "history", "step"],
        ),
        (
            "agent at x = 1e7",
            base.clone().edit("history", |v| {
                for t in 0..8 {
                    v[h(2, t, 0)] += 1e7;
                }
            }),
            &["agent 2", "history"],
        ),
        (
            "road 1e-9 m wide",
            base.clone()
                .edit("lane_bounds", |v| {
                    let n = v.len();
                    for (i, b) in v.iter_mut().enumerate() {
                        *b = 1e-9 * i as f64 / (n - 1) as f64;
                    }
                })
                .edit("lane_centres", |v| {
                    let n = v.len();
                    for (i, c) in v.iter_mut().enumerate() {
                        *c = 1e-9 * (i as f64 + 0.5) / n as f64;
                    }
                }),
            &["lane", "width"],
        ),
        (
            "one lane 40 m wide",
            base.clone().edit("lane_bounds", |v| {
                let n = v.len();
                v[n - 1] += 40.0;
            }),
            &["lane", "width"],
        ),
    ];
    for (what, parts, words) in cases {
        let err = parts
            .read()
            .err()
            .unwrap_or_else(|| panic!("{what}: accepted"));
        let msg = err.to_string();
        assert!(msg.contains("edited.safetensors"), "{what}: {msg}");
        for w in words {
            assert!(msg.contains(w), "{what}: {msg:?} does not say {w:?}");
        }
    }
}

/// Runs `f` on a thread; `None` if it has not returned within `secs`.
fn within<T: Send + 'static>(secs: u64, f: impl FnOnce() -> T + Send + 'static) -> Option<T> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(std::time::Duration::from_secs(secs)).ok()
}

#[cfg(unix)]
#[test]
fn special_and_huge_files_are_refused_before_reading() {
    let dir = std::env::temp_dir().join(format!("nudge-scenario-files-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("fifo.safetensors");
    let _ = std::fs::remove_file(&fifo);
    assert!(
        std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let huge = dir.join("huge.safetensors");
    std::fs::File::create(&huge)
        .unwrap()
        .set_len(1 << 40)
        .unwrap();
    for (path, words) in [
        (fifo.clone(), ["not a regular file", "FIFO"]),
        (PathBuf::from("/dev/zero"), ["not a regular file", "device"]),
        (dir.clone(), ["not a regular file", "directory"]),
        (huge.clone(), ["larger than", "bytes"]),
    ] {
        let p = path.clone();
        let result = within(10, move || Scenario::from_file(&p).map(|_| ()));
        if result.is_none() && path == fifo {
            let _ = std::fs::OpenOptions::new().write(true).open(&fifo);
        }
        let err = result
            .unwrap_or_else(|| panic!("{}: blocked", path.display()))
            .expect_err("must be refused");
        let msg = err.to_string();
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        for w in words {
            assert!(msg.contains(w), "{msg}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
