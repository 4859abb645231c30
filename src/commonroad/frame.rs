//! The road frame of a CommonRoad scene and its inverse: the transform of the data pipeline
//! (`nudge_train.data.commonroad`, which made every nudge scenario), step for step, so that a
//! scenario read here equals one the pipeline writes (tested against it to 1 mm).
//!
//! 1. **Rotation** by θ: the length-weighted mean direction of every lanelet bound (first to
//!    last point), refined by the span-weighted mean least-squares slope of every bound longer
//!    than [`MIN_SLOPE_SPAN`] in the rotated frame.
//! 2. **Straightening**: a polynomial centre-line shape y = a₁x + a₂x² (+ a₃x³ when the bounds
//!    span more than [`CUBIC_SPAN`]) fitted, with one offset per bound, to the bounds longer
//!    than [`MIN_FIT_SPAN`]; bounds off it by more than [`FIT_REJECT`] are dropped and the fit
//!    repeated (at most [`FIT_ROUNDS`] times). Road x = arc length along the shape (tabulated on
//!    [`ARC_GRID`] points), road y = perpendicular offset, positive left.
//!
//! The inverse ([`RoadFrame::to_file`]) solves the forward map by Newton's method, so the
//! round trip is exact to ≪ 1 µm.
//!
//! **Range.** The frame is defined where its arc-length table is ([`RoadFrame::road_range`]:
//! the lane map's x range plus [`FIT_MARGIN`] + [`ARC_MARGIN`] on either side). Beyond it the
//! forward map is constant in x (numpy's `interp` clamps), so it has no inverse there:
//! [`RoadFrame::try_to_file`] answers `None` for such a road point rather than extrapolating a
//! road the file does not describe, and the solution writer refuses a trajectory that leaves
//! the range with a typed error naming the time step.

use nalgebra::{DMatrix, DVector};

use super::frenet::Reference;
use super::xml::RawLanelet;

/// Bounds spanning more than this (m, rotated x) refine the rotation.
pub const MIN_SLOPE_SPAN: f64 = 5.0;
/// Bounds spanning more than this (m) enter the shape fit (all bounds when none does).
pub const MIN_FIT_SPAN: f64 = 20.0;
/// The shape is cubic when the fitted bounds span more than this (m), else quadratic.
pub const CUBIC_SPAN: f64 = 150.0;
/// A bound farther than this (m) from the fitted shape is dropped from the next round.
pub const FIT_REJECT: f64 = 0.3;
/// Most rounds of the shape fit.
pub const FIT_ROUNDS: usize = 4;
/// The shape's valid range extends this far (m) beyond the fitted bounds' x range.
pub const FIT_MARGIN: f64 = 50.0;
/// The arc-length table extends this far (m) beyond the shape's valid range.
pub const ARC_MARGIN: f64 = 200.0;
/// Points of the arc-length table.
pub const ARC_GRID: usize = 4001;

/// Linear interpolation with numpy's `interp` semantics: `xp` ascending, constant beyond the
/// ends; NaN for a NaN `x` (as numpy).
pub(crate) fn interp(x: f64, xp: &[f64], fp: &[f64]) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    let n = xp.len();
    if x <= xp[0] {
        return fp[0];
    }
    if x >= xp[n - 1] {
        return fp[n - 1];
    }
    let j = xp.partition_point(|&v| v <= x) - 1;
    let slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]);
    slope * (x - xp[j]) + fp[j]
}

/// Polynomial value, coefficients highest power first (Horner).
fn polyval(coef: &[f64], x: f64) -> f64 {
    coef.iter().fold(0.0, |y, c| y * x + c)
}

/// Peak-to-peak of the x coordinates (m).
fn x_span(poly: &[[f64; 2]]) -> f64 {
    let (lo, hi) = poly
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
            (l.min(p[0]), h.max(p[0]))
        });
    hi - lo
}

/// `p` rotated by −θ (so direction θ maps to +x).
fn rotate(p: [f64; 2], theta: f64) -> [f64; 2] {
    let (s, c) = theta.sin_cos();
    [c * p[0] + s * p[1], -s * p[0] + c * p[1]]
}

/// Wraps an angle (rad) into [−π, π) as Python's `(a + π) % 2π − π`.
#[must_use]
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::PI;
    (a + PI).rem_euclid(2.0 * PI) - PI
}

/// The travel direction θ (rad) of the lanelet bounds (step 1 of the module docs).
fn direction(lanelets: &[RawLanelet]) -> f64 {
    let mut d = [0.0, 0.0];
    for ll in lanelets {
        for b in [&ll.left, &ll.right] {
            let (first, last) = (b[0], b[b.len() - 1]);
            d[0] += last[0] - first[0];
            d[1] += last[1] - first[1];
        }
    }
    let theta = d[1].atan2(d[0]);
    let (mut num, mut den) = (0.0, 0.0);
    for b in lanelets.iter().flat_map(|ll| [&ll.left, &ll.right]) {
        let p: Vec<[f64; 2]> = b.iter().map(|&q| rotate(q, theta)).collect();
        let span = x_span(&p);
        if span > MIN_SLOPE_SPAN {
            #[allow(clippy::cast_precision_loss)]
            let mean = p.iter().map(|q| q[0]).sum::<f64>() / p.len() as f64;
            let sxy: f64 = p.iter().map(|q| (q[0] - mean) * q[1]).sum();
            let sxx: f64 = p.iter().map(|q| (q[0] - mean) * (q[0] - mean)).sum();
            num += span * sxy / sxx;
            den += span;
        }
    }
    if den > 0.0 {
        theta + (num / den).atan()
    } else {
        theta
    }
}

/// One least-squares round of the shape fit on the bounds `keep` of `polys` (x scaled by
/// `scale`): returns (shape coefficients `[deg]` of u¹..u^deg, per-bound offsets `[keep]`).
fn fit_round(
    polys: &[Vec<[f64; 2]>],
    keep: &[usize],
    deg: usize,
    scale: f64,
) -> (Vec<f64>, Vec<f64>) {
    let rows: usize = keep.iter().map(|&i| polys[i].len()).sum();
    let cols = deg + keep.len();
    let mut a = DMatrix::<f64>::zeros(rows, cols);
    let mut b = DVector::<f64>::zeros(rows);
    let mut r = 0;
    for (k, &i) in keep.iter().enumerate() {
        for p in &polys[i] {
            let u = p[0] / scale;
            for d in 1..=deg {
                a[(r, d - 1)] = u.powi(i32::try_from(d).unwrap_or(3));
            }
            a[(r, deg + k)] = 1.0;
            b[r] = p[1];
            r += 1;
        }
    }
    let sol = a
        .svd(true, true)
        .solve(&b, 1e-12)
        .unwrap_or_else(|_| DVector::zeros(cols));
    (
        sol.as_slice()[..deg].to_vec(),
        sol.as_slice()[deg..].to_vec(),
    )
}

/// The largest |y − fitted y| (m) of bound `p` under `shape` (scaled) plus `offset`.
fn fit_residual(p: &[[f64; 2]], shape: &[f64], offset: f64, scale: f64) -> f64 {
    p.iter()
        .map(|q| {
            let u = q[0] / scale;
            let pred: f64 = shape
                .iter()
                .enumerate()
                .map(|(d, c)| c * u.powi(i32::try_from(d + 1).unwrap_or(3)))
                .sum::<f64>()
                + offset;
            (q[1] - pred).abs()
        })
        .fold(0.0, f64::max)
}

/// The centre-line shape (step 2): coefficients highest power first (constant 0) and the x
/// range (m) it is valid over.
fn fit_shape(rot_bounds: &[Vec<[f64; 2]>]) -> (Vec<f64>, f64, f64) {
    let mut polys: Vec<Vec<[f64; 2]>> = rot_bounds
        .iter()
        .filter(|p| x_span(p) > MIN_FIT_SPAN)
        .cloned()
        .collect();
    if polys.is_empty() {
        polys = rot_bounds.to_vec();
    }
    let xs = polys.iter().flatten().map(|p| p[0]);
    let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
        (l.min(x), h.max(x))
    });
    let scale = x0.abs().max(x1.abs()).max(1.0);
    let deg = if x1 - x0 > CUBIC_SPAN { 3 } else { 2 };
    let mut keep: Vec<usize> = (0..polys.len()).collect();
    let mut coef = vec![0.0; deg + 1];
    for _ in 0..FIT_ROUNDS {
        let (shape, offsets) = fit_round(&polys, &keep, deg, scale);
        let new_keep: Vec<usize> = keep
            .iter()
            .zip(&offsets)
            .filter(|&(&i, &o)| fit_residual(&polys[i], &shape, o, scale) <= FIT_REJECT)
            .map(|(&i, _)| i)
            .collect();
        coef = (1..=deg)
            .rev()
            .map(|d| shape[d - 1] / scale.powi(i32::try_from(d).unwrap_or(3)))
            .chain([0.0])
            .collect();
        if new_keep.len() == keep.len() || new_keep.len() < 2 {
            break;
        }
        keep = new_keep;
    }
    (coef, x0 - FIT_MARGIN, x1 + FIT_MARGIN)
}

/// The road frame of one scene: rotation θ, straightened along a fitted polynomial shape.
#[derive(Debug, Clone, PartialEq)]
pub struct RoadFrame {
    /// Rotation (rad): the file's direction θ is the rotated frame's +x.
    pub theta: f64,
    /// Shape y(x) in the rotated frame, coefficients highest power first (m, 1/m, ...).
    pub coef: Vec<f64>,
    /// The shape's derivative, highest power first.
    deriv: Vec<f64>,
    /// Arc-length table: rotated x `[ARC_GRID]` (m) ...
    grid_x: Vec<f64>,
    /// ... and the arc length at each (m; 0 at rotated x = 0).
    grid_arc: Vec<f64>,
    /// The curvilinear frame's reference path ([`RoadFrame::curvilinear`]); `None` for the
    /// straightened frame.
    path: Option<Reference>,
}

impl RoadFrame {
    /// Fits the frame to the lanelets of a scene (at least one, each bound ≥ 2 points).
    #[must_use]
    pub fn fit(lanelets: &[RawLanelet]) -> Self {
        let theta = direction(lanelets);
        let rot: Vec<Vec<[f64; 2]>> = lanelets
            .iter()
            .flat_map(|ll| [&ll.left, &ll.right])
            .map(|b| b.iter().map(|&p| rotate(p, theta)).collect())
            .collect();
        let (coef, x0, x1) = fit_shape(&rot);
        let deg = coef.len() - 1;
        #[allow(clippy::cast_precision_loss)]
        let deriv: Vec<f64> = coef[..deg]
            .iter()
            .enumerate()
            .map(|(k, c)| c * (deg - k) as f64)
            .collect();
        let (lo, hi) = (x0 - ARC_MARGIN, x1 + ARC_MARGIN);
        #[allow(clippy::cast_precision_loss)]
        let step = (hi - lo) / (ARC_GRID - 1) as f64;
        #[allow(clippy::cast_precision_loss)]
        let mut grid_x: Vec<f64> = (0..ARC_GRID).map(|i| i as f64 * step + lo).collect();
        grid_x[ARC_GRID - 1] = hi;
        let mut grid_arc = Vec::with_capacity(ARC_GRID);
        let mut acc = 0.0;
        grid_arc.push(0.0);
        for w in grid_x.windows(2) {
            acc += (w[1] - w[0]).hypot(polyval(&coef, w[1]) - polyval(&coef, w[0]));
            grid_arc.push(acc);
        }
        let zero = interp(0.0, &grid_x, &grid_arc);
        grid_arc.iter_mut().for_each(|a| *a -= zero);
        Self {
            theta,
            coef,
            deriv,
            grid_x,
            grid_arc,
            path: None,
        }
    }

    /// The curvilinear (Frenet) frame of the lanelets ([`super::frenet`]): road x = arc
    /// length s along a P-spline reference path fitted to every bound, road y = the signed
    /// offset d of the exact foot point (positive left). For scenes whose lanes are not
    /// straight lines in the straightened frame ([`RoadFrame::fit`]). `coef` is empty.
    ///
    /// # Errors
    /// A reason when the reference path turns by more than [`super::frenet::MAX_TURN_RAD`].
    pub fn curvilinear(lanelets: &[RawLanelet]) -> Result<Self, String> {
        let theta = direction(lanelets);
        let rot: Vec<Vec<[f64; 2]>> = lanelets
            .iter()
            .flat_map(|ll| [&ll.left, &ll.right])
            .map(|b| b.iter().map(|&p| rotate(p, theta)).collect())
            .collect();
        let path = Reference::fit(theta, &rot)?;
        Ok(Self {
            theta,
            coef: Vec::new(),
            deriv: Vec::new(),
            grid_x: Vec::new(),
            grid_arc: Vec::new(),
            path: Some(path),
        })
    }

    /// The curvilinear frame's reference-path curvature (1/m, positive turning left) at road
    /// x `s` (m); `None` for the straightened frame.
    #[must_use]
    pub fn curvature_at(&self, s: f64) -> Option<f64> {
        let path = self.path.as_ref()?;
        Some(path.curvature(path.u_of_s(s)))
    }

    /// Whether this is the curvilinear frame ([`RoadFrame::curvilinear`]).
    #[must_use]
    pub fn is_curvilinear(&self) -> bool {
        self.path.is_some()
    }

    /// The curvilinear frame's (s, d) of file point `p` and |curvature · d| at its foot (the
    /// projection is unique while this is below 1); `None` for the straightened frame or a
    /// point whose foot lies beyond the reference path.
    #[must_use]
    pub fn project(&self, p: [f64; 2]) -> Option<([f64; 2], f64)> {
        let path = self.path.as_ref()?;
        let (r, u) = path.project(p)?;
        Some((r, (path.curvature(u) * r[1]).abs()))
    }

    /// The road direction (rad) at rotated-frame x (m).
    fn tangent_angle(&self, x: f64) -> f64 {
        polyval(&self.deriv, x).atan()
    }

    /// Rotated-frame point (m) → road frame (m).
    fn rotated_to_road(&self, q: [f64; 2]) -> [f64; 2] {
        let ang = self.tangent_angle(q[0]);
        let dy = q[1] - polyval(&self.coef, q[0]);
        let (s, c) = ang.sin_cos();
        let x_foot = q[0] + dy * s * c;
        [interp(x_foot, &self.grid_x, &self.grid_arc), dy * c]
    }

    /// A point of the file's frame (m) → road frame (x along travel, y left) (m).
    #[must_use]
    pub fn to_road(&self, p: [f64; 2]) -> [f64; 2] {
        if let Some(path) = &self.path {
            return path.project(p).map_or([f64::NAN; 2], |(r, _)| r);
        }
        self.rotated_to_road(rotate(p, self.theta))
    }

    /// An orientation (rad) at file point `p` → heading relative to the road, in [−π, π).
    #[must_use]
    pub fn heading_to_road(&self, p: [f64; 2], orientation: f64) -> f64 {
        if let Some(path) = &self.path {
            return path.project(p).map_or(f64::NAN, |(_, u)| {
                wrap_angle(orientation - path.tangent_angle(u))
            });
        }
        let q = rotate(p, self.theta);
        wrap_angle(orientation - self.theta - self.tangent_angle(q[0]))
    }

    /// The inverse of [`RoadFrame::to_road`]: road point (m) → file point (m), by Newton's
    /// method on the forward map (converged to 1e-10 m or 30 iterations). Outside
    /// [`RoadFrame::road_range`] the result is meaningless (possibly non-finite); use
    /// [`RoadFrame::try_to_file`] where the point may lie outside.
    #[must_use]
    pub fn to_file(&self, r: [f64; 2]) -> [f64; 2] {
        if let Some(path) = &self.path {
            return path.to_file(r).unwrap_or([f64::NAN; 2]);
        }
        let q = self.road_to_rotated(r);
        rotate(q, -self.theta)
    }

    /// The road x range (m) the frame is defined over: the arc length at the ends of its table.
    #[must_use]
    pub fn road_range(&self) -> (f64, f64) {
        if let Some(path) = &self.path {
            return path.s_range();
        }
        (self.grid_arc[0], self.grid_arc[ARC_GRID - 1])
    }

    /// [`RoadFrame::to_file`] where it is defined: `None` for a non-finite road point, one
    /// whose x lies outside [`RoadFrame::road_range`], or one the Newton iteration does not
    /// bring back to within 1 µm under the forward map.
    #[must_use]
    pub fn try_to_file(&self, r: [f64; 2]) -> Option<[f64; 2]> {
        if let Some(path) = &self.path {
            return path.to_file(r);
        }
        let (lo, hi) = self.road_range();
        if !(r[0].is_finite() && r[1].is_finite() && (lo..=hi).contains(&r[0])) {
            return None;
        }
        let q = self.road_to_rotated(r);
        let back = self.rotated_to_road(q);
        let err = (back[0] - r[0]).abs().max((back[1] - r[1]).abs());
        (err < 1e-6).then(|| rotate(q, -self.theta))
    }

    fn road_to_rotated(&self, r: [f64; 2]) -> [f64; 2] {
        let xf = interp(r[0], &self.grid_arc, &self.grid_x);
        let (s, c) = self.tangent_angle(xf).sin_cos();
        let mut q = [xf - r[1] * s, polyval(&self.coef, xf) + r[1] * c];
        let h = 1e-6;
        for _ in 0..30 {
            let f = self.rotated_to_road(q);
            let e = [f[0] - r[0], f[1] - r[1]];
            if e[0].abs().max(e[1].abs()) < 1e-10 {
                break;
            }
            let fx = self.rotated_to_road([q[0] + h, q[1]]);
            let fy = self.rotated_to_road([q[0], q[1] + h]);
            let j = [
                [(fx[0] - f[0]) / h, (fy[0] - f[0]) / h],
                [(fx[1] - f[1]) / h, (fy[1] - f[1]) / h],
            ];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            q[0] -= (j[1][1] * e[0] - j[0][1] * e[1]) / det;
            q[1] -= (-j[1][0] * e[0] + j[0][0] * e[1]) / det;
        }
        q
    }

    /// A road-relative heading (rad) at road point `r` → orientation in the file's frame, in
    /// [−π, π) (the inverse of [`RoadFrame::heading_to_road`]).
    #[must_use]
    pub fn heading_to_file(&self, r: [f64; 2], heading: f64) -> f64 {
        if let Some(path) = &self.path {
            return wrap_angle(heading + path.tangent_angle(path.u_of_s(r[0])));
        }
        let q = self.road_to_rotated(r);
        wrap_angle(heading + self.theta + self.tangent_angle(q[0]))
    }
}
