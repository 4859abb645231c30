//! The curvilinear (Frenet) road frame of a curved scene: a smooth reference path fitted to
//! the lanelet bounds, every point as (s, d) (arc length along the path, signed offset,
//! positive left) by its exact foot point, and the closed-form inverse. The data pipeline's
//! `frenet` frame (`nudge_train.data.frenet`: `fit_reference`, `ReferencePath`) step for step:
//!
//! 1. In the frame rotated by θ (as [`super::frame`]), the road's shape y = f(x) is a cubic
//!    P-spline: uniform knots about every [`KNOT_M`], fitted by least squares to every
//!    lanelet bound with one lateral offset per bound, f(0) = 0, and a second-difference
//!    penalty of weight [`SMOOTHING`]; bounds whose residual exceeds [`REJECT_M`] (ramp
//!    tapers, gores) are left out one at a time, worst first (at least two kept).
//! 2. s is the arc length of the path (Simpson per [`SAMPLE_M`] interval, 0 at x = 0); d the
//!    signed distance to the foot point, found by Newton's method on the path's parameter.
//! 3. The inverse is closed-form: the path point at s moved d along the left normal.
//!
//! Refused (typed, by the caller): a path turning by more than [`MAX_TURN_RAD`] over the
//! scene (not a graph over one direction), and a point whose foot lies beyond the path's ends
//! or whose projection does not converge.

use nalgebra::{DMatrix, DVector};

/// Knot spacing (m) of the reference path's cubic spline.
pub const KNOT_M: f64 = 25.0;
/// Weight of the spline's second-difference penalty (m⁻² against squared bound residuals).
pub const SMOOTHING: f64 = 1e-3;
/// Bounds deviating more than this (m) from the fitted shape leave the next fit.
pub const REJECT_M: f64 = 0.3;
/// The path extends this far (m) beyond the lanelets at both ends.
pub const MARGIN_M: f64 = 60.0;
/// Spacing (m) of the arc-length table.
pub const SAMPLE_M: f64 = 0.25;
/// Largest heading change (rad) of the path over the scene.
pub const MAX_TURN_RAD: f64 = 1.0;
/// Most lanelet bounds the path is fitted to: 400, 11 times the most of a US-101 file (36).
/// The fit solves a dense system with one unknown per bound, once per rejection round, so its
/// work grows with the cube of their number.
pub const MAX_FIT_BOUNDS: usize = 400;
/// Most spline intervals (knots every [`KNOT_M`]): 400, a scene 10 km long (a US-101 file
/// spans 0.6 km).
pub const MAX_INTERVALS: usize = 400;
/// Most rejection rounds of the fit (one bound left out per round; a US-101 file has at most
/// 36 bounds, so the rounds end before this).
pub const MAX_FIT_ROUNDS: usize = 64;

/// The uniform cubic B-spline basis on the interval `j` at local parameter `u` ∈ [0, 1]:
/// values (`nu` = 0), first or second derivatives in u (`nu` = 1, 2) of the 4 coefficients
/// j..j+3.
fn basis(u: f64, nu: usize) -> [f64; 4] {
    let w = 1.0 - u;
    match nu {
        0 => [
            w * w * w / 6.0,
            (3.0 * u * u * u - 6.0 * u * u + 4.0) / 6.0,
            (-3.0 * u * u * u + 3.0 * u * u + 3.0 * u + 1.0) / 6.0,
            u * u * u / 6.0,
        ],
        1 => [
            -w * w / 2.0,
            (3.0 * u * u - 4.0 * u) / 2.0,
            (-3.0 * u * u + 2.0 * u + 1.0) / 2.0,
            u * u / 2.0,
        ],
        _ => [w, 3.0 * u - 2.0, -3.0 * u + 1.0, u],
    }
}

/// The reference path: y = f(x) in the frame rotated by θ, a uniform cubic spline over
/// rotated x in [`Reference::x_lo`, `x_hi`], with its arc-length table.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// Rotation (rad).
    pub theta: f64,
    /// Start of the spline's range (rotated x, m).
    pub x_lo: f64,
    /// End of the spline's range (rotated x, m).
    pub x_hi: f64,
    /// Knot spacing (m).
    h: f64,
    /// Intervals.
    n_int: usize,
    /// Coefficients `[n_int + 3]` (m).
    coef: Vec<f64>,
    /// Arc-length table: rotated x ...
    table_u: Vec<f64>,
    /// ... and arc length (m, 0 at x = 0).
    table_s: Vec<f64>,
}

/// `p` rotated by −θ.
fn rotate(p: [f64; 2], theta: f64) -> [f64; 2] {
    let (s, c) = theta.sin_cos();
    [c * p[0] + s * p[1], -s * p[0] + c * p[1]]
}

impl Reference {
    /// The interval and local parameter of rotated x (clamped into the range).
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        clippy::cast_precision_loss
    )]
    fn locate(h: f64, n_int: usize, x_lo: f64, x: f64) -> (usize, f64) {
        let v = ((x - x_lo) / h).clamp(0.0, n_int as f64);
        let j = (v.floor() as usize).min(n_int - 1);
        (j, v - j as f64)
    }

    /// f (`nu` = 0) or its derivatives (1, 2) at rotated x (clamped to the range).
    fn f(&self, x: f64, nu: usize) -> f64 {
        let (j, u) = Self::locate(self.h, self.n_int, self.x_lo, x);
        let b = basis(u, nu);
        let scale = self.h.powi(i32::try_from(nu).unwrap_or(0));
        (0..4).map(|k| b[k] * self.coef[j + k]).sum::<f64>() / scale
    }

    /// Fits the path to the bounds `rot` (already rotated by `theta`, each ≥ 2 points).
    ///
    /// # Errors
    /// A reason when there are more than [`MAX_FIT_BOUNDS`] bounds, they span more than
    /// [`MAX_INTERVALS`] knot intervals, or the path turns by more than [`MAX_TURN_RAD`].
    pub fn fit(theta: f64, rot: &[Vec<[f64; 2]>]) -> Result<Self, String> {
        let (lo, hi) = rot
            .iter()
            .flatten()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
                (a.0.min(p[0]), a.1.max(p[0]))
            });
        let (lo, hi) = (lo - MARGIN_M, hi + MARGIN_M);
        if rot.len() > MAX_FIT_BOUNDS {
            return Err(format!(
                "{} lanelet bounds (the reference path is fitted to at most {MAX_FIT_BOUNDS})",
                rot.len()
            ));
        }
        let span = (hi - lo) / KNOT_M;
        #[allow(clippy::cast_precision_loss)]
        if !(span.is_finite() && span <= MAX_INTERVALS as f64) {
            return Err(format!(
                "the lanelets span {:.0} m (the reference path covers at most {:.0} m)",
                hi - lo,
                MAX_INTERVALS as f64 * KNOT_M
            ));
        }
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let n_int = (span.ceil() as usize).max(1);
        #[allow(clippy::cast_precision_loss)]
        let h = (hi - lo) / n_int as f64;
        let n_c = n_int + 3;
        let mut keep: Vec<usize> = (0..rot.len()).collect();
        let mut coef = vec![0.0; n_c];
        for _ in 0..rot.len().min(MAX_FIT_ROUNDS) {
            let cols = n_c + keep.len();
            // Normal equations of the stacked least-squares system.
            let mut ata = DMatrix::<f64>::zeros(cols, cols);
            let mut atb = DVector::<f64>::zeros(cols);
            let mut add_row = |idx: &[(usize, f64)], rhs: f64| {
                for &(a, va) in idx {
                    atb[a] += va * rhs;
                    for &(b, vb) in idx {
                        ata[(a, b)] += va * vb;
                    }
                }
            };
            for (k, &i) in keep.iter().enumerate() {
                for p in &rot[i] {
                    let (j, u) = Self::locate(h, n_int, lo, p[0]);
                    let b = basis(u, 0);
                    let row = [
                        (j, b[0]),
                        (j + 1, b[1]),
                        (j + 2, b[2]),
                        (j + 3, b[3]),
                        (n_c + k, 1.0),
                    ];
                    add_row(&row, p[1]);
                }
            }
            if lo <= 0.0 && 0.0 <= hi {
                let (j, u) = Self::locate(h, n_int, lo, 0.0);
                let b = basis(u, 0);
                let row: Vec<(usize, f64)> = (0..4).map(|q| (j + q, 1e3 * b[q])).collect();
                add_row(&row, 0.0);
            }
            let w = SMOOTHING.sqrt();
            for r in 0..n_c - 2 {
                add_row(&[(r, w), (r + 1, -2.0 * w), (r + 2, w)], 0.0);
            }
            let sol = ata
                .clone()
                .cholesky()
                .map(|c| c.solve(&atb))
                .or_else(|| ata.svd(true, true).solve(&atb, 1e-12).ok())
                .unwrap_or_else(|| DVector::zeros(cols));
            coef = sol.as_slice()[..n_c].to_vec();
            let path = Self {
                theta,
                x_lo: lo,
                x_hi: hi,
                h,
                n_int,
                coef: coef.clone(),
                table_u: Vec::new(),
                table_s: Vec::new(),
            };
            let worst: Vec<f64> = keep
                .iter()
                .enumerate()
                .map(|(k, &i)| {
                    rot[i]
                        .iter()
                        .map(|p| (p[1] - path.f(p[0], 0) - sol[n_c + k]).abs())
                        .fold(0.0, f64::max)
                })
                .collect();
            let (k_worst, &w_worst) = worst
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .unwrap_or((0, &0.0));
            if w_worst <= REJECT_M || keep.len() <= 2 {
                break;
            }
            keep.remove(k_worst);
        }
        let mut path = Self {
            theta,
            x_lo: lo,
            x_hi: hi,
            h,
            n_int,
            coef,
            table_u: Vec::new(),
            table_s: Vec::new(),
        };
        path.tabulate()?;
        Ok(path)
    }

    /// The arc-length table (Simpson per interval) and the turn check.
    fn tabulate(&mut self) -> Result<(), String> {
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let n = (((self.x_hi - self.x_lo) / SAMPLE_M).ceil() as usize).max(2);
        #[allow(clippy::cast_precision_loss)]
        let u: Vec<f64> = (0..=n)
            .map(|i| self.x_lo + (self.x_hi - self.x_lo) * i as f64 / n as f64)
            .collect();
        let speed = |x: f64| self.f(x, 1).hypot(1.0);
        let mut s = vec![0.0];
        for w in u.windows(2) {
            let seg = (w[1] - w[0]) / 6.0
                * (speed(w[0]) + 4.0 * speed(0.5 * (w[0] + w[1])) + speed(w[1]));
            s.push(s[s.len() - 1] + seg);
        }
        let zero = super::frame::interp(0.0, &u, &s);
        s.iter_mut().for_each(|v| *v -= zero);
        let (a_lo, a_hi) = u
            .iter()
            .map(|&x| self.f(x, 1).atan())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |a, v| {
                (a.0.min(v), a.1.max(v))
            });
        if a_hi - a_lo > MAX_TURN_RAD {
            return Err(format!(
                "the reference path turns by {:.0} deg over the scene (the frame follows at most \
                 {:.0} deg)",
                (a_hi - a_lo).to_degrees(),
                MAX_TURN_RAD.to_degrees()
            ));
        }
        self.table_u = u;
        self.table_s = s;
        Ok(())
    }

    /// The s range (m) of the path.
    #[must_use]
    pub fn s_range(&self) -> (f64, f64) {
        (self.table_s[0], self.table_s[self.table_s.len() - 1])
    }

    /// Signed curvature (1/m, positive turning left) at rotated x.
    #[must_use]
    pub fn curvature(&self, x: f64) -> f64 {
        let (f1, f2) = (self.f(x, 1), self.f(x, 2));
        f2 / (1.0 + f1 * f1).powf(1.5)
    }

    /// A file point (m) → (s, d) (m) and the foot's rotated x; `None` when the projection does
    /// not converge or the foot lies beyond the path's ends.
    #[must_use]
    pub fn project(&self, p: [f64; 2]) -> Option<([f64; 2], f64)> {
        let q = rotate(p, self.theta);
        let (px, py) = (q[0], q[1]);
        let mut u = px.clamp(self.x_lo, self.x_hi);
        for _ in 0..50 {
            let (f, f1, f2) = (self.f(u, 0), self.f(u, 1), self.f(u, 2));
            let g = (px - u) + (py - f) * f1;
            let gp = -1.0 - f1 * f1 + (py - f) * f2;
            let step = g / gp;
            u -= step;
            if step.abs() < 1e-10 {
                break;
            }
        }
        let (f, f1) = (self.f(u, 0), self.f(u, 1));
        let g = (px - u) + (py - f) * f1;
        let converged = u.is_finite() && g.abs() <= 1e-7 * (1.0 + (py - f).abs());
        if !converged || u <= self.x_lo || u >= self.x_hi {
            return None;
        }
        let d = (-(px - u) * f1 + (py - f)) / f1.hypot(1.0);
        let s = super::frame::interp(u, &self.table_u, &self.table_s);
        Some(([s, d], u))
    }

    /// (s, d) (m) → file point (m): the inverse of [`Reference::project`]; `None` outside the
    /// path's s range or for a non-finite input.
    #[must_use]
    pub fn to_file(&self, r: [f64; 2]) -> Option<[f64; 2]> {
        let (lo, hi) = self.s_range();
        if !(r[0].is_finite() && r[1].is_finite() && lo < r[0] && r[0] < hi) {
            return None;
        }
        let u = self.u_of_s(r[0]);
        let (f, f1) = (self.f(u, 0), self.f(u, 1));
        let n = f1.hypot(1.0);
        let q = [u - r[1] * f1 / n, f + r[1] / n];
        Some(rotate(q, -self.theta))
    }

    /// Rotated x of the path point at arc length `s` (m).
    #[must_use]
    pub fn u_of_s(&self, s: f64) -> f64 {
        super::frame::interp(s, &self.table_s, &self.table_u)
    }

    /// The path's direction (rad, file frame) at rotated x.
    #[must_use]
    pub fn tangent_angle(&self, x: f64) -> f64 {
        self.theta + self.f(x, 1).atan()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// Bounds along a circle of radius 400 m (lanes 3.6 m wide): the fitted path's (s, d) of
    /// every bound point is its arc length and constant offset, and the inverse returns the
    /// point.
    #[test]
    fn circle_is_straightened_and_inverted() {
        let r0 = 400.0;
        let bound = |off: f64| -> Vec<[f64; 2]> {
            (0..=60)
                .map(|i| {
                    let a = -0.2 + 0.4 * f64::from(i) / 60.0;
                    [(r0 - off) * a.sin(), r0 - (r0 - off) * a.cos()]
                })
                .collect()
        };
        let rot: Vec<Vec<[f64; 2]>> = [-1.8, 1.8, 5.4].iter().map(|&o| bound(o)).collect();
        let path = Reference::fit(0.0, &rot).unwrap();
        for (b, off) in rot.iter().zip([-1.8, 1.8, 5.4]) {
            let ds: Vec<f64> = b.iter().map(|&p| path.project(p).unwrap().0[1]).collect();
            let (lo, hi) = ds.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &v| {
                (a.0.min(v), a.1.max(v))
            });
            assert!(hi - lo < 0.05, "offset {off}: d spans {lo}..{hi}");
            for &p in b {
                let (r, _) = path.project(p).unwrap();
                let back = path.to_file(r).unwrap();
                assert!(
                    (back[0] - p[0]).hypot(back[1] - p[1]) < 1e-6,
                    "{p:?} -> {back:?}"
                );
            }
        }
        assert!((path.curvature(0.0) - 1.0 / r0).abs() < 2e-4);
    }

    /// Too many bounds or too long a span are refused at once, before any fit.
    #[test]
    fn oversized_inputs_are_refused_before_the_fit() {
        let line = |y: f64| vec![[0.0, y], [100.0, y]];
        let many: Vec<Vec<[f64; 2]>> = (0..=MAX_FIT_BOUNDS)
            .map(|k| line(f64::from(u32::try_from(k).unwrap())))
            .collect();
        let t = std::time::Instant::now();
        let err = Reference::fit(0.0, &many).unwrap_err();
        assert!(err.contains("401 lanelet bounds"), "{err}");
        let long = vec![vec![[0.0, 0.0], [2e4, 0.0]], vec![[0.0, 3.6], [2e4, 3.6]]];
        let err = Reference::fit(0.0, &long).unwrap_err();
        assert!(err.contains("span"), "{err}");
        assert!(t.elapsed().as_secs_f64() < 0.5);
    }
}
