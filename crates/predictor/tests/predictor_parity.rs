//! Parity of the Rust networks with PyTorch (golden files written by
//! `nudge-train goldens`, in `tests/golden`) and their properties: permutation equivariance,
//! cached == uncached (fast path vs the literal reference implementation), determinism, and
//! the exact constant-velocity baseline.
#![allow(clippy::unwrap_used, clippy::print_stdout)]

use std::path::{Path, PathBuf};

use nudge_predictor::weights::synthetic_weights;
use nudge_predictor::{
    ConstantVelocity, History, ModelConfig, ModelWeights, Predictor, PredictorSpec, Student, T_OBS,
    Teacher, load_predictor, reference,
};
use proptest::prelude::*;
use safetensors::SafeTensors;

mod common;
use common::{Rng, max_err, run, scene};

/// Largest acceptable |rust − pytorch| in metres.
const TOL: f64 = 1e-5;

/// Largest acceptable |rust − pytorch| in metres for the f32 teacher rolled out beyond 6
/// steps: each step's f32 prediction is the next step's input, so the rounding compounds
/// (trained teacher, 10 steps: ≤ 1e-5 through step 7, 1.9e-5 at step 10 with 17 agents). The
/// f64 reference rolled out as far still meets [`TOL`].
const LONG_TOL: f64 = 2.5e-5;

/// The repository root (trained-weight goldens name repo-relative paths).
fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// This crate's golden files.
fn golden_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden")
}

fn f32s(st: &SafeTensors<'_>, name: &str) -> Option<(Vec<usize>, Vec<f64>)> {
    let t = st.tensor(name).ok()?;
    assert_eq!(t.dtype(), safetensors::Dtype::F32, "{name} must be F32");
    Some((
        t.shape().to_vec(),
        t.data()
            .chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .collect(),
    ))
}

/// Runs one golden case file; returns false (with a note) when it is absent.
fn golden(kind: &str, variant: &str) -> bool {
    let cases = golden_dir().join(format!("cases_{kind}_{variant}.safetensors"));
    if !cases.exists() {
        println!("NOTE: {} absent, case skipped", cases.display());
        return false;
    }
    let bytes = std::fs::read(&cases).unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
    let meta = header.metadata().clone().unwrap_or_default();
    let weights_name = meta.get("weights").expect("cases file names its weights");
    // Random-weight cases name a file beside them, trained ones a repo-relative path.
    let weights: PathBuf = [repo().join(weights_name), golden_dir().join(weights_name)]
        .into_iter()
        .find(|p| p.exists())
        .unwrap_or_else(|| panic!("weights {weights_name} of {} not found", cases.display()));
    // A long-horizon case file rolls the teacher out over the horizon its metadata names.
    let mut model = match meta.get("horizon") {
        Some(h) => PredictorSpec::from_file(&weights)
            .unwrap()
            .with_horizon(h.parse().unwrap())
            .unwrap()
            .build(),
        None => load_predictor(&weights).unwrap(),
    };
    let w = ModelWeights::from_file(&weights).unwrap();
    let z: Vec<f32> = w
        .tensor("fixed_noise")
        .map(|t| t.data.clone())
        .unwrap_or_default();
    assert_eq!(model.name(), kind);
    let t = model.horizon();
    let tol = if t > 6 { LONG_TOL } else { TOL };
    let mut worst = 0.0f64;
    let mut n_cases = 0;
    for n in [1usize, 2, 5, 17, 47] {
        let Some((hs, history)) = f32s(&st, &format!("n{n}.history")) else {
            panic!("{}: n{n}.history missing", cases.display());
        };
        assert_eq!(hs, vec![n, T_OBS, 2]);
        let (cs, cand) = f32s(&st, &format!("n{n}.candidates")).unwrap();
        assert_eq!(cs[1..], [t, 2]);
        let batch = cs[0];
        let expected = match f32s(&st, &format!("n{n}.expected")) {
            Some((es, e)) => {
                assert_eq!(es, vec![batch, n - 1, t, 2]);
                e
            }
            None if n == 1 => Vec::new(),
            None => panic!("{}: n{n}.expected missing", cases.display()),
        };
        let history = History::new(history, n).unwrap();
        model.set_scene(&history).unwrap();
        let mut out = vec![f64::NAN; batch * (n - 1) * t * 2];
        model.predict(&cand, &mut out).unwrap();
        let err = out
            .iter()
            .zip(&expected)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f64, f64::max);
        println!("{kind}/{variant} n={n}: max |rust - pytorch| = {err:.3e} m");
        assert!(
            err <= tol,
            "{kind}/{variant} n={n}: max error {err:.3e} > {tol:.1e}"
        );
        // The literal f64 reference must agree too (small scenes only: it is slow).
        if n <= 5 {
            let r = reference::predict_over(&w, &z, &history, &cand, t).unwrap();
            let rerr = max_err(&r, &expected);
            println!("{kind}/{variant} n={n}: max |reference - pytorch| = {rerr:.3e} m");
            assert!(rerr <= TOL, "reference n={n}: {rerr:.3e}");
        }
        worst = worst.max(err);
        n_cases += 1;
    }
    println!("{kind}/{variant}: {n_cases} scenes, worst error {worst:.3e} m");
    true
}

#[test]
fn golden_teacher_random() {
    golden("teacher", "random");
}

#[test]
fn golden_student_random() {
    golden("student", "random");
}

#[test]
fn golden_teacher_trained() {
    golden("teacher", "trained");
}

#[test]
fn golden_student_trained() {
    golden("student", "trained");
}

/// The trained teacher rolled out over 10 steps (3 s) against PyTorch's 10-step recursion.
#[test]
fn golden_teacher_trained_long_horizon() {
    assert!(
        golden("teacher", "trained_h10"),
        "the long-horizon cases are committed"
    );
}

// ---------------------------------------------------------------------------------------
// Property tests on synthetic (seeded, PyTorch-like initialised) weights.
// ---------------------------------------------------------------------------------------

fn weights(cfg: &ModelConfig) -> ModelWeights {
    ModelWeights::from_bytes(&synthetic_weights(cfg, 7).unwrap()).unwrap()
}

/// Fast (split pooling, folded embeddings, cached scene work) vs the literal reference.
fn check_against_reference(cfg: &ModelConfig, seed: u64, n: usize) {
    let w = weights(cfg);
    let z: Vec<f32> = w
        .tensor("fixed_noise")
        .map(|t| t.data.clone())
        .unwrap_or_default();
    let (history, cand) = scene(seed, n, 3);
    let mut fast: Box<dyn Predictor> = match cfg.kind {
        nudge_predictor::ModelKind::Teacher => Box::new(Teacher::from_weights(&w).unwrap()),
        nudge_predictor::ModelKind::Student => Box::new(Student::from_weights(&w).unwrap()),
    };
    let got = run(fast.as_mut(), &history, &cand);
    let want = reference::predict(&w, &z, &history, &cand).unwrap();
    let err = max_err(&got, &want);
    assert!(
        err <= TOL,
        "{:?} n={n}: fast vs reference {err:.3e}",
        cfg.kind
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]

    #[test]
    fn student_matches_reference(seed in any::<u64>(), n in 1usize..12) {
        check_against_reference(&ModelConfig::student(), seed, n);
    }

    #[test]
    fn teacher_matches_reference(seed in any::<u64>(), n in 1usize..7) {
        check_against_reference(&ModelConfig::teacher(), seed, n);
    }

    /// Sizes that are not multiples of the SIMD block width, a teacher that pools in its
    /// decoder, a student with noise and without decoder pooling.
    #[test]
    fn odd_configs_match_reference(seed in any::<u64>(), n in 1usize..7) {
        let odd = ModelConfig {
            embedding_dim: 5,
            encoder_h_dim: 7,
            decoder_h_dim: 9,
            mlp_dim: 11,
            bottleneck_dim: 13,
            pool_hidden_dim: 40,
            noise_dim: 3,
            ..ModelConfig::teacher()
        };
        check_against_reference(&ModelConfig { pool_every_timestep: true, ..odd.clone() }, seed, n);
        check_against_reference(
            &ModelConfig {
                pool_every_timestep: false,
                noise_dim: 2,
                ..ModelConfig { kind: nudge_predictor::ModelKind::Student, pred_len: 6, ..odd }
            },
            seed,
            n,
        );
    }

    /// Reordering the non-ego agents reorders the prediction, bit for bit.
    #[test]
    fn permutation_equivariance(seed in any::<u64>(), n in 2usize..9, shuffle in any::<u64>()) {
        let (history, cand) = scene(seed, n, 2);
        let mut perm: Vec<usize> = (1..n).collect();
        let mut rng = Rng(shuffle);
        for i in (1..perm.len()).rev() {
            let j = (rng.next() * (i + 1) as f64) as usize;
            perm.swap(i, j.min(i));
        }
        let permuted = history.permuted(&perm);
        let mut models: Vec<Box<dyn Predictor>> = vec![
            Box::new(Student::from_weights(&weights(&ModelConfig::student())).unwrap()),
            Box::new(Teacher::from_weights(&weights(&ModelConfig::teacher())).unwrap()),
            Box::new(ConstantVelocity::default()),
        ];
        for model in &mut models {
            let t = model.horizon();
            let a = run(model.as_mut(), &history, &cand);
            let b = run(model.as_mut(), &permuted, &cand);
            for bi in 0..2 {
                for (new, &old) in perm.iter().enumerate() {
                    let s = |agent: usize| ((bi * (n - 1) + agent - 1) * t) * 2;
                    prop_assert_eq!(
                        &a[s(old)..s(old) + 2 * t],
                        &b[s(new + 1)..s(new + 1) + 2 * t],
                        "{} agent {} -> {}", model.name(), old, new + 1
                    );
                }
            }
        }
    }

    /// Same inputs, same bits: repeated calls, a batch vs one candidate at a time, and a
    /// fresh instance.
    #[test]
    fn deterministic(seed in any::<u64>(), n in 1usize..10) {
        let (history, cand) = scene(seed, n, 3);
        let sw = weights(&ModelConfig::student());
        let tw = weights(&ModelConfig::teacher());
        let make = |k: usize| -> Box<dyn Predictor> {
            match k {
                0 => Box::new(Student::from_weights(&sw).unwrap()),
                _ => Box::new(Teacher::from_weights(&tw).unwrap()),
            }
        };
        for k in 0..2 {
            let mut m = make(k);
            let first = run(m.as_mut(), &history, &cand);
            let again = run(m.as_mut(), &history, &cand);
            let fresh = run(make(k).as_mut(), &history, &cand);
            prop_assert!(first.iter().all(|v| v.is_finite()));
            prop_assert_eq!(&first, &again);
            prop_assert_eq!(&first, &fresh);
            // One candidate at a time on the same scene.
            let per = first.len() / 3;
            for b in 0..3 {
                let mut out = vec![0.0; per];
                m.predict(&cand[b * 12..(b + 1) * 12], &mut out).unwrap();
                prop_assert_eq!(&out[..], &first[b * per..(b + 1) * per]);
            }
        }
    }

    /// Constant velocity: last position plus k times the last displacement, exactly.
    #[test]
    fn constant_velocity_exact(seed in any::<u64>(), n in 1usize..20) {
        let (history, cand) = scene(seed, n, 2);
        let out = run(&mut ConstantVelocity::default(), &history, &cand);
        for b in 0..2 {
            for a in 1..n {
                let last = history.at(a, T_OBS - 1);
                let prev = history.at(a, T_OBS - 2);
                for k in 1..=6 {
                    for c in 0..2 {
                        let want = last[c] + k as f64 * (last[c] - prev[c]);
                        let o = (((b * (n - 1)) + a - 1) * 6 + k - 1) * 2 + c;
                        prop_assert_eq!(out[o], want);
                    }
                }
            }
        }
    }
}

/// The teacher's noise changes its prediction; the default is the file's `fixed_noise`.
#[test]
fn teacher_noise() {
    let w = weights(&ModelConfig::teacher());
    let (history, cand) = scene(3, 6, 2);
    let fixed: Vec<f64> = w
        .tensor("fixed_noise")
        .unwrap()
        .data
        .iter()
        .map(|&v| f64::from(v))
        .collect();
    let mut t = Teacher::from_weights(&w).unwrap();
    assert_eq!(t.noise(), fixed);
    let base = run(&mut t, &history, &cand);
    let mut other = Teacher::from_weights(&w)
        .unwrap()
        .with_noise(&[0.5; 8])
        .unwrap();
    let moved = run(&mut other, &history, &cand);
    assert!(max_err(&base, &moved) > 1e-6, "noise has no effect");
    other.set_noise(&fixed).unwrap();
    assert_eq!(run(&mut other, &history, &cand), base);
}

#[test]
fn shipped_models_load() {
    for kind in [
        nudge_predictor::ModelKind::Teacher,
        nudge_predictor::ModelKind::Student,
    ] {
        let name = kind.as_str();
        let p: &Path = &nudge_predictor::model_path(&repo().join("assets"), kind);
        if !p.exists() {
            println!("NOTE: {} absent, skipped", p.display());
            continue;
        }
        let m = load_predictor(p).unwrap();
        assert_eq!(m.name(), name);
        assert_eq!(m.horizon(), 6);
    }
}

/// A longer horizon is a longer roll-out of the same one-step teacher: the first 6 of its 10
/// predicted steps are the 6-step prediction bit for bit, for every candidate and agent; a
/// horizon outside 1..=MAX_HORIZON is refused, naming it.
#[test]
fn teacher_horizon_10_extends_the_6_step_roll_out() {
    let w = weights(&ModelConfig::teacher());
    let (history, _) = scene(11, 6, 1);
    let (n, batch) = (6, 3);
    // Candidates [3, 10, 2]: the ego at 25 m/s drifting sideways at three rates.
    let last = history.at(0, T_OBS - 1);
    let long: Vec<f64> = (0..batch)
        .flat_map(|b| {
            (1..=10).flat_map(move |k| [last[0] + 7.5 * k as f64, last[1] + 0.2 * (b * k) as f64])
        })
        .collect();
    let short: Vec<f64> = long
        .chunks_exact(20)
        .flat_map(|c| c[..12].to_vec())
        .collect();
    let mut t10 = Teacher::from_weights(&w).unwrap().with_horizon(10).unwrap();
    let mut t6 = Teacher::from_weights(&w).unwrap();
    assert_eq!((t10.horizon(), t6.horizon()), (10, 6));
    let (p10, p6) = (
        run(&mut t10, &history, &long),
        run(&mut t6, &history, &short),
    );
    for b in 0..batch {
        for a in 0..n - 1 {
            let o10 = ((b * (n - 1) + a) * 10) * 2;
            let o6 = ((b * (n - 1) + a) * 6) * 2;
            assert_eq!(
                p10[o10..o10 + 12],
                p6[o6..o6 + 12],
                "candidate {b}, agent {}",
                a + 1
            );
        }
    }
    for h in [0, nudge_predictor::MAX_HORIZON + 1] {
        assert!(matches!(
            Teacher::from_weights(&w).unwrap().with_horizon(h),
            Err(nudge_predictor::PredictorError::Horizon { got, .. }) if got == h
        ));
    }
}
