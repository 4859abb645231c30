//! Criterion benchmarks of the run animations, one thread.
//!
//! * `animate/frame`: drawing one frame ([`draw_frame`]) of a traced run at the default
//!   settings (720 px wide);
//! * `animate/run`: a whole run drawn and written as a GIF ([`animate`], no MP4).
//!
//! The run: the shipped scene us101-19_1-t02.1-ego451 (17 vehicles), planned with constant
//! velocity, the log moving the others, 30 steps at most.
#![allow(clippy::unwrap_used)]

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use nudge::animate::{AnimationSettings, Reel, animate, draw_frame, frame_size};
use nudge::planner::{PlannerSettings, Scenario};
use nudge::predictor::ConstantVelocity;
use nudge::sim::{Cancel, RunControl, SimConfig, World, WorldModel, simulate_with};

fn reel() -> Reel {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("assets/scenes/us101-19_1-t02.1-ego451.safetensors");
    let sc = Scenario::from_file(path).unwrap();
    let cfg = SimConfig {
        world: World::LogReplay,
        ..SimConfig::default()
    };
    let control = RunControl {
        cancel: &Cancel::new(),
        trace: true,
    };
    let mut cv = ConstantVelocity::default();
    let s = PlannerSettings::default();
    let rec = simulate_with(&sc, &s, &cfg, 2, &mut cv, WorldModel::LogReplay, control).unwrap();
    Reel::from_run(&sc, &rec).unwrap()
}

fn bench(c: &mut Criterion) {
    let reel = reel();
    let settings = AnimationSettings::default();
    let size = frame_size(&reel, &settings).unwrap();
    let mid = reel.shots.len() / 2;
    let gif = std::env::temp_dir().join(format!("nudge-bench-{}.gif", std::process::id()));
    let mut group = c.benchmark_group("animate");
    group
        .sample_size(20)
        .measurement_time(Duration::from_secs(3));
    group.bench_function("frame", |b| {
        b.iter(|| draw_frame(black_box(&reel), mid, &settings, size));
    });
    group.bench_function(format!("run/{}_frames", reel.shots.len()), |b| {
        b.iter(|| animate(black_box(&reel), &settings, &gif, None).unwrap());
    });
    group.finish();
    let _ = std::fs::remove_file(&gif);
}

criterion_group!(benches, bench);
criterion_main!(benches);
