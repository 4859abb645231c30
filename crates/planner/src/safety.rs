//! The safety constraint b_i (the ellipse, or the separation of the oriented boxes) and
//! bounding-box collision tests.

/// Largest heading (rad) read from a vehicle's motion; steeper motion is clamped to it.
pub const MAX_MOTION_HEADING: f64 = 0.5;
/// Smallest forward displacement (m) from which a heading is read off a vehicle's motion;
/// below it the fallback heading is used.
pub const MIN_MOTION_DX: f64 = 0.3;

/// The part of the segment `a` + t·(`b` − `a`), t ∈ [0, 1], inside the axis-aligned box
/// [`lo`, `hi`] (closed), as its parameter interval (t0, t1) (Liang–Barsky); `None` when no
/// point of the segment is inside.
#[must_use]
pub fn clip_segment_to_box(
    a: [f64; 2],
    b: [f64; 2],
    lo: [f64; 2],
    hi: [f64; 2],
) -> Option<(f64, f64)> {
    let d = [b[0] - a[0], b[1] - a[1]];
    let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
    for axis in 0..2 {
        // lo ≤ a + t·d ≤ hi along this axis: p·t ≤ q for both sides.
        for (p, q) in [
            (-d[axis], a[axis] - lo[axis]),
            (d[axis], hi[axis] - a[axis]),
        ] {
            if p == 0.0 {
                if q < 0.0 {
                    return None;
                }
            } else if p < 0.0 {
                t0 = t0.max(q / p);
            } else {
                t1 = t1.min(q / p);
            }
        }
    }
    (t0 <= t1).then_some((t0, t1))
}

/// Heading (rad) of the motion from `from` to `to` (positions in metres), clamped to
/// ±[`MAX_MOTION_HEADING`]; `fallback` when the forward displacement is at most
/// [`MIN_MOTION_DX`] (stopped, or moving backwards through noise).
#[must_use]
pub fn motion_heading(from: [f64; 2], to: [f64; 2], fallback: f64) -> f64 {
    let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
    if dx > MIN_MOTION_DX {
        dy.atan2(dx).clamp(-MAX_MOTION_HEADING, MAX_MOTION_HEADING)
    } else {
        fallback
    }
}

/// (|cos ψ|, |sin ψ|) of [`motion_heading`] without trigonometry (the planner evaluates it
/// for every checked vehicle at every step of every trial point).
#[must_use]
pub fn motion_direction(from: [f64; 2], to: [f64; 2], fallback: [f64; 2]) -> [f64; 2] {
    let dx = to[0] - from[0];
    if dx > MIN_MOTION_DX {
        let dy = (to[1] - from[1]).abs().min(dx * MAX_MOTION_HEADING.tan());
        let d = dx.hypot(dy);
        [dx / d, dy / d]
    } else {
        fallback
    }
}

/// (cos ψ, sin ψ) of [`motion_heading`] (signed, unlike [`motion_direction`]) without
/// trigonometry; `fallback` (a unit vector) when the forward displacement is at most
/// [`MIN_MOTION_DX`].
#[must_use]
pub fn motion_axis(from: [f64; 2], to: [f64; 2], fallback: [f64; 2]) -> [f64; 2] {
    let dx = to[0] - from[0];
    if dx > MIN_MOTION_DX {
        let lim = dx * MAX_MOTION_HEADING.tan();
        let dy = (to[1] - from[1]).clamp(-lim, lim);
        let d = dx.hypot(dy);
        [dx / d, dy / d]
    } else {
        fallback
    }
}

/// Separating-axis distance (m) between the ego's box `ego` and another box `other`, less a
/// clearance, with its gradient with respect to the ego's centre (x, y) (the headings held
/// fixed): the largest over the four box axes n (each box's long and short axis) of
/// |d·n| − h_ego(n) − h_other(n) − c(n), where d is the offset of the centres, h(n) a box's
/// half extent on n and c(n) = m_x·|n_x| + m_y·|n_y| the clearance `margin` = (m_x along the
/// road, m_y across it) projected on n. With zero margins it is > 0 exactly when the boxes do
/// not overlap (the separating-axis theorem, as [`OrientedBox::overlaps`]); margins only make
/// it stricter. Piecewise linear in the ego's position: the gradient is that of the largest
/// term (the first on ties), ±n.
#[must_use]
pub fn box_separation(ego: &OrientedBox, other: &OrientedBox, margin: [f64; 2]) -> (f64, [f64; 2]) {
    let d = [ego.x - other.x, ego.y - other.y];
    let [a0, a1] = ego.axes();
    let [b0, b1] = other.axes();
    let mut best = (f64::NEG_INFINITY, [0.0; 2]);
    for n in [a0, a1, b0, b1] {
        let proj = d[0] * n[0] + d[1] * n[1];
        let clearance = margin[0] * n[0].abs() + margin[1] * n[1].abs();
        let gap = proj.abs() - ego.half_extent_on(n) - other.half_extent_on(n) - clearance;
        // NaN never wins a comparison, so a NaN offset leaves −∞ (never safe).
        if gap > best.0 || gap.is_nan() {
            let sign = if proj < 0.0 { -1.0 } else { 1.0 };
            best = (gap, [sign * n[0], sign * n[1]]);
            if gap.is_nan() {
                return (f64::NAN, [0.0; 2]);
            }
        }
    }
    best
}

/// Half extents (along x, along y) in metres of the axis-aligned box that bounds a vehicle of
/// `size` = (length, width) (m) whose heading ψ has `dir` = (|cos ψ|, |sin ψ|).
#[must_use]
pub fn bounding_half_extents(size: [f64; 2], dir: [f64; 2]) -> [f64; 2] {
    [
        0.5 * (size[0] * dir[0] + size[1] * dir[1]),
        0.5 * (size[0] * dir[1] + size[1] * dir[0]),
    ]
}

/// Ellipse semi-axes around one other vehicle: a_x = s·(e_x,ego + e_x,i) + m_x,
/// a_y = s·(e_y,ego + e_y,i) + m_y (metres), where (e_x, e_y) are the half extents of the
/// axis-aligned box bounding each vehicle at its heading ([`bounding_half_extents`]; at
/// heading 0 they are the half length and half width). With s = √2 the ellipse circumscribes
/// the rectangle of centre offsets at which those bounding boxes overlap, so b > 0 excludes
/// overlap of the real (rotated) vehicles; s = 1 is the inscribed ellipse (corners
/// uncovered). Headings matter: a 14.6 m truck turned by 0.1 rad sweeps 0.73 m further
/// sideways than its width.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipse {
    /// Longitudinal semi-axis (m).
    pub a_x: f64,
    /// Lateral semi-axis (m).
    pub a_y: f64,
}

impl Ellipse {
    /// The ellipse for an ego of size `ego` = (length, width) and another vehicle of size
    /// `other`, both aligned with the road (heading 0), with scale `scale` (s above) and
    /// margins `m_x`, `m_y` (metres).
    #[must_use]
    pub fn new(ego: [f64; 2], other: [f64; 2], scale: f64, m_x: f64, m_y: f64) -> Self {
        Self::oriented(ego, [1.0, 0.0], other, [1.0, 0.0], scale, m_x, m_y)
    }

    /// The ellipse for an ego of size `ego` = (length, width) (m) with heading direction
    /// `ego_dir` = (|cos ψ|, |sin ψ|) and another vehicle of size `other` with heading
    /// direction `other_dir`, scale `scale` and margins `m_x`, `m_y` (metres).
    #[must_use]
    pub fn oriented(
        ego: [f64; 2],
        ego_dir: [f64; 2],
        other: [f64; 2],
        other_dir: [f64; 2],
        scale: f64,
        m_x: f64,
        m_y: f64,
    ) -> Self {
        let e = bounding_half_extents(ego, ego_dir);
        let o = bounding_half_extents(other, other_dir);
        Self {
            a_x: scale * (e[0] + o[0]) + m_x,
            a_y: scale * (e[1] + o[1]) + m_y,
        }
    }

    /// [`Ellipse::oriented`] with headings in radians.
    #[must_use]
    pub fn with_headings(
        ego: [f64; 2],
        ego_heading: f64,
        other: [f64; 2],
        other_heading: f64,
        scale: f64,
        m_x: f64,
        m_y: f64,
    ) -> Self {
        let dir = |h: f64| [h.cos().abs(), h.sin().abs()];
        Self::oriented(
            ego,
            dir(ego_heading),
            other,
            dir(other_heading),
            scale,
            m_x,
            m_y,
        )
    }

    /// b = ((x − x̂)/a_x)² + ((y − ŷ)/a_y)² − 1 for an ego at `ego` and the other vehicle
    /// predicted at `other` (metres); > 0 means safe.
    #[must_use]
    pub fn value(&self, ego: [f64; 2], other: [f64; 2]) -> f64 {
        let dx = (ego[0] - other[0]) / self.a_x;
        let dy = (ego[1] - other[1]) / self.a_y;
        dx * dx + dy * dy - 1.0
    }

    /// b and ∂b/∂(x, y) of an ego cut into `slices` equal slices along its long axis
    /// `axis` = (cos ψ, sin ψ) (a unit vector), `self` being the ellipse of **one** slice (an
    /// ego of size (length / `slices`, width), [`Ellipse::oriented`]): the smallest over the
    /// slices j of [`Ellipse::value`] at the slice's centre `ego` + c_j·`axis`,
    /// c_j = −length/2 + (j + ½)·length/`slices` (m), with that slice's gradient (the centres
    /// move with `ego`, the heading held fixed); the first slice on ties, NaN when any value is.
    /// The ego's box is the union of the slices' boxes, so with scale √2 and non-negative
    /// margins b > 0 still excludes overlap, and one slice is [`Ellipse::value`] itself.
    #[must_use]
    pub fn sliced(
        &self,
        ego: [f64; 2],
        axis: [f64; 2],
        length: f64,
        slices: usize,
        other: [f64; 2],
    ) -> (f64, [f64; 2]) {
        let k = slices.max(1);
        let piece = length / k as f64;
        let mut best = (f64::INFINITY, [0.0; 2]);
        for j in 0..k {
            let c = -0.5 * length + (j as f64 + 0.5) * piece;
            let p = [ego[0] + c * axis[0], ego[1] + c * axis[1]];
            let b = self.value(p, other);
            if b.is_nan() {
                return (f64::NAN, [0.0; 2]);
            }
            if b < best.0 {
                best = (b, self.gradient(p, other));
            }
        }
        best
    }

    /// ∂b/∂(x, y) of the ego position, the prediction held fixed.
    #[must_use]
    pub fn gradient(&self, ego: [f64; 2], other: [f64; 2]) -> [f64; 2] {
        [
            2.0 * (ego[0] - other[0]) / (self.a_x * self.a_x),
            2.0 * (ego[1] - other[1]) / (self.a_y * self.a_y),
        ]
    }
}

/// An oriented rectangle: centre (m), heading (rad), length and width (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrientedBox {
    /// Centre x (m).
    pub x: f64,
    /// Centre y (m).
    pub y: f64,
    /// Heading of the long axis (rad, 0 = +x).
    pub heading: f64,
    /// Length along the heading (m).
    pub length: f64,
    /// Width across the heading (m).
    pub width: f64,
}

impl OrientedBox {
    /// A box of `size` = (length, width) (m) centred at `centre` (m) whose long axis has the
    /// direction `axis` = (cos ψ, sin ψ) (a unit vector).
    #[must_use]
    pub fn along(centre: [f64; 2], axis: [f64; 2], size: [f64; 2]) -> Self {
        Self {
            x: centre[0],
            y: centre[1],
            heading: axis[1].atan2(axis[0]),
            length: size[0],
            width: size[1],
        }
    }

    fn axes(&self) -> [[f64; 2]; 2] {
        let (s, c) = self.heading.sin_cos();
        [[c, s], [-s, c]]
    }

    fn half_extent_on(&self, axis: [f64; 2]) -> f64 {
        let [u, v] = self.axes();
        0.5 * self.length * (u[0] * axis[0] + u[1] * axis[1]).abs()
            + 0.5 * self.width * (v[0] * axis[0] + v[1] * axis[1]).abs()
    }

    /// True when the two rectangles overlap (separating-axis test; touching is not overlap).
    #[must_use]
    pub fn overlaps(&self, other: &OrientedBox) -> bool {
        let d = [other.x - self.x, other.y - self.y];
        let [a0, a1] = self.axes();
        let [b0, b1] = other.axes();
        for axis in [a0, a1, b0, b1] {
            let dist = (d[0] * axis[0] + d[1] * axis[1]).abs();
            if dist >= self.half_extent_on(axis) + other.half_extent_on(axis) {
                return false;
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ellipse_sign_and_gradient() {
        let e = Ellipse::new([4.5, 1.8], [4.5, 1.8], 1.0, 2.5, 0.4);
        assert!((e.a_x - 7.0).abs() < 1e-12 && (e.a_y - 2.2).abs() < 1e-12);
        assert!(e.value([0.0, 0.0], [0.0, 0.0]) < 0.0);
        assert!(e.value([0.0, 3.7], [0.0, 0.0]) > 0.0);
        assert!(e.value([7.5, 0.0], [0.0, 0.0]) > 0.0);
        // With scale √2 and no margin, the corner of the overlap rectangle lies on the ellipse.
        let c = Ellipse::new([4.5, 1.8], [4.5, 1.8], std::f64::consts::SQRT_2, 0.0, 0.0);
        assert!(c.value([4.5, 1.8], [0.0, 0.0]).abs() < 1e-12);
        let p = [3.0, 1.0];
        let g = e.gradient(p, [0.5, -0.2]);
        let h = 1e-6;
        let fx = (e.value([p[0] + h, p[1]], [0.5, -0.2]) - e.value([p[0] - h, p[1]], [0.5, -0.2]))
            / (2.0 * h);
        assert!((fx - g[0]).abs() < 1e-6);
    }

    #[test]
    fn box_overlap() {
        let a = OrientedBox {
            x: 0.0,
            y: 0.0,
            heading: 0.0,
            length: 4.0,
            width: 2.0,
        };
        let mut b = a;
        b.x = 3.9;
        assert!(a.overlaps(&b));
        b.x = 4.1;
        assert!(!a.overlaps(&b));
        b.x = 0.0;
        b.y = 2.1;
        assert!(!a.overlaps(&b));
        // Rotated 90°: its half length now extends along y.
        b.heading = std::f64::consts::FRAC_PI_2;
        b.y = 2.9;
        assert!(a.overlaps(&b));
        b.y = 3.1;
        assert!(!a.overlaps(&b));
    }

    #[test]
    fn a_turned_truck_needs_the_oriented_ellipse() {
        // The failure this guards against: a 14.6 m truck at heading −0.109 rad whose rear
        // swings 0.8 m sideways into a car beside it while the road-aligned ellipse of the
        // centres says b > 0.
        let (truck, car) = ([14.6304, 2.5908], [3.6576, 1.524]);
        let ego = OrientedBox {
            x: 241.385,
            y: 1.340,
            heading: -0.1086,
            length: truck[0],
            width: truck[1],
        };
        let other = OrientedBox {
            x: 232.598,
            y: 3.973,
            heading: -0.0002,
            length: car[0],
            width: car[1],
        };
        assert!(ego.overlaps(&other));
        let s2 = std::f64::consts::SQRT_2;
        let aligned = Ellipse::new(truck, car, s2, 1.5, 0.3);
        assert!(aligned.value([ego.x, ego.y], [other.x, other.y]) > 0.0);
        let turned = Ellipse::with_headings(truck, ego.heading, car, other.heading, s2, 1.5, 0.3);
        assert!(turned.value([ego.x, ego.y], [other.x, other.y]) < 0.0);
        // The trigonometry-free direction agrees with the heading.
        let d = motion_direction([0.0, 0.0], [4.0, -0.3], [1.0, 0.0]);
        let h = motion_heading([0.0, 0.0], [4.0, -0.3], 0.0);
        assert!((d[0] - h.cos().abs()).abs() < 1e-12 && (d[1] - h.sin().abs()).abs() < 1e-12);
        // Clamped the same way.
        let d = motion_direction([0.0, 0.0], [1.0, 3.0], [1.0, 0.0]);
        let h = motion_heading([0.0, 0.0], [1.0, 3.0], 0.0);
        assert!((h - MAX_MOTION_HEADING).abs() < 1e-12);
        assert!((d[0] - h.cos()).abs() < 1e-12 && (d[1] - h.sin()).abs() < 1e-12);
        // Too little forward motion: the fallback.
        assert_eq!(
            motion_direction([0.0, 0.0], [0.1, 0.5], [0.6, 0.8]),
            [0.6, 0.8]
        );
        assert_eq!(motion_heading([0.0, 0.0], [0.1, 0.5], 0.25), 0.25);
    }

    /// The four separating-axis terms of [`box_separation`] recomputed from the corners:
    /// on each axis n, the gap between the two boxes' corner projections less the clearance.
    fn terms(a: &OrientedBox, b: &OrientedBox, margin: [f64; 2]) -> Vec<f64> {
        let corners = |o: &OrientedBox| {
            let (sn, cs) = o.heading.sin_cos();
            let (l, w) = (0.5 * o.length, 0.5 * o.width);
            [(l, w), (l, -w), (-l, w), (-l, -w)]
                .map(|(u, v)| [o.x + u * cs - v * sn, o.y + u * sn + v * cs])
        };
        let (ca, cb) = (corners(a), corners(b));
        [a.heading, b.heading]
            .iter()
            .flat_map(|h| {
                let (sn, cs) = h.sin_cos();
                [[cs, sn], [-sn, cs]]
            })
            .map(|n| {
                let proj = |c: &[[f64; 2]; 4]| {
                    let p = c.map(|p| p[0] * n[0] + p[1] * n[1]);
                    (
                        p.iter().copied().fold(f64::INFINITY, f64::min),
                        p.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                    )
                };
                let ((a0, a1), (b0, b1)) = (proj(&ca), proj(&cb));
                (b0 - a1).max(a0 - b1) - margin[0] * n[0].abs() - margin[1] * n[1].abs()
            })
            .collect()
    }

    #[test]
    fn box_separation_of_aligned_boxes() {
        let a = OrientedBox::along([0.0, 0.0], [1.0, 0.0], [4.5, 1.8]);
        let b = OrientedBox::along([10.0, 3.0], [1.0, 0.0], [5.5, 2.0]);
        // max(|dx| − 5 − m_x, |dy| − 1.9 − m_y) for road-aligned boxes.
        let (sep, g) = box_separation(&a, &b, [1.5, 0.3]);
        assert!((sep - (10.0 - 5.0 - 1.5)).abs() < 1e-12, "{sep}");
        assert_eq!(g, [-1.0, 0.0], "moving the ego back opens the gap");
        let b = OrientedBox::along([1.0, 2.5], [1.0, 0.0], [5.5, 2.0]);
        let (sep, g) = box_separation(&a, &b, [1.5, 0.3]);
        assert!((sep - (2.5 - 1.9 - 0.3)).abs() < 1e-12, "{sep}");
        assert!(g[0].abs() < 1e-12 && (g[1] + 1.0).abs() < 1e-12);
        // A NaN position is never safe.
        let nan = OrientedBox::along([f64::NAN, 0.0], [1.0, 0.0], [4.5, 1.8]);
        assert!(box_separation(&nan, &b, [0.0, 0.0]).0.is_nan());
        // The signed motion axis keeps the side the heading ψ = atan2 gives.
        let ax = motion_axis([0.0, 0.0], [4.0, -0.3], [1.0, 0.0]);
        let h = motion_heading([0.0, 0.0], [4.0, -0.3], 0.0);
        assert!((ax[0] - h.cos()).abs() < 1e-12 && (ax[1] - h.sin()).abs() < 1e-12);
        let ax = motion_axis([0.0, 0.0], [1.0, -3.0], [1.0, 0.0]);
        assert!(
            (ax[1].atan2(ax[0]) + MAX_MOTION_HEADING).abs() < 1e-12,
            "clamped"
        );
        assert_eq!(
            motion_axis([0.0, 0.0], [0.1, 0.5], [0.6, -0.8]),
            [0.6, -0.8]
        );
    }

    /// The slice ellipse of an ego `size` cut into `k` slices at heading `h0` against a
    /// vehicle `other` at heading `h1` (scale √2).
    fn slice_ellipse(
        size: [f64; 2],
        k: usize,
        h0: f64,
        other: [f64; 2],
        h1: f64,
        m: [f64; 2],
    ) -> Ellipse {
        let piece = [size[0] / k as f64, size[1]];
        Ellipse::with_headings(piece, h0, other, h1, std::f64::consts::SQRT_2, m[0], m[1])
    }

    /// The failure the slices fix: a 19.8 m truck 4 m behind a car's bumper in the same lane
    /// (centres 16.15 m apart) is inside the whole-truck ellipse (a_x ≈ 18.7 m), although the
    /// boxes are 4 m apart; four slices see it outside, and one slice is the plain ellipse.
    #[test]
    fn a_sliced_long_ego_reaches_no_further_than_needed() {
        let (truck, car, m) = ([19.8, 2.6], [4.5, 1.8], [1.5, 0.3]);
        let other = [16.15, 0.0];
        let whole = slice_ellipse(truck, 1, 0.0, car, 0.0, m);
        assert!(whole.value([0.0, 0.0], other) < 0.0);
        let (b1, g1) = whole.sliced([0.0, 0.0], [1.0, 0.0], truck[0], 1, other);
        assert_eq!(
            (b1, g1),
            (
                whole.value([0.0, 0.0], other),
                whole.gradient([0.0, 0.0], other)
            )
        );
        let four = slice_ellipse(truck, 4, 0.0, car, 0.0, m);
        let (b4, g4) = four.sliced([0.0, 0.0], [1.0, 0.0], truck[0], 4, other);
        assert!(b4 > 0.0, "{b4}");
        // The front slice binds (centre 7.425 m ahead of the truck's): its gradient.
        let front = four.gradient([7.425, 0.0], other);
        assert!((g4[0] - front[0]).abs() < 1e-12 && (g4[1] - front[1]).abs() < 1e-12);
        let ego = OrientedBox::along([0.0, 0.0], [1.0, 0.0], truck);
        let ahead = OrientedBox::along(other, [1.0, 0.0], car);
        assert!(!ego.overlaps(&ahead));
        // A NaN position is never safe.
        assert!(
            four.sliced([f64::NAN, 0.0], [1.0, 0.0], truck[0], 4, other)
                .0
                .is_nan()
        );
    }

    proptest::proptest! {
        /// A sliced ego (k slices of a box up to 25 m long, any heading within ±0.6 rad) with
        /// s = √2 and non-negative margins: b > 0 excludes overlap of the rotated boxes
        /// (independent truth: the separating-axis test, [`OrientedBox::overlaps`]).
        #[test]
        fn positive_sliced_b_excludes_overlap(
            l0 in 2.0f64..25.0, w0 in 1.0f64..3.0, h0 in -0.6f64..0.6, k in 1usize..6,
            l1 in 2.0f64..20.0, w1 in 1.0f64..3.0, h1 in -0.6f64..0.6,
            dx in -30.0f64..30.0, dy in -6.0f64..6.0,
            mx in 0.0f64..3.0, my in 0.0f64..1.0,
        ) {
            let e = slice_ellipse([l0, w0], k, h0, [l1, w1], h1, [mx, my]);
            let (b, _) = e.sliced([0.0, 0.0], [h0.cos(), h0.sin()], l0, k, [dx, dy]);
            let a = OrientedBox { x: 0.0, y: 0.0, heading: h0, length: l0, width: w0 };
            let o = OrientedBox { x: dx, y: dy, heading: h1, length: l1, width: w1 };
            if b > 0.0 {
                proptest::prop_assert!(!a.overlaps(&o));
            }
        }

        /// The sliced gradient against central finite differences of the ego's centre, away
        /// from the kinks (two slices within 1e-3 of each other).
        #[test]
        fn sliced_gradient_matches_finite_differences(
            l0 in 2.0f64..25.0, w0 in 1.0f64..3.0, h0 in -0.6f64..0.6, k in 1usize..6,
            dx in -30.0f64..30.0, dy in -6.0f64..6.0,
        ) {
            let e = slice_ellipse([l0, w0], k, h0, [4.5, 1.8], 0.0, [1.5, 0.3]);
            let axis = [h0.cos(), h0.sin()];
            let other = [dx, dy];
            let mut v: Vec<f64> = (0..k)
                .map(|j| {
                    let c = -0.5 * l0 + (j as f64 + 0.5) * l0 / k as f64;
                    e.value([c * axis[0], c * axis[1]], other)
                })
                .collect();
            v.sort_by(f64::total_cmp);
            proptest::prop_assume!(k == 1 || v[1] - v[0] > 1e-3);
            let f = |x: f64, y: f64| e.sliced([x, y], axis, l0, k, other).0;
            let (_, g) = e.sliced([0.0, 0.0], axis, l0, k, other);
            let h = 1e-6;
            let fx = (f(h, 0.0) - f(-h, 0.0)) / (2.0 * h);
            let fy = (f(0.0, h) - f(0.0, -h)) / (2.0 * h);
            proptest::prop_assert!((fx - g[0]).abs() < 1e-5 && (fy - g[1]).abs() < 1e-5,
                "fd ({}, {}) vs {:?}", fx, fy, g);
        }

        /// With s = √2 and non-negative margins, b > 0 excludes overlap of the rotated boxes
        /// (independent truth: the separating-axis test).
        #[test]
        fn positive_b_excludes_overlap(
            l0 in 2.0f64..20.0, w0 in 1.0f64..3.0, h0 in -0.6f64..0.6,
            l1 in 2.0f64..20.0, w1 in 1.0f64..3.0, h1 in -0.6f64..0.6,
            dx in -25.0f64..25.0, dy in -6.0f64..6.0,
            mx in 0.0f64..3.0, my in 0.0f64..1.0,
        ) {
            let e = Ellipse::with_headings(
                [l0, w0], h0, [l1, w1], h1, std::f64::consts::SQRT_2, mx, my,
            );
            let a = OrientedBox { x: 0.0, y: 0.0, heading: h0, length: l0, width: w0 };
            let b = OrientedBox { x: dx, y: dy, heading: h1, length: l1, width: w1 };
            if e.value([0.0, 0.0], [dx, dy]) > 0.0 {
                proptest::prop_assert!(!a.overlaps(&b));
            }
        }
        /// With s = √2 and non-negative margins, b > 0 of the ego cut into k slices excludes
        /// overlap of the rotated boxes (independent truth: the separating-axis test).
        #[test]
        fn positive_b_of_the_sliced_ego_excludes_overlap(
            l0 in 2.0f64..20.0, w0 in 1.0f64..3.0, h0 in -0.6f64..0.6,
            l1 in 2.0f64..20.0, w1 in 1.0f64..3.0, h1 in -0.6f64..0.6,
            dx in -25.0f64..25.0, dy in -6.0f64..6.0,
            mx in 0.0f64..3.0, my in 0.0f64..1.0,
            k in 1usize..5,
        ) {
            let dir = |h: f64| [h.cos().abs(), h.sin().abs()];
            let e = Ellipse::oriented(
                [l0 / k as f64, w0], dir(h0), [l1, w1], dir(h1), std::f64::consts::SQRT_2, mx, my,
            );
            let a = OrientedBox { x: 0.0, y: 0.0, heading: h0, length: l0, width: w0 };
            let b = OrientedBox { x: dx, y: dy, heading: h1, length: l1, width: w1 };
            let (v, _) = e.sliced([0.0, 0.0], [h0.cos(), h0.sin()], l0, k, [dx, dy]);
            if v > 0.0 {
                proptest::prop_assert!(!a.overlaps(&b));
            }
        }

            /// With zero margins the separation is > 0 exactly when the rotated boxes do not
        /// overlap (independent truth: [`OrientedBox::overlaps`]); it equals the largest of the
        /// axis terms recomputed from the corners; margins only lower it.
        #[test]
        fn box_separation_is_the_separating_axis_test(
            l0 in 2.0f64..20.0, w0 in 1.0f64..3.0, h0 in -0.6f64..0.6,
            l1 in 2.0f64..20.0, w1 in 1.0f64..3.0, h1 in -0.6f64..0.6,
            dx in -25.0f64..25.0, dy in -6.0f64..6.0,
            mx in 0.0f64..3.0, my in 0.0f64..1.0,
        ) {
            let a = OrientedBox { x: 0.0, y: 0.0, heading: h0, length: l0, width: w0 };
            let b = OrientedBox { x: dx, y: dy, heading: h1, length: l1, width: w1 };
            let (sep, _) = box_separation(&a, &b, [0.0, 0.0]);
            if sep.abs() > 1e-9 {
                proptest::prop_assert_eq!(sep > 0.0, !a.overlaps(&b));
            }
            let best = terms(&a, &b, [mx, my]).into_iter().fold(f64::NEG_INFINITY, f64::max);
            let (with_margin, _) = box_separation(&a, &b, [mx, my]);
            proptest::prop_assert!((with_margin - best).abs() < 1e-9, "{} vs {}", with_margin, best);
            proptest::prop_assert!(with_margin <= sep + 1e-12);
        }

        /// The gradient with respect to the ego's centre against central finite differences,
        /// away from the kinks (where two axis terms tie).
        #[test]
        fn box_separation_gradient_matches_finite_differences(
            l0 in 2.0f64..20.0, w0 in 1.0f64..3.0, h0 in -0.6f64..0.6,
            l1 in 2.0f64..20.0, w1 in 1.0f64..3.0, h1 in -0.6f64..0.6,
            dx in -25.0f64..25.0, dy in -6.0f64..6.0,
            mx in 0.0f64..3.0, my in 0.0f64..1.0,
        ) {
            let b = OrientedBox { x: dx, y: dy, heading: h1, length: l1, width: w1 };
            let at = |x: f64, y: f64| OrientedBox { x, y, heading: h0, length: l0, width: w0 };
            let mut t = terms(&at(0.0, 0.0), &b, [mx, my]);
            t.sort_by(f64::total_cmp);
            proptest::prop_assume!(t[3] - t[2] > 1e-3);
            let (_, g) = box_separation(&at(0.0, 0.0), &b, [mx, my]);
            let h = 1e-6;
            let f = |x: f64, y: f64| box_separation(&at(x, y), &b, [mx, my]).0;
            let fx = (f(h, 0.0) - f(-h, 0.0)) / (2.0 * h);
            let fy = (f(0.0, h) - f(0.0, -h)) / (2.0 * h);
            proptest::prop_assert!((fx - g[0]).abs() < 1e-6 && (fy - g[1]).abs() < 1e-6,
                "fd ({}, {}) vs {:?}", fx, fy, g);
        }
    }
}
