//! Measures where the networks stay finite and match the f64 reference as input magnitudes
//! grow; the measurement behind the accepted input ranges of `nudge_predictor::limits`.
//!
//! `cargo run --release -p nudge-predictor --example input_range [weights.safetensors ...]`
//! (default: the shipped `assets/models/{teacher,student}.safetensors`). For a 5-agent highway
//! scene it sweeps three magnitudes and prints, per value, whether every prediction is finite
//! and the largest difference from the literal f64 reference (`reference::predict`):
//!
//! * `shift`: every position (history and candidate) translated by (s, s): the networks see
//!   only differences, so the predictions must translate too; also prints the largest
//!   |pred(s) − s − pred(0)|;
//! * `step`: every agent moves about d metres per 0.3 s step (displacements);
//! * `offset`: one neighbour placed at (d, d) metres from the ego (offsets between agents).
#![allow(clippy::print_stdout, clippy::unwrap_used)]

use nudge_predictor::{
    History, ModelKind, ModelWeights, Predictor, Student, T_OBS, Teacher, reference,
};

/// `(x0, y0, vx per step)` of the scene's agents; ego first.
const AGENTS: [(f64, f64, f64); 5] = [
    (0.0, 0.0, 7.5),
    (25.0, 0.0, 7.0),
    (-20.0, 0.0, 8.0),
    (10.0, 3.7, 7.2),
    (-5.0, -3.7, 7.8),
];

/// History and one candidate: agents at `(x0, y0)` now, moving `vx * vscale` per step,
/// agent 1 moved to `(offset, offset)` metres from the ego, everything shifted by `(s, s)`.
fn scene(s: f64, vscale: f64, offset: Option<f64>) -> (History, Vec<f64>) {
    let mut pos = Vec::new();
    for (a, &(x0, y0, vx)) in AGENTS.iter().enumerate() {
        let (x0, y0) = match offset {
            Some(d) if a == 1 => (d, d),
            _ => (x0, y0),
        };
        for t in 0..T_OBS {
            let back = (T_OBS - 1 - t) as f64;
            pos.push(s + x0 - vx * vscale * back);
            pos.push(s + y0);
        }
    }
    let vx = AGENTS[0].2 * vscale;
    let cand: Vec<f64> = (1..=6)
        .flat_map(|k| [s + vx * k as f64, s + 0.2 * k as f64])
        .collect();
    (History::new(pos, AGENTS.len()).unwrap(), cand)
}

struct Model {
    weights: ModelWeights,
    fast: Box<dyn Predictor>,
    noise: Vec<f32>,
}

fn run(m: &mut Model, h: &History, cand: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut out = vec![0.0; (h.n_agents() - 1) * 12];
    m.fast.set_scene(h).unwrap();
    // Outputs, whatever they are: the range checks of `predict` are what this measures.
    let _ = m.fast.predict(cand, &mut out);
    let r = reference::predict(&m.weights, &m.noise, h, cand).unwrap();
    (out, r)
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            if x.is_finite() && y.is_finite() {
                (x - y).abs()
            } else {
                f64::NAN
            }
        })
        .fold(0.0, |m: f64, d| {
            if d.is_nan() || m.is_nan() {
                f64::NAN
            } else {
                m.max(d)
            }
        })
}

fn main() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let args: Vec<String> = std::env::args().skip(1).collect();
    let files: Vec<std::path::PathBuf> = if args.is_empty() {
        ["teacher", "student"]
            .iter()
            .map(|k| root.join(format!("assets/models/{k}.safetensors")))
            .collect()
    } else {
        args.iter().map(Into::into).collect()
    };
    let mut mags: Vec<f64> = vec![0.0];
    for e in 0..10 {
        for m in [1.0, 2.0, 5.0] {
            mags.push(m * 10f64.powi(e));
        }
    }
    mags.extend([
        1e10, 1e12, 1e15, 1e20, 1e30, 1e38, 1e39, 1e100, 1e154, 1e300,
    ]);
    for f in files {
        let weights = ModelWeights::from_file(&f).unwrap();
        let noise: Vec<f32> = weights
            .tensor("fixed_noise")
            .map(|t| t.data.clone())
            .unwrap_or_default();
        let fast: Box<dyn Predictor> = match weights.config().kind {
            ModelKind::Teacher => Box::new(Teacher::from_weights(&weights).unwrap()),
            ModelKind::Student => Box::new(Student::from_weights(&weights).unwrap()),
        };
        let mut m = Model {
            weights,
            fast,
            noise,
        };
        println!("== {}", f.display());
        let (h0, c0) = scene(0.0, 1.0, None);
        let (base, _) = run(&mut m, &h0, &c0);
        println!(
            "{:>10} | {:>8} {:>10} {:>10} | {:>8} {:>10} | {:>8} {:>10}",
            "magnitude",
            "shift ok",
            "vs ref",
            "translat.",
            "step ok",
            "vs ref",
            "offs ok",
            "vs ref"
        );
        for &v in &mags[1..] {
            let (h, c) = scene(v, 1.0, None);
            let (o, r) = run(&mut m, &h, &c);
            let shifted: Vec<f64> = o.iter().map(|x| x - v).collect();
            let (hs, cs) = scene(0.0, v / 7.5, None);
            let (os, rs) = run(&mut m, &hs, &cs);
            let (ho, co) = scene(0.0, 1.0, Some(v));
            let (oo, ro) = run(&mut m, &ho, &co);
            let fin = |x: &[f64]| x.iter().all(|v| v.is_finite());
            println!(
                "{v:>10.0e} | {:>8} {:>10.2e} {:>10.2e} | {:>8} {:>10.2e} | {:>8} {:>10.2e}",
                fin(&o),
                max_diff(&o, &r),
                max_diff(&shifted, &base),
                fin(&os),
                max_diff(&os, &rs),
                fin(&oo),
                max_diff(&oo, &ro),
            );
        }
    }
}
