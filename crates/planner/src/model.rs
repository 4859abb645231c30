//! The kinematic bicycle (centre of gravity), its exact Jacobians, and the stacked linearised
//! dynamics F = AΔ + Bα + CZ + D over the horizon.
//!
//! State z = (x, y, ψ, v): position of the centre of gravity (m, road frame), heading (rad,
//! 0 = +x, positive to the left), speed (m/s). Inputs: steering δ (rad), acceleration a (m/s²).

use nalgebra::{SMatrix, SVector};

/// A state (x, y, ψ, v): position of the centre of gravity (m, m), heading (rad), speed (m/s).
pub type State = SVector<f64, 4>;
/// A `[4, 4]` state Jacobian ∂f/∂z.
pub type Jac4 = SMatrix<f64, 4, 4>;

/// Kinematic bicycle parameters and step length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bicycle {
    /// Centre of gravity to front axle (m).
    pub l_f: f64,
    /// Centre of gravity to rear axle (m).
    pub l_r: f64,
    /// Step length (s).
    pub dt: f64,
}

impl Bicycle {
    /// Slip angle β(δ) = atan(l_r/(l_f+l_r) · tan δ) (rad).
    #[must_use]
    pub fn slip(&self, delta: f64) -> f64 {
        (self.l_r / (self.l_f + self.l_r) * delta.tan()).atan()
    }

    /// dβ/dδ (dimensionless).
    #[must_use]
    pub fn slip_derivative(&self, delta: f64) -> f64 {
        let k = self.l_r / (self.l_f + self.l_r);
        let t = delta.tan();
        let sec2 = 1.0 + t * t;
        k * sec2 / (1.0 + k * k * t * t)
    }

    /// One exact (nonlinear) step z⁺ = f(z, δ, a) of `dt` seconds, steering δ (rad),
    /// acceleration a (m/s²); the speed may go negative (the linearisation needs the smooth
    /// model; see [`Bicycle::advance`] for the vehicle).
    #[must_use]
    pub fn step(&self, z: &State, delta: f64, accel: f64) -> State {
        let beta = self.slip(delta);
        let (x, y, psi, v) = (z[0], z[1], z[2], z[3]);
        let dt = self.dt;
        State::new(
            x + dt * v * (psi + beta).cos(),
            y + dt * v * (psi + beta).sin(),
            psi + dt * v * beta.sin() / self.l_r,
            v + dt * accel,
        )
    }

    /// Exact Jacobians at (z, δ): returns (∂f/∂z `[4, 4]`, ∂f/∂δ `[4]`, ∂f/∂a `[4]`).
    #[must_use]
    pub fn jacobians(&self, z: &State, delta: f64) -> (Jac4, State, State) {
        let beta = self.slip(delta);
        let db = self.slip_derivative(delta);
        let (psi, v) = (z[2], z[3]);
        let dt = self.dt;
        let (s, c) = (psi + beta).sin_cos();
        let mut jz = Jac4::identity();
        jz[(0, 2)] = -dt * v * s;
        jz[(0, 3)] = dt * c;
        jz[(1, 2)] = dt * v * c;
        jz[(1, 3)] = dt * s;
        jz[(2, 3)] = dt * beta.sin() / self.l_r;
        let jd = State::new(
            -dt * v * s * db,
            dt * v * c * db,
            dt * v * beta.cos() * db / self.l_r,
            0.0,
        );
        let ja = State::new(0.0, 0.0, 0.0, dt);
        (jz, jd, ja)
    }

    /// One step of the vehicle as it drives: [`Bicycle::step`], then the speed clamped at 0
    /// (the vehicle brakes to a stop, it does not reverse). The planner's roll-outs, its
    /// fallbacks and the closed-loop simulator all move the ego with this; the linearisation
    /// uses the unclamped [`Bicycle::step`].
    #[must_use]
    pub fn advance(&self, z: &State, delta: f64, accel: f64) -> State {
        let mut next = self.step(z, delta, accel);
        next[3] = next[3].max(0.0);
        next
    }

    /// Rolls the vehicle out from `z0` under `delta`, `accel` (length T each, rad and m/s²)
    /// with [`Bicycle::advance`] into `out` (T states z_1..z_T).
    pub fn rollout(&self, z0: &State, delta: &[f64], accel: &[f64], out: &mut [State]) {
        let mut z = *z0;
        for ((d, a), o) in delta.iter().zip(accel).zip(out.iter_mut()) {
            z = self.advance(&z, *d, *a);
            *o = z;
        }
    }
}

/// The dynamics over the horizon linearised around a nominal trajectory:
/// F(Δ, α, Z) = AΔ + Bα + CZ + D ∈ R^{4T}, block k (k = 0..T) being the linearised
/// f(z_k, δ_k, a_k) − z_{k+1}, with z_0 the measured state.
///
/// Structure: A is block-diagonal (`jd[k]` in rows 4k..4k+4, column k), B likewise with
/// `ja` = (0, 0, 0, dt), C has −I on the diagonal blocks and `jz[k]` on the sub-diagonal block
/// (rows of step k, columns of state z_k, k ≥ 1).
#[derive(Debug, Clone, PartialEq)]
pub struct Linearisation {
    /// Horizon T (steps).
    pub horizon: usize,
    /// ∂f/∂z at each nominal point, `[T]` of `[4, 4]`, k = 0..T (`jz[0]` multiplies the
    /// fixed z_0 and enters D).
    pub jz: Vec<Jac4>,
    /// ∂f/∂δ at each nominal point, `[T]` of `[4]` (A's blocks).
    pub jd: Vec<State>,
    /// ∂f/∂a, `[4]` (B's blocks; constant).
    pub ja: State,
    /// The constant term D, `[T]` blocks of 4.
    pub d: Vec<State>,
}

impl Linearisation {
    /// Linearises around the nominal states `nominal` (z̄_0..z̄_{T−1}; z̄_0 should be the
    /// measured state) and inputs, with the measured state `z0`. Nominal speeds are clamped to
    /// at least `v_lin_min` (the model degenerates at v = 0).
    #[must_use]
    pub fn new(
        model: &Bicycle,
        z0: &State,
        nominal: &[State],
        nom_delta: &[f64],
        nom_accel: &[f64],
        v_lin_min: f64,
    ) -> Self {
        let t = nominal.len();
        let mut jz = Vec::with_capacity(t);
        let mut jd = Vec::with_capacity(t);
        let mut d = Vec::with_capacity(t);
        let mut ja = State::zeros();
        for k in 0..t {
            let mut zb = nominal[k];
            zb[3] = zb[3].max(v_lin_min);
            let (j, g, h) = model.jacobians(&zb, nom_delta[k]);
            let fz = model.step(&zb, nom_delta[k], nom_accel[k]);
            let mut dk = fz - j * zb - g * nom_delta[k] - h * nom_accel[k];
            if k == 0 {
                dk += j * z0;
            }
            jz.push(j);
            jd.push(g);
            ja = h;
            d.push(dk);
        }
        Self {
            horizon: t,
            jz,
            jd,
            ja,
            d,
        }
    }

    /// Evaluates F(Δ, α, Z) into `out` (`[T]` states); `delta` `[T]` (rad), `accel` `[T]`
    /// (m/s²), `z` `[T]` holds z_1..z_T.
    pub fn residual(&self, delta: &[f64], accel: &[f64], z: &[State], out: &mut [State]) {
        for k in 0..self.horizon {
            let mut r = self.d[k] + self.jd[k] * delta[k] + self.ja * accel[k] - z[k];
            if k > 0 {
                r += self.jz[k] * z[k - 1];
            }
            out[k] = r;
        }
    }

    /// `out = C v` for a stacked state vector `v` (`[T]` blocks).
    pub fn apply_c(&self, v: &[State], out: &mut [State]) {
        for k in 0..self.horizon {
            let mut r = -v[k];
            if k > 0 {
                r += self.jz[k] * v[k - 1];
            }
            out[k] = r;
        }
    }

    /// `out = Cᵀ w`.
    pub fn apply_ct(&self, w: &[State], out: &mut [State]) {
        for k in 0..self.horizon {
            let mut r = -w[k];
            if k + 1 < self.horizon {
                r += self.jz[k + 1].transpose() * w[k + 1];
            }
            out[k] = r;
        }
    }

    /// Dense A (`[4T, T]`, row-major).
    #[must_use]
    pub fn dense_a(&self) -> Vec<f64> {
        let t = self.horizon;
        let mut a = vec![0.0; 4 * t * t];
        for k in 0..t {
            for i in 0..4 {
                a[(4 * k + i) * t + k] = self.jd[k][i];
            }
        }
        a
    }

    /// Dense B (`[4T, T]`, row-major).
    #[must_use]
    pub fn dense_b(&self) -> Vec<f64> {
        let t = self.horizon;
        let mut b = vec![0.0; 4 * t * t];
        for k in 0..t {
            for i in 0..4 {
                b[(4 * k + i) * t + k] = self.ja[i];
            }
        }
        b
    }

    /// Dense C (`[4T, 4T]`, row-major).
    #[must_use]
    pub fn dense_c(&self) -> Vec<f64> {
        let n = 4 * self.horizon;
        let mut c = vec![0.0; n * n];
        for k in 0..self.horizon {
            for i in 0..4 {
                c[(4 * k + i) * n + 4 * k + i] = -1.0;
                if k > 0 {
                    for j in 0..4 {
                        c[(4 * k + i) * n + 4 * (k - 1) + j] = self.jz[k][(i, j)];
                    }
                }
            }
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> Bicycle {
        Bicycle {
            l_f: 1.4,
            l_r: 1.4,
            dt: 0.3,
        }
    }

    /// Central differences vs the analytic Jacobians at several points (abs + rel tolerance).
    #[test]
    fn jacobians_match_finite_differences() {
        let m = model();
        let pts = [
            (State::new(0.0, 0.0, 0.0, 10.0), 0.0),
            (State::new(5.0, -2.0, 0.3, 3.0), 0.1),
            (State::new(-1.0, 3.5, -0.7, 25.0), -0.14),
            (State::new(0.0, 0.0, 1.2, 0.5), 0.4),
        ];
        let h = 1e-6;
        for (z, d) in pts {
            let (jz, jd, ja) = m.jacobians(&z, d);
            for j in 0..4 {
                let mut zp = z;
                let mut zm = z;
                zp[j] += h;
                zm[j] -= h;
                let fd = (m.step(&zp, d, 0.7) - m.step(&zm, d, 0.7)) / (2.0 * h);
                for i in 0..4 {
                    let e = (fd[i] - jz[(i, j)]).abs();
                    assert!(e <= 1e-7 + 1e-6 * fd[i].abs(), "dz {i},{j}: {e}");
                }
            }
            let fd = (m.step(&z, d + h, 0.7) - m.step(&z, d - h, 0.7)) / (2.0 * h);
            for i in 0..4 {
                assert!((fd[i] - jd[i]).abs() <= 1e-7 + 1e-6 * fd[i].abs(), "dδ {i}");
            }
            let fd = (m.step(&z, d, 0.7 + h) - m.step(&z, d, 0.7 - h)) / (2.0 * h);
            for i in 0..4 {
                assert!((fd[i] - ja[i]).abs() <= 1e-7 + 1e-6 * fd[i].abs(), "da {i}");
            }
        }
    }

    /// `advance` is `step` with the speed clamped at 0; the roll-out chains `advance`.
    #[test]
    fn advance_clamps_speed_and_rollout_chains_it() {
        let m = model();
        let z = State::new(1.0, 2.0, 0.1, 0.5);
        // Hard braking from 0.5 m/s: the unclamped step reverses, the vehicle stops.
        let free = m.step(&z, 0.05, -6.0);
        assert!(free[3] < 0.0);
        let driven = m.advance(&z, 0.05, -6.0);
        assert_eq!(driven[3], 0.0);
        assert_eq!(driven.fixed_rows::<3>(0), free.fixed_rows::<3>(0));
        // Without braking below 0 the two agree bit for bit.
        assert_eq!(m.advance(&z, 0.05, 1.0), m.step(&z, 0.05, 1.0));
        let mut out = vec![State::zeros(); 3];
        m.rollout(&z, &[0.05, 0.0, -0.05], &[-6.0, -6.0, 2.0], &mut out);
        assert_eq!(out[0], driven);
        assert_eq!(out[1], m.advance(&driven, 0.0, -6.0));
        assert_eq!(out[2], m.advance(&out[1], -0.05, 2.0));
        assert!((out[2][3] - 0.6).abs() < 1e-12, "speed {}", out[2][3]);
    }

    /// The linearisation is exact at the nominal point and first-order accurate near it.
    #[test]
    fn linearisation_exact_at_nominal() {
        let m = model();
        let z0 = State::new(0.0, 0.0, 0.05, 12.0);
        let dn = [0.02, 0.01, 0.0, -0.01];
        let an = [0.5, 0.0, -0.5, 0.2];
        let mut roll = vec![State::zeros(); 4];
        m.rollout(&z0, &dn, &an, &mut roll);
        let mut nominal = vec![z0];
        nominal.extend_from_slice(&roll[..3]);
        let lin = Linearisation::new(&m, &z0, &nominal, &dn, &an, 1.0);
        let mut f = vec![State::zeros(); 4];
        lin.residual(&dn, &an, &roll, &mut f);
        for r in &f {
            assert!(r.amax() < 1e-12, "residual at nominal {r}");
        }
        // Perturb inputs by ε: the linear prediction error must be O(ε²).
        let eps = 1e-3;
        let dp: Vec<f64> = dn.iter().map(|d| d + eps).collect();
        let ap: Vec<f64> = an.iter().map(|a| a - eps).collect();
        let mut rp = vec![State::zeros(); 4];
        m.rollout(&z0, &dp, &ap, &mut rp);
        lin.residual(&dp, &ap, &rp, &mut f);
        for r in &f {
            assert!(r.amax() < 1e-4, "second-order error too large {r}");
        }
        // Dense matrices agree with the structured products.
        let c = lin.dense_c();
        let n = 16;
        let v: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let vs: Vec<State> = v.chunks(4).map(State::from_column_slice).collect();
        let mut cv = vec![State::zeros(); 4];
        lin.apply_c(&vs, &mut cv);
        let mut ctv = vec![State::zeros(); 4];
        lin.apply_ct(&vs, &mut ctv);
        for i in 0..n {
            let dense: f64 = (0..n).map(|j| c[i * n + j] * v[j]).sum();
            assert!((dense - cv[i / 4][i % 4]).abs() < 1e-12);
            let dense_t: f64 = (0..n).map(|j| c[j * n + i] * v[j]).sum();
            assert!((dense_t - ctv[i / 4][i % 4]).abs() < 1e-12);
        }
    }
}
