//! The ellipse safety constraint b_i and bounding-box collision tests.

/// Ellipse semi-axes around one other vehicle: a_x = s·(L_ego + L_i)/2 + m_x,
/// a_y = s·(W_ego + W_i)/2 + m_y (metres). With s = √2 the ellipse circumscribes the
/// rectangle of centre offsets at which aligned bounding boxes overlap, so b > 0 excludes
/// overlap; s = 1 is the inscribed ellipse (corners uncovered).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipse {
    /// Longitudinal semi-axis (m).
    pub a_x: f64,
    /// Lateral semi-axis (m).
    pub a_y: f64,
}

impl Ellipse {
    /// The ellipse for an ego of size `ego` = (length, width) and another vehicle of size
    /// `other`, with scale `scale` (s above) and margins `m_x`, `m_y` (metres).
    #[must_use]
    pub fn new(ego: [f64; 2], other: [f64; 2], scale: f64, m_x: f64, m_y: f64) -> Self {
        Self {
            a_x: scale * 0.5 * (ego[0] + other[0]) + m_x,
            a_y: scale * 0.5 * (ego[1] + other[1]) + m_y,
        }
    }

    /// b = ((x − x̂)/a_x)² + ((y − ŷ)/a_y)² − 1 for an ego at `ego` and the other vehicle
    /// predicted at `other` (metres); > 0 means safe.
    #[must_use]
    pub fn value(&self, ego: [f64; 2], other: [f64; 2]) -> f64 {
        let dx = (ego[0] - other[0]) / self.a_x;
        let dy = (ego[1] - other[1]) / self.a_y;
        dx * dx + dy * dy - 1.0
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
}
