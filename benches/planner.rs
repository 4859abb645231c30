//! Criterion benchmarks of the planner, one thread.
//!
//! * `planner/z_update/<predictor>/<N>`: one Z-update's worth of work, measured as the
//!   median Z-update time of a whole MPC call (the call is timed internally and divided);
//!   reported through criterion's `iter_custom` as the summed Z-update time.
//! * `planner/step/<predictor>/<N>`: one whole MPC call from a cold start (fresh planner).
//!
//! N ∈ {2, 4, 8, 16} vehicles (ego included): a real shipped scene (assets/scenes) keeping its
//! N − 1 nearest neighbours. Predictors: teacher, student (skipped when their weights file is
//! missing), constant velocity.
#![allow(clippy::unwrap_used)]

use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use nudge::planner::{Planner, PlannerSettings, PlanningProblem, Scenario};
use nudge::predictor::{
    ConstantVelocity, History, ModelKind, Predictor, load_predictor, model_path,
};

const NS: [usize; 4] = [2, 4, 8, 16];

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn predictors() -> Vec<Box<dyn Predictor>> {
    let mut v: Vec<Box<dyn Predictor>> = Vec::new();
    for kind in [ModelKind::Teacher, ModelKind::Student] {
        let p = model_path(&repo().join("assets"), kind);
        if p.exists() {
            v.push(load_predictor(&p).unwrap());
        } else {
            eprintln!("skipping {}: {} missing", kind.as_str(), p.display());
        }
    }
    v.push(Box::new(ConstantVelocity::default()));
    v
}

/// The densest shipped scene, cut to its n nearest vehicles.
fn scene(n: usize) -> Scenario {
    let (scenes, _) = Scenario::load_dir(repo().join("assets/scenes")).unwrap();
    let big = scenes
        .into_iter()
        .max_by_key(|s| (s.n_agents, s.name.clone()))
        .unwrap();
    assert!(big.n_agents >= n, "no shipped scene with {n} vehicles");
    big.nearest(n - 1)
}

fn bench(c: &mut Criterion) {
    let settings = PlannerSettings::default();
    let mut preds = predictors();
    let mut group = c.benchmark_group("planner");
    group
        .sample_size(20)
        .measurement_time(Duration::from_secs(4))
        .warm_up_time(Duration::from_secs(1));
    for &n in &NS {
        let sc = scene(n);
        let history = History::new(sc.history.clone(), sc.n_agents).unwrap();
        let target = if sc.ego_lane + 1 < sc.lane_centres.len() {
            sc.ego_lane + 1
        } else {
            sc.ego_lane - 1
        };
        let problem = PlanningProblem::at_scenario_start(&sc, &history, sc.lane_centres[target]);
        for pred in &mut preds {
            let name = pred.name();
            group.bench_function(BenchmarkId::new(format!("step/{name}"), n), |b| {
                b.iter(|| {
                    let mut planner = Planner::new(settings.clone()).unwrap();
                    black_box(planner.plan(black_box(&problem), pred.as_mut()).unwrap())
                });
            });
            group.bench_function(BenchmarkId::new(format!("z_update/{name}"), n), |b| {
                b.iter_custom(|iters| {
                    let mut total = Duration::ZERO;
                    let mut done = 0u64;
                    while done < iters {
                        let mut planner = Planner::new(settings.clone()).unwrap();
                        let t0 = Instant::now();
                        let plan = planner.plan(&problem, pred.as_mut()).unwrap();
                        let _ = t0.elapsed();
                        for z in &plan.timings.z_updates_s {
                            if done < iters {
                                total += Duration::from_secs_f64(*z);
                                done += 1;
                            }
                        }
                    }
                    total
                });
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
