//! Times one predictor outside criterion (for profiling under `perf` / `valgrind`):
//! `cargo run --release -p nudge-predictor --example timing -- <teacher|student> <N> <iters> [batch]`
//! with the shipped weights (`assets/models`) and the bench scenes
//! (`crates/predictor/benches/data/scenes.safetensors`). Prints the mean wall time of `set_scene` + `predict`.
#![allow(clippy::print_stdout)]

use std::time::Instant;

use nudge_predictor::{History, ModelKind, Predictor, Student, Teacher, model_path};
use safetensors::SafeTensors;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let model = args.get(1).map_or("student", String::as_str);
    let n: usize = args.get(2).map_or(Ok(8), |s| s.parse())?;
    let iters: usize = args.get(3).map_or(Ok(1000), |s| s.parse())?;
    let batch: usize = args.get(4).map_or(Ok(1), |s| s.parse())?;
    let here = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let bytes = std::fs::read(here.join("benches/data/scenes.safetensors"))?;
    let st = SafeTensors::deserialize(&bytes)?;
    let read = |name: &str| -> Result<Vec<f64>, safetensors::SafeTensorError> {
        let t = st.tensor(name)?;
        Ok(t.data()
            .chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .collect())
    };
    let history = History::new(read(&format!("n{n}.history"))?, n)?;
    let cand = read(&format!("n{n}.candidates"))?;
    let cand = &cand[..batch * 12];
    let assets = here.join("../../assets");
    let mut p: Box<dyn Predictor> = match model {
        "teacher" => Box::new(Teacher::from_file(model_path(&assets, ModelKind::Teacher))?),
        _ => Box::new(Student::from_file(model_path(&assets, ModelKind::Student))?),
    };
    let mut out = vec![0.0; batch * (n - 1) * 12];
    let start = Instant::now();
    for _ in 0..iters {
        p.set_scene(std::hint::black_box(&history))?;
        p.predict(std::hint::black_box(cand), &mut out)?;
    }
    let dt = start.elapsed().as_secs_f64() / iters as f64;
    println!(
        "{model} n={n} batch={batch}: {:.2} us per set_scene+predict",
        dt * 1e6
    );
    Ok(())
}
