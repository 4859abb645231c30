//! Helpers shared by the predictor crate's integration tests: a seeded pseudo-random stream and
//! synthetic highway scenes.
#![allow(dead_code)]

use nudge_predictor::{History, Predictor, T_OBS};

/// Deterministic pseudo-random stream in [0, 1).
pub struct Rng(pub u64);
impl Rng {
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// A highway-like scene of `n` agents (ego's last position at the origin) and `batch`
/// candidates `[batch, 6, 2]`, positions rounded to f32 as the goldens are.
pub fn scene(seed: u64, n: usize, batch: usize) -> (History, Vec<f64>) {
    let mut rng = Rng(seed);
    let mut pos = Vec::with_capacity(n * T_OBS * 2);
    for a in 0..n {
        let (x0, y0) = if a == 0 {
            (0.0, 0.0)
        } else {
            (rng.range(-60.0, 60.0), rng.range(-8.0, 8.0))
        };
        let v = rng.range(5.0, 30.0) * 0.3;
        let drift = rng.range(-0.1, 0.1);
        for t in 0..T_OBS {
            let back = (T_OBS - 1 - t) as f64;
            pos.push(f64::from((x0 - back * v) as f32));
            pos.push(f64::from((y0 - back * drift) as f32));
        }
    }
    let v0 = pos[2 * T_OBS - 2] - pos[2 * T_OBS - 4];
    let mut cand = Vec::with_capacity(batch * 12);
    for _ in 0..batch {
        let accel = rng.range(-1.0, 1.0);
        let lat = rng.range(-3.5, 3.5);
        for k in 1..=6 {
            let s = k as f64;
            cand.push(f64::from((s * v0 + 0.5 * accel * s * s * 0.09) as f32));
            cand.push(f64::from((lat * s / 6.0) as f32));
        }
    }
    (History::new(pos, n).unwrap(), cand)
}

/// Predictions `[batch, n − 1, T, 2]` (flat) of `model` for the candidates `cand` on `history`.
pub fn run(model: &mut dyn Predictor, history: &History, cand: &[f64]) -> Vec<f64> {
    let n = history.n_agents();
    let t = model.horizon();
    let mut out = vec![f64::NAN; cand.len() / (2 * t) * (n - 1) * t * 2];
    model.set_scene(history).unwrap();
    model.predict(cand, &mut out).unwrap();
    out
}

/// Largest |a − b| over two equally long slices.
pub fn max_err(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}
