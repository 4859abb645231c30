//! Reliability of `nudge-predictor` against hostile or corrupted input: networks whose output
//! is non-finite or absurd, coordinates the networks cannot represent, degenerate shapes,
//! special and huge files, and weights files whose bytes changed after export.
//!
//! Every check asserts the behaviour a user sees: a typed error naming the item (file, agent,
//! step, range), or finite and plausible predictions — never a panic, a hang or NaN.
#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nudge_predictor::weights::synthetic_weights;
use nudge_predictor::{
    ConstantVelocity, History, ModelConfig, Predictor, PredictorError, Student, T_OBS, Teacher,
    load_predictor,
};
use proptest::prelude::*;
use safetensors::tensor::TensorView;
use safetensors::{Dtype, SafeTensors};
use sha2::{Digest, Sha256};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A scratch directory unique to this test process and `tag`.
fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nudge-reliability-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

// ---------------------------------------------------------------------------------------
// Weights files taken apart and put back together.
// ---------------------------------------------------------------------------------------

/// The content hash of a weights file, computed here independently of the library from the
/// layout documented in `nudge_predictor::weights` (and written by `python/train`'s exporter):
/// SHA-256 over, each length-prefixed with a u64 little-endian byte count, the format string
/// `nudge.weights/1`, the `config` metadata string, then for every tensor in ascending name
/// order its name, its dtype name (`F32`), its shape (u64 count, then each u64 dimension) and
/// its raw data bytes.
fn documented_hash(config: &str, tensors: &[(String, Dtype, Vec<usize>, Vec<u8>)]) -> String {
    fn field(h: &mut Sha256, bytes: &[u8]) {
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    }
    let mut h = Sha256::new();
    field(&mut h, b"nudge.weights/1");
    field(&mut h, config.as_bytes());
    let mut sorted: Vec<&(String, Dtype, Vec<usize>, Vec<u8>)> = tensors.iter().collect();
    sorted.sort_by(|a, b| a.0.as_bytes().cmp(b.0.as_bytes()));
    for (name, dtype, shape, data) in sorted {
        field(&mut h, name.as_bytes());
        field(&mut h, format!("{dtype:?}").as_bytes());
        let dims: Vec<u8> = shape
            .iter()
            .flat_map(|d| (*d as u64).to_le_bytes())
            .collect();
        h.update((shape.len() as u64).to_le_bytes());
        h.update(&dims);
        field(&mut h, data);
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// A weights file taken apart: tensors `(name, dtype, shape, bytes)` and metadata.
#[derive(Clone)]
struct Parts {
    tensors: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
    meta: HashMap<String, String>,
}

impl Parts {
    fn of(bytes: &[u8]) -> Self {
        let st = SafeTensors::deserialize(bytes).unwrap();
        let (_, header) = SafeTensors::read_metadata(bytes).unwrap();
        let tensors = st
            .tensors()
            .into_iter()
            .map(|(n, v)| (n, v.dtype(), v.shape().to_vec(), v.data().to_vec()))
            .collect();
        Self {
            tensors,
            meta: header.metadata().clone().unwrap_or_default(),
        }
    }

    fn shipped(kind: &str) -> Self {
        Self::of(&std::fs::read(repo().join(format!("assets/models/{kind}.safetensors"))).unwrap())
    }

    fn synthetic(kind: &str) -> Self {
        let cfg = if kind == "teacher" {
            ModelConfig::teacher()
        } else {
            ModelConfig::student()
        };
        Self::of(&synthetic_weights(&cfg, 5).unwrap())
    }

    /// Serialised as is (metadata untouched).
    fn raw(&self) -> Vec<u8> {
        let views: Vec<(String, TensorView<'_>)> = self
            .tensors
            .iter()
            .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).unwrap()))
            .collect();
        safetensors::serialize(views, Some(self.meta.clone())).unwrap()
    }

    /// Serialised with a freshly computed content hash: what an exporter would write for
    /// these (possibly edited) weights.
    fn stamped(&self) -> Vec<u8> {
        let mut p = self.clone();
        let hash = documented_hash(&p.meta["config"], &p.tensors);
        p.meta.insert("sha256".into(), hash);
        p.raw()
    }

    fn set_f32(&mut self, tensor: &str, index: usize, value: f32) -> &mut Self {
        let t = self.tensors.iter_mut().find(|t| t.0 == tensor).unwrap();
        t.3[4 * index..4 * index + 4].copy_from_slice(&value.to_le_bytes());
        self
    }
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

// ---------------------------------------------------------------------------------------
// A highway scene.
// ---------------------------------------------------------------------------------------

/// `(x, y, metres per step)` now of a 5-agent scene, ego first.
const AGENTS: [(f64, f64, f64); 5] = [
    (0.0, 0.0, 7.5),
    (25.0, 0.0, 7.0),
    (-20.0, 0.0, 8.0),
    (10.0, 3.7, 7.2),
    (-5.0, -3.7, 7.8),
];

/// `[5, 8, 2]` history of [`AGENTS`], optionally with agent `a` moved to `(x, y)` (at every
/// observed step, keeping its speed) or moving `step` metres per step.
fn history_with(edit: Option<(usize, [f64; 2])>, step: Option<(usize, f64)>) -> Vec<f64> {
    let mut pos = Vec::new();
    for (a, &(x0, y0, vx)) in AGENTS.iter().enumerate() {
        let (x0, y0) = match edit {
            Some((b, p)) if b == a => (p[0], p[1]),
            _ => (x0, y0),
        };
        let vx = match step {
            Some((b, s)) if b == a => s,
            _ => vx,
        };
        for t in 0..T_OBS {
            pos.push(x0 - vx * (T_OBS - 1 - t) as f64);
            pos.push(y0);
        }
    }
    pos
}

/// `[2, 6, 2]`: keep lane and drift left 0.3 m per step, from the ego at (0, 0).
fn candidates() -> Vec<f64> {
    let mut c = Vec::new();
    for lat in [0.0, 0.3] {
        for k in 1..=6 {
            c.push(7.5 * k as f64);
            c.push(lat * k as f64);
        }
    }
    c
}

fn predictors() -> Vec<Box<dyn Predictor>> {
    vec![
        Box::new(Teacher::from_bytes(&Parts::synthetic("teacher").stamped()).unwrap()),
        Box::new(Student::from_bytes(&Parts::synthetic("student").stamped()).unwrap()),
        Box::new(ConstantVelocity::default()),
        load_predictor(repo().join("assets/models/teacher.safetensors")).unwrap(),
        load_predictor(repo().join("assets/models/student.safetensors")).unwrap(),
    ]
}

/// Runs `History::new` + `set_scene` + `predict`; the error of the first step that fails.
fn run(
    p: &mut dyn Predictor,
    hist: Vec<f64>,
    n: usize,
    cand: &[f64],
) -> Result<Vec<f64>, PredictorError> {
    let h = History::new(hist, n)?;
    p.set_scene(&h)?;
    let t = p.horizon();
    let mut out = vec![0.0; cand.len() / (2 * t) * (n - 1) * t * 2];
    p.predict(cand, &mut out)?;
    Ok(out)
}

// ---------------------------------------------------------------------------------------
// Defect 1: non-finite or absurd network outputs, unrepresentable inputs.
// ---------------------------------------------------------------------------------------

/// A student whose decoder LSTM has one huge (finite) input weight: every prediction is NaN
/// (inf − inf inside the gates). The file must fail at load, naming itself.
#[test]
fn weights_whose_network_outputs_nan_fail_at_load() {
    let dir = scratch("nan-net");
    let mut p = Parts::shipped("student");
    p.set_f32("decoder.decoder.weight_ih_l0", 0, 3e38);
    let file = write(&dir, "nan-student.safetensors", &p.stamped());
    for result in [
        Student::from_file(&file).map(|_| ()),
        load_predictor(&file).map(|_| ()),
    ] {
        let err = result.expect_err("a network that outputs NaN must not load");
        match &err {
            PredictorError::SelfCheck { path, source } => {
                assert_eq!(path, &file);
                assert!(
                    matches!(
                        **source,
                        PredictorError::NonFiniteOutput {
                            predictor: "student",
                            ..
                        }
                    ),
                    "{source:?}"
                );
            }
            other => panic!("expected SelfCheck, got {other:?}"),
        }
        let msg = err.to_string();
        assert!(msg.contains("nan-student.safetensors"), "{msg}");
        assert!(msg.contains("self-check"), "{msg}");
        assert!(msg.contains("non-finite"), "{msg}");
    }
}

/// A hidden2pos bias of 3.4e38: predictions of ~2e39 m, finite but absurd.
#[test]
fn weights_with_absurd_outputs_fail_at_load() {
    let dir = scratch("huge-bias");
    for kind in ["teacher", "student"] {
        let mut p = Parts::shipped(kind);
        p.set_f32("decoder.hidden2pos.bias", 0, 3.4e38);
        let file = write(&dir, &format!("huge-{kind}.safetensors"), &p.stamped());
        let err = load_predictor(&file)
            .err()
            .expect("absurd outputs must not load");
        match &err {
            PredictorError::SelfCheck { source, .. } => match **source {
                PredictorError::ImplausibleOutput {
                    displacement,
                    max,
                    step: 1,
                    ..
                } => {
                    assert!(displacement > 1e38 && max == nudge_predictor::limits::MAX_STEP);
                }
                ref other => panic!("{other:?}"),
            },
            other => panic!("expected SelfCheck, got {other:?}"),
        }
        let msg = err.to_string();
        assert!(msg.contains(&format!("huge-{kind}.safetensors")), "{msg}");
        assert!(msg.contains("implausible"), "{msg}");
        assert!(msg.contains("30 m"), "the bound is stated: {msg}");
    }
}

/// A teacher whose pooling embedding overflows for some agents only: the error names the
/// agent and the step.
#[test]
fn partially_non_finite_network_names_agent_and_step() {
    let mut p = Parts::shipped("teacher");
    p.set_f32("pool_net.spatial_embedding.weight", 0, 3e38);
    let err = Teacher::from_bytes(&p.stamped()).expect_err("must not load");
    let msg = err.to_string();
    assert!(msg.contains("agent ") && msg.contains("step "), "{msg}");
}

/// Coordinates the networks cannot represent are refused with the accepted range; values just
/// inside the ranges give finite predictions.
#[test]
fn unrepresentable_inputs_are_refused_with_the_accepted_range() {
    let n = AGENTS.len();
    let far = |d: f64| history_with(Some((1, [d, d])), None);
    let bad_histories: Vec<(&str, Vec<f64>)> = vec![
        ("agent at 1e154 m", far(1e154)),
        ("agent at 2e6 m", history_with(Some((2, [2e6, 0.0])), None)),
        ("every agent at 2e6 m", {
            let mut h = history_with(None, None);
            h.iter_mut().for_each(|v| *v += 2e6);
            h
        }),
        ("agent 1.5 km from the others", far(1060.0)),
        (
            "agent moving 40 m per step",
            history_with(None, Some((3, 40.0))),
        ),
    ];
    for mut p in predictors() {
        let name = p.name();
        for (what, h) in &bad_histories {
            let err = run(p.as_mut(), h.clone(), n, &candidates())
                .err()
                .unwrap_or_else(|| panic!("{name}: {what} accepted"));
            let msg = err.to_string();
            assert!(msg.contains("accepted range"), "{name}: {what}: {msg}");
            assert!(
                matches!(
                    err,
                    PredictorError::InputOutOfRange {
                        what: "history",
                        ..
                    }
                ),
                "{name}: {what}: {err:?}"
            );
        }
        let mut far_cand = candidates();
        far_cand[3] = 1e154;
        let mut jump = candidates();
        jump[4] += 1001.0;
        for (what, c) in [
            ("candidate at 1e154 m", far_cand),
            ("candidate jumping 1 km", jump),
        ] {
            let err = run(p.as_mut(), history_with(None, None), n, &c)
                .err()
                .unwrap_or_else(|| panic!("{name}: {what} accepted"));
            assert!(
                err.to_string().contains("accepted range"),
                "{name}: {what}: {err}"
            );
            assert!(
                matches!(
                    err,
                    PredictorError::InputOutOfRange {
                        what: "candidates",
                        ..
                    }
                ),
                "{name}: {what}: {err:?}"
            );
        }
        // An optimiser's overshooting trial point (40 m in one step) still gets a prediction.
        let mut overshoot = candidates();
        overshoot[4] += 40.0;
        let out = run(p.as_mut(), history_with(None, None), n, &overshoot)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(out.iter().all(|v| v.is_finite()), "{name}");
        // Just inside every range: finite predictions.
        let mut shifted = history_with(Some((1, [690.0, 690.0])), Some((3, 20.0)));
        shifted.iter_mut().for_each(|v| *v += 9.9e5);
        let cand: Vec<f64> = candidates().iter().map(|v| v + 9.9e5).collect();
        let out = run(p.as_mut(), shifted, n, &cand).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(out.iter().all(|v| v.is_finite()), "{name}");
    }
}

// ---------------------------------------------------------------------------------------
// Defect 2: horizon 0 and other degenerate shapes never panic.
// ---------------------------------------------------------------------------------------

#[test]
fn constant_velocity_horizon_zero_is_refused_not_a_panic() {
    for h in [0, nudge_predictor::MAX_HORIZON + 1, usize::MAX] {
        match ConstantVelocity::new(h) {
            Err(PredictorError::Horizon { got, max }) => {
                assert_eq!((got, max), (h, nudge_predictor::MAX_HORIZON));
            }
            other => panic!("horizon {h}: {other:?}"),
        }
    }
    let err = ConstantVelocity::new(0).unwrap_err();
    assert_eq!(
        err.to_string(),
        "horizon 0 steps is outside the supported range 1..=60"
    );
    // The shared batch check refuses horizon 0 and 0 agents too (it divided by zero).
    assert!(matches!(
        nudge_predictor::check_batch(&[], &[], 0, 2, [0.0; 2]),
        Err(PredictorError::Horizon { got: 0, .. })
    ));
    assert!(matches!(
        nudge_predictor::check_batch(&[0.0; 12], &[], 6, 0, [0.0; 2]),
        Err(PredictorError::AgentCount { got: 0, .. })
    ));
    let mut cv = ConstantVelocity::new(1).unwrap();
    let h = History::new(history_with(None, None), AGENTS.len()).unwrap();
    cv.set_scene(&h).unwrap();
    let mut out = vec![0.0; 4 * 2];
    cv.predict(&[7.5, 0.0], &mut out).unwrap();
    assert_eq!(&out[..2], &[32.0, 0.0]);
}

/// Strategy: a float that is often ordinary, sometimes huge, NaN or infinite.
fn wild_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => -100.0f64..100.0,
        1 => prop::num::f64::ANY,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => prop_oneof![Just(1e154), Just(-1e300), Just(3.5e38), Just(1e6), Just(2e3)],
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    /// Arbitrary shapes and values through every public entry point: a typed error or finite
    /// output, never a panic.
    #[test]
    fn arbitrary_inputs_give_typed_errors_or_finite_outputs(
        n in 0usize..6,
        hist_len_delta in -1i64..=1,
        batch in 0usize..3,
        cand_len_delta in -1i64..=1,
        out_len_delta in -1i64..=1,
        horizon in 0usize..8,
        edits in prop::collection::vec((0usize..200, wild_f64()), 0..4),
        cand_edits in prop::collection::vec((0usize..40, wild_f64()), 0..3),
    ) {
        let outcome = std::panic::catch_unwind(|| {
            let mut results = Vec::new();
            let mut ps = predictors();
            match ConstantVelocity::new(horizon) {
                Ok(cv) => ps.push(Box::new(cv)),
                Err(e) => results.push(("constant_velocity", Err(e))),
            }
            for mut p in ps {
                let t = p.horizon();
                let mut hist = history_with(None, None);
                hist.truncate(n.min(AGENTS.len()) * T_OBS * 2);
                let hl = (hist.len() as i64 + hist_len_delta).max(0) as usize;
                hist.resize(hl, 1.0);
                for &(i, v) in &edits {
                    if let Some(x) = hist.get_mut(i) { *x = v; }
                }
                let mut cand: Vec<f64> = (0..batch * t).flat_map(|k| [7.5 * (k % t.max(1) + 1) as f64, 0.0]).collect();
                let cl = (cand.len() as i64 + cand_len_delta).max(0) as usize;
                cand.resize(cl, 0.0);
                for &(i, v) in &cand_edits {
                    if let Some(x) = cand.get_mut(i) { *x = v; }
                }
                let out_len = (batch * n.saturating_sub(1) * t * 2) as i64 + out_len_delta;
                let mut out = vec![0.0; out_len.max(0) as usize];
                let r = History::new(hist, n).and_then(|h| {
                    p.set_scene(&h)?;
                    p.predict(&cand, &mut out)
                });
                results.push((p.name(), r.map(|()| out)));
            }
            results
        });
        let results = outcome.map_err(|_| TestCaseError::fail("a predictor panicked"))?;
        for (name, r) in results {
            if let Ok(out) = r {
                prop_assert!(out.iter().all(|v| v.is_finite()), "{}: non-finite output accepted", name);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// Defect 9: special and huge files.
// ---------------------------------------------------------------------------------------

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
fn fifo_is_refused_without_blocking() {
    let dir = scratch("fifo");
    let fifo = dir.join("model.safetensors");
    let _ = std::fs::remove_file(&fifo);
    let status = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(status.success());
    let f = fifo.clone();
    let result = within(10, move || load_predictor(&f).map(|_| ()));
    // Unblock a loader stuck in open() before asserting, so the process can end.
    if result.is_none() {
        let _ = std::fs::OpenOptions::new().write(true).open(&fifo);
    }
    let err = result
        .expect("loading a FIFO blocked")
        .expect_err("a FIFO must be refused");
    assert!(
        matches!(&err, PredictorError::NotRegularFile { path, kind: "a FIFO" } if *path == fifo),
        "{err:?}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("model.safetensors") && msg.contains("not a regular file"),
        "{msg}"
    );
}

#[cfg(unix)]
#[test]
fn devices_and_directories_are_refused_before_reading() {
    let dir = scratch("special");
    for path in [
        PathBuf::from("/dev/zero"),
        PathBuf::from("/dev/null"),
        dir.clone(),
    ] {
        let p = path.clone();
        let err = within(10, move || Teacher::from_file(&p).map(|_| ()))
            .unwrap_or_else(|| panic!("{}: blocked", path.display()))
            .expect_err("must be refused");
        let msg = err.to_string();
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        assert!(msg.contains("not a regular file"), "{msg}");
    }
}

#[test]
fn oversized_file_is_refused_before_reading() {
    let dir = scratch("huge");
    let path = dir.join("huge.safetensors");
    // A sparse 1 TiB file: reading it would take hours and all the memory.
    let f = std::fs::File::create(&path).unwrap();
    f.set_len(1 << 40).unwrap();
    drop(f);
    let p = path.clone();
    let err = within(10, move || load_predictor(&p).map(|_| ()))
        .expect("an oversized file must be refused before reading")
        .expect_err("must be refused");
    assert!(
        matches!(err, PredictorError::FileTooLarge { size, max, .. } if size == 1 << 40 && max == nudge_predictor::file::MAX_WEIGHTS_BYTES),
        "{err:?}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("huge.safetensors") && msg.contains("larger than"),
        "{msg}"
    );
    std::fs::remove_file(&path).unwrap();
}

// ---------------------------------------------------------------------------------------
// Defect 10: weights integrity.
// ---------------------------------------------------------------------------------------

/// The shipped models and the golden weights carry the content hash, in the documented layout
/// (computed here independently) — the Python exporter and the Rust loader agree on it.
#[test]
fn shipped_and_golden_weights_carry_the_documented_hash() {
    for rel in [
        "assets/models/teacher.safetensors",
        "assets/models/student.safetensors",
        "crates/predictor/tests/golden/weights_teacher_random.safetensors",
        "crates/predictor/tests/golden/weights_student_random.safetensors",
    ] {
        let p = Parts::of(&std::fs::read(repo().join(rel)).unwrap());
        let stored = p
            .meta
            .get("sha256")
            .unwrap_or_else(|| panic!("{rel}: no sha256"));
        assert_eq!(
            stored,
            &documented_hash(&p.meta["config"], &p.tensors),
            "{rel}"
        );
        load_predictor(repo().join(rel)).unwrap();
    }
}

/// One flipped low mantissa bit (a finite value, predictions off by a little) is detected,
/// with the file named and both hashes shown.
#[test]
fn flipped_bits_are_detected() {
    let dir = scratch("flip");
    let good = std::fs::read(repo().join("assets/models/student.safetensors")).unwrap();
    let header = 8 + u64::from_le_bytes(good[..8].try_into().unwrap()) as usize;
    for offset in [header, header + 1000, good.len() - 1] {
        let mut bad = good.clone();
        bad[offset] ^= 0x01;
        let file = write(&dir, "flipped.safetensors", &bad);
        let err = load_predictor(&file)
            .err()
            .unwrap_or_else(|| panic!("flip at {offset} accepted"));
        let msg = err.to_string();
        assert!(msg.contains("flipped.safetensors"), "{msg}");
        assert!(msg.contains("sha256"), "{msg}");
        assert!(
            matches!(err, PredictorError::HashMismatch { .. }),
            "{err:?}"
        );
    }
    // An edited config field the loader does not otherwise check (the seed) too.
    let mut p = Parts::shipped("student");
    let cfg = p.meta["config"].replace("\"seed\":", "\"seed\": ");
    p.meta.insert("config".into(), cfg);
    assert!(Student::from_bytes(&p.raw()).is_err());
}

/// A file without the hash is refused (its integrity cannot be checked).
#[test]
fn weights_without_hash_are_refused() {
    let mut p = Parts::shipped("teacher");
    p.meta.remove("sha256");
    let err = Teacher::from_bytes(&p.raw()).expect_err("must be refused");
    assert!(matches!(err, PredictorError::MissingHash { .. }), "{err:?}");
    assert!(err.to_string().contains("sha256"), "{err}");
    let mut p = Parts::shipped("teacher");
    p.meta.insert("sha256".into(), "not a hash".into());
    assert!(Teacher::from_bytes(&p.raw()).is_err());
}
