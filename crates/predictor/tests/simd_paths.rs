//! Every instruction-set path the running CPU supports (`portable` always; `avx2`, `avx512`
//! where present), forced one at a time with `set_simd_path`: PyTorch parity on the golden
//! files, agreement with the portable path and with the literal f64 reference, determinism,
//! and the path selection itself (`NUDGE_SIMD`, typed errors).
#![allow(clippy::unwrap_used, clippy::print_stdout)]

use std::path::{Path, PathBuf};

use nudge_predictor::weights::synthetic_weights;
use nudge_predictor::{
    History, ModelConfig, ModelKind, ModelWeights, Predictor, PredictorError, SimdPath, Student,
    Teacher, best_simd_path, reference, simd_path, supported_simd_paths,
};
use proptest::prelude::*;
use safetensors::SafeTensors;

mod common;
use common::{max_err, run, scene};

/// Largest acceptable |rust − pytorch| (and |rust − f64 reference|) in metres.
const TOL: f64 = 1e-5;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A model of `w`'s kind running on `path`.
fn model(w: &ModelWeights, path: SimdPath) -> Box<dyn Predictor> {
    match w.config().kind {
        ModelKind::Teacher => {
            let mut m = Teacher::from_weights(w).unwrap();
            m.set_simd_path(path).unwrap();
            assert_eq!(m.simd_path(), path);
            Box::new(m)
        }
        ModelKind::Student => {
            let mut m = Student::from_weights(w).unwrap();
            m.set_simd_path(path).unwrap();
            assert_eq!(m.simd_path(), path);
            Box::new(m)
        }
    }
}

fn f32s(st: &SafeTensors<'_>, name: &str) -> Option<Vec<f64>> {
    let t = st.tensor(name).ok()?;
    Some(
        t.data()
            .chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .collect(),
    )
}

/// The golden case file of `kind`/`variant` and its weights, wherever the goldens live.
fn golden_files(kind: &str, variant: &str) -> Option<(PathBuf, PathBuf)> {
    let name = format!("cases_{kind}_{variant}.safetensors");
    let dir = [
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden"),
        repo().join("tests/golden"),
    ]
    .into_iter()
    .find(|d| d.join(&name).exists())?;
    let cases = dir.join(&name);
    let bytes = std::fs::read(&cases).unwrap();
    let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
    let meta = header.metadata().clone().unwrap_or_default();
    let weights_name = meta.get("weights").expect("cases file names its weights");
    let weights = [repo().join(weights_name), dir.join(weights_name)]
        .into_iter()
        .find(|p| p.exists())
        .unwrap_or_else(|| panic!("weights {weights_name} of {} not found", cases.display()));
    Some((cases, weights))
}

/// PyTorch parity of one golden file on every supported path; returns the worst error per
/// path.
fn golden_all_paths(kind: &str, variant: &str) {
    let Some((cases, weights)) = golden_files(kind, variant) else {
        println!("NOTE: golden {kind}/{variant} absent, skipped");
        return;
    };
    let bytes = std::fs::read(&cases).unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let w = ModelWeights::from_file(&weights).unwrap();
    for path in supported_simd_paths() {
        let mut m = model(&w, path);
        let mut worst = 0.0f64;
        for n in [1usize, 2, 5, 17, 47] {
            let history = History::new(f32s(&st, &format!("n{n}.history")).unwrap(), n).unwrap();
            let cand = f32s(&st, &format!("n{n}.candidates")).unwrap();
            let expected = f32s(&st, &format!("n{n}.expected")).unwrap_or_default();
            let got = run(m.as_mut(), &history, &cand);
            let err = max_err(&got, &expected);
            assert!(
                err <= TOL,
                "{kind}/{variant} {path} n={n}: max |rust - pytorch| {err:.3e} > {TOL:.0e}"
            );
            worst = worst.max(err);
        }
        println!("{kind}/{variant} {path}: max |rust - pytorch| = {worst:.3e} m");
    }
}

#[test]
fn golden_teacher_trained_every_path() {
    golden_all_paths("teacher", "trained");
}

#[test]
fn golden_student_trained_every_path() {
    golden_all_paths("student", "trained");
}

#[test]
fn golden_teacher_random_every_path() {
    golden_all_paths("teacher", "random");
}

#[test]
fn golden_student_random_every_path() {
    golden_all_paths("student", "random");
}

/// The portable path runs everywhere; the default path is the forced one or the widest; a path
/// the CPU lacks is a typed error, never a silent fallback.
#[test]
fn path_selection() {
    let supported = supported_simd_paths();
    assert_eq!(supported[0], SimdPath::Portable);
    assert!(SimdPath::Portable.is_supported());
    let chosen = simd_path().unwrap();
    match std::env::var("NUDGE_SIMD") {
        Ok(v) if !v.trim().is_empty() => assert_eq!(chosen.as_str(), v.trim()),
        _ => assert_eq!(chosen, best_simd_path()),
    }
    let w =
        ModelWeights::from_bytes(&synthetic_weights(&ModelConfig::student(), 1).unwrap()).unwrap();
    let mut s = Student::from_weights(&w).unwrap();
    assert_eq!(s.simd_path(), chosen);
    for path in SimdPath::ALL {
        match s.set_simd_path(path) {
            Ok(()) => assert!(supported.contains(&path)),
            Err(PredictorError::SimdPath { requested, .. }) => {
                assert!(!supported.contains(&path));
                assert_eq!(requested, path.as_str());
            }
            Err(e) => panic!("unexpected error {e}"),
        }
    }
    println!("supported paths: {supported:?}, default: {chosen}");
}

/// Every path against the portable one and the f64 reference; the fused paths bit-identical
/// to each other; each path deterministic (repeat, fresh instance, one candidate at a time).
fn check_paths(cfg: &ModelConfig, seed: u64, n: usize) {
    let w = ModelWeights::from_bytes(&synthetic_weights(cfg, seed % 5).unwrap()).unwrap();
    let z: Vec<f32> = w
        .tensor("fixed_noise")
        .map(|t| t.data.clone())
        .unwrap_or_default();
    let (history, cand) = scene(seed, n, 3);
    let want = reference::predict(&w, &z, &history, &cand).unwrap();
    let portable = run(model(&w, SimdPath::Portable).as_mut(), &history, &cand);
    let mut fused: Option<Vec<f64>> = None;
    for path in supported_simd_paths() {
        let mut m = model(&w, path);
        let got = run(m.as_mut(), &history, &cand);
        assert!(
            got.iter().all(|v| v.is_finite()),
            "{path}: non-finite output"
        );
        let e_ref = max_err(&got, &want);
        let e_port = max_err(&got, &portable);
        assert!(
            e_ref <= TOL,
            "{:?} {path} n={n}: vs reference {e_ref:.3e}",
            cfg.kind
        );
        assert!(
            e_port <= TOL,
            "{:?} {path} n={n}: vs portable {e_port:.3e}",
            cfg.kind
        );
        assert_eq!(
            run(m.as_mut(), &history, &cand),
            got,
            "{path}: repeat differs"
        );
        assert_eq!(
            run(model(&w, path).as_mut(), &history, &cand),
            got,
            "{path}: fresh instance differs"
        );
        let per = got.len() / 3;
        for b in 0..3 {
            let mut out = vec![0.0; per];
            m.predict(&cand[b * 12..(b + 1) * 12], &mut out).unwrap();
            assert_eq!(
                out[..],
                got[b * per..(b + 1) * per],
                "{path}: batch vs single"
            );
        }
        if path.is_fused() {
            match &fused {
                None => fused = Some(got),
                Some(f) => assert_eq!(f, &got, "{path} differs from the other fused path"),
            }
        }
    }
}

fn odd() -> ModelConfig {
    ModelConfig {
        embedding_dim: 5,
        encoder_h_dim: 7,
        decoder_h_dim: 9,
        mlp_dim: 11,
        bottleneck_dim: 13,
        pool_hidden_dim: 40,
        noise_dim: 3,
        ..ModelConfig::teacher()
    }
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 6,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn student_paths_agree(seed in any::<u64>(), n in 1usize..12) {
        check_paths(&ModelConfig::student(), seed, n);
    }

    #[test]
    fn teacher_paths_agree(seed in any::<u64>(), n in 1usize..7) {
        check_paths(&ModelConfig::teacher(), seed, n);
    }

    /// Sizes that are not multiples of the vector widths (partial blocks and tiles), a teacher
    /// that pools in its decoder and a student without decoder pooling.
    #[test]
    fn odd_config_paths_agree(seed in any::<u64>(), n in 1usize..7) {
        check_paths(&ModelConfig { pool_every_timestep: true, ..odd() }, seed, n);
        check_paths(
            &ModelConfig {
                kind: ModelKind::Student,
                pred_len: 6,
                pool_every_timestep: false,
                noise_dim: 2,
                ..odd()
            },
            seed,
            n,
        );
    }
}
