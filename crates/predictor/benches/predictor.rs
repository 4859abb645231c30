//! Criterion benchmarks of the predictors, one thread.
//!
//! * group `predictor`, ids `teacher/{N}`, `student/{N}`, `constant_velocity/{N}`: a full
//!   from-scratch prediction, `set_scene` + `predict` of one candidate;
//! * group `predictor_batch32`, same ids: `set_scene` once + `predict` of 32 candidates.
//!
//! N ∈ {2, 4, 8, 16, 32} agents (ego included). Scenes come from
//! `benches/data/scenes.safetensors` (`n{N}.history` `[N, 8, 2]`, `n{N}.candidates`
//! `[32, 6, 2]`, f32 metres), weights from `assets/models/{teacher,student}.safetensors`;
//! both are written by `nudge-train goldens`.
#![allow(clippy::unwrap_used)]

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use nudge_predictor::{ConstantVelocity, History, Predictor, Student, Teacher};
use safetensors::SafeTensors;

const NS: [usize; 5] = [2, 4, 8, 16, 32];

/// This crate's directory.
fn here() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `(history, candidates [32, 6, 2])` of the bench scene with `n` agents.
fn scenes() -> Vec<(usize, History, Vec<f64>)> {
    let path = here().join("benches/data/scenes.safetensors");
    let bytes = std::fs::read(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (run make_goldens.py)", path.display()));
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let read = |name: String| -> Vec<f64> {
        let t = st.tensor(&name).unwrap();
        t.data()
            .chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .collect()
    };
    NS.iter()
        .map(|&n| {
            let history = History::new(read(format!("n{n}.history")), n).unwrap();
            (n, history, read(format!("n{n}.candidates")))
        })
        .collect()
}

fn models() -> Vec<Box<dyn Predictor>> {
    let dir = here().join("../../assets/models");
    vec![
        Box::new(Teacher::from_file(dir.join("teacher.safetensors")).unwrap()),
        Box::new(Student::from_file(dir.join("student.safetensors")).unwrap()),
        Box::new(ConstantVelocity::default()),
    ]
}

fn bench(c: &mut Criterion) {
    let scenes = scenes();
    let mut models = models();

    let mut group = c.benchmark_group("predictor");
    for model in &mut models {
        for (n, history, cand) in &scenes {
            let t = model.horizon();
            let one = &cand[..2 * t];
            let mut out = vec![0.0; (n - 1) * t * 2];
            group.bench_function(BenchmarkId::new(model.name(), n), |b| {
                b.iter(|| {
                    model.set_scene(black_box(history)).unwrap();
                    model.predict(black_box(one), black_box(&mut out)).unwrap();
                });
            });
        }
    }
    group.finish();

    let mut group = c.benchmark_group("predictor_batch32");
    for model in &mut models {
        for (n, history, cand) in &scenes {
            let t = model.horizon();
            let batch = cand.len() / (2 * t);
            let mut out = vec![0.0; batch * (n - 1) * t * 2];
            group.bench_function(BenchmarkId::new(model.name(), n), |b| {
                b.iter(|| {
                    model.set_scene(black_box(history)).unwrap();
                    model.predict(black_box(cand), black_box(&mut out)).unwrap();
                });
            });
        }
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(2))
        .sample_size(20);
    targets = bench
}
criterion_main!(benches);
