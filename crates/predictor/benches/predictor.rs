//! Criterion benchmarks of the predictors, one thread.
//!
//! * group `predictor`, ids `teacher/{N}`, `student/{N}`, `constant_velocity/{N}`: a full
//!   from-scratch prediction, `set_scene` + `predict` of one candidate;
//! * group `predictor_batch32`, same ids: `set_scene` once + `predict` of 32 candidates;
//! * group `predictor_simd`, ids `{teacher,student}_{portable,avx2,avx512}/{N}`: the
//!   `predictor` measurement on every instruction-set path this CPU supports, side by side
//!   (the `predictor` group itself runs the default path, `NUDGE_SIMD` or the widest).
//!
//! After criterion, a report (skipped with `--test`/`--list`) prints, per path: the measured
//! one-thread multiply-add peak (a register-only FMA loop, [`fma_peak_loop`]), then per model,
//! path and N the latency of a full prediction from individually timed calls interleaved
//! across paths (p50, p99, max, µs), the multiply-adds of one prediction
//! ([`multiply_adds`]), the achieved GMAC/s at the median and its share of the path's peak,
//! the criterion median of `predictor_simd` when present, and the teacher/student ratio.
//!
//! N ∈ {2, 4, 8, 16, 32} agents (ego included). Scenes come from
//! `benches/data/scenes.safetensors` (`n{N}.history` `[N, 8, 2]`, `n{N}.candidates`
//! `[32, 6, 2]`, f32 metres), weights from `assets/models/{teacher,student}.safetensors`;
//! both are written by `nudge-train goldens`.
#![allow(clippy::unwrap_used)]

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group};
use nudge_predictor::simd::fma_peak_loop;
use nudge_predictor::{
    ConstantVelocity, History, ModelKind, ModelWeights, Predictor, SimdPath, Student, Teacher,
    multiply_adds, supported_simd_paths,
};
use safetensors::SafeTensors;

const NS: [usize; 5] = [2, 4, 8, 16, 32];

/// This crate's directory.
fn here() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The repository root (two levels above this crate).
fn repo() -> PathBuf {
    here().join("../..")
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

/// The teacher or student of `w` running on `path`.
fn on_path(w: &ModelWeights, path: SimdPath) -> Box<dyn Predictor> {
    match w.config().kind {
        ModelKind::Teacher => {
            let mut m = Teacher::from_weights(w).unwrap();
            m.set_simd_path(path).unwrap();
            Box::new(m)
        }
        ModelKind::Student => {
            let mut m = Student::from_weights(w).unwrap();
            m.set_simd_path(path).unwrap();
            Box::new(m)
        }
    }
}

fn shipped(name: &str) -> ModelWeights {
    ModelWeights::from_file(repo().join(format!("assets/models/{name}.safetensors"))).unwrap()
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

    let mut group = c.benchmark_group("predictor_simd");
    for name in ["teacher", "student"] {
        let w = shipped(name);
        for (n, history, cand) in &scenes {
            for path in supported_simd_paths() {
                let mut model = on_path(&w, path);
                let t = model.horizon();
                let one = &cand[..2 * t];
                let mut out = vec![0.0; (n - 1) * t * 2];
                group.bench_function(BenchmarkId::new(format!("{name}_{path}"), n), |b| {
                    b.iter(|| {
                        model.set_scene(black_box(history)).unwrap();
                        model.predict(black_box(one), black_box(&mut out)).unwrap();
                    });
                });
            }
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
fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    let args: Vec<String> = std::env::args().collect();
    if !args.iter().any(|a| a == "--test" || a == "--list") {
        report::print(&scenes());
    }
}

/// The latency / GMAC/s report (see the module docs).
#[allow(clippy::print_stdout)]
mod report {
    use std::time::{Duration, Instant};

    use super::*;

    /// Multiply-adds per second of the path's register-only FMA loop, best of 5 runs.
    fn peak_gmacs(path: SimdPath) -> f64 {
        let iterations = 20_000_000;
        (0..5)
            .map(|_| {
                let start = Instant::now();
                let (macs, sum) = fma_peak_loop(path, black_box(iterations)).unwrap();
                black_box(sum);
                macs as f64 / start.elapsed().as_secs_f64() / 1e9
            })
            .fold(0.0, f64::max)
    }

    /// Criterion's median (µs) of `predictor_simd/{id}/{n}`, if that bench has run.
    fn criterion_median_us(id: &str, n: usize) -> Option<f64> {
        let dir = std::env::var_os("CARGO_TARGET_DIR")
            .map_or_else(|| repo().join("target"), PathBuf::from);
        let path = dir.join(format!(
            "criterion/predictor_simd/{id}/{n}/new/estimates.json"
        ));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()?;
        Some(json["median"]["point_estimate"].as_f64()? / 1e3)
    }

    /// Sorted latencies (µs) of full predictions, one vector per path, calls interleaved
    /// round-robin across paths for at least `budget` per path.
    fn latencies(
        models: &mut [Box<dyn Predictor>],
        history: &History,
        one: &[f64],
        budget: Duration,
    ) -> Vec<Vec<f64>> {
        let n = history.n_agents();
        let mut out = vec![0.0; (n - 1) * one.len()];
        let mut samples = vec![Vec::new(); models.len()];
        let start = Instant::now();
        while start.elapsed() < budget * models.len() as u32 || samples[0].len() < 200 {
            for (m, s) in models.iter_mut().zip(&mut samples) {
                let t0 = Instant::now();
                m.set_scene(black_box(history)).unwrap();
                m.predict(black_box(one), black_box(&mut out)).unwrap();
                s.push(t0.elapsed().as_secs_f64() * 1e6);
            }
            if samples[0].len() >= 20_000 {
                break;
            }
        }
        for s in &mut samples {
            s.sort_by(f64::total_cmp);
        }
        samples
    }

    fn quantile(sorted: &[f64], q: f64) -> f64 {
        sorted[((sorted.len() - 1) as f64 * q).round() as usize]
    }

    pub(super) fn print(scenes: &[(usize, History, Vec<f64>)]) {
        let paths = supported_simd_paths();
        let threads = std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset".into());
        println!(
            "\n## Inference latency and throughput (one thread; RAYON_NUM_THREADS={threads})\n"
        );
        let peaks: Vec<f64> = paths.iter().map(|&p| peak_gmacs(p)).collect();
        println!("| path | FMA peak GMAC/s (one core, register-only loop) |");
        println!("|---|---:|");
        for (p, g) in paths.iter().zip(&peaks) {
            println!("| {p} | {g:.1} |");
        }
        println!(
            "\n| model | N | path | p50 µs | p99 µs | max µs | criterion median µs | MMAC | GMAC/s (p50) | % of peak |"
        );
        println!("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|");
        let mut p50s = std::collections::BTreeMap::new();
        for name in ["teacher", "student"] {
            let w = shipped(name);
            let budget = Duration::from_millis(if name == "teacher" { 400 } else { 200 });
            for (n, history, cand) in scenes {
                let mut models: Vec<_> = paths.iter().map(|&p| on_path(&w, p)).collect();
                let t = models[0].horizon();
                let lat = latencies(&mut models, history, &cand[..2 * t], budget);
                let macs = multiply_adds(w.config(), *n).total(1) as f64;
                for ((path, s), peak) in paths.iter().zip(&lat).zip(&peaks) {
                    let p50 = quantile(s, 0.5);
                    let gmacs = macs / p50 / 1e3;
                    let crit = criterion_median_us(&format!("{name}_{path}"), *n)
                        .map_or_else(|| "—".to_owned(), |v| format!("{v:.2}"));
                    println!(
                        "| {name} | {n} | {path} | {p50:.2} | {:.2} | {:.2} | {crit} | {:.3} | {gmacs:.1} | {:.0} |",
                        quantile(s, 0.99),
                        s[s.len() - 1],
                        macs / 1e6,
                        100.0 * gmacs / peak,
                    );
                    p50s.insert((name, *n, *path), p50);
                }
            }
        }
        println!("\n| N | path | teacher/student (p50) | teacher/student (criterion) |");
        println!("|---:|---|---:|---:|");
        for (n, _, _) in scenes {
            for path in &paths {
                let r = p50s[&("teacher", *n, *path)] / p50s[&("student", *n, *path)];
                let crit = criterion_median_us(&format!("teacher_{path}"), *n)
                    .zip(criterion_median_us(&format!("student_{path}"), *n))
                    .map_or_else(|| "—".to_owned(), |(t, s)| format!("{:.1}", t / s));
                println!("| {n} | {path} | {r:.1} | {crit} |");
            }
        }
    }
}
