//! The heading governor: the steering of a candidate limited so that its nonlinear roll-out
//! keeps the heading bounds.
//!
//! The ADMM iterates keep |ψ_k| within the heading bound on the *linearised* dynamics only;
//! the nonlinear roll-out of their inputs, which is what the vehicle does, can pass it by a
//! few milliradians, and a plan nothing admissible beats is returned as it is. With
//! `PlannerSettings::heading_governor` every candidate's steering goes through
//! [`govern_heading`] before its roll-out is checked: step by step, the steering is the value
//! nearest to the candidate's that the box and rate bounds allow and that keeps ψ_{k+1}
//! within [lower_k, upper_k] on the exact model, so the returned states keep the bound
//! wherever the steering bounds can keep it.

use crate::model::{Bicycle, State};
use crate::qp::RateBox;

/// Limits the steering `delta` (`[T]`, rad; changed in place) so that the roll-out from
/// `start` under `delta` and `accel` (`[T]`, m/s²) keeps ψ_{k+1} within
/// [`lower[k][2]`, `upper[k][2]`] (rad, the call's frame) at every step, within the box and
/// rate bounds `bounds`.
///
/// Step k, from the governed state z_k: the steering is first brought into the box and the
/// rate window of the governed δ_{k−1} (a no-op for an input sequence that keeps them, until
/// a step before it was governed); if the exact step then leaves the heading bounds, δ_k is
/// replaced by the steering that puts ψ_{k+1} on the bound it passes (the inverse of
/// ψ_{k+1} = ψ_k + dt·v_k·sin β(δ)/l_r), or by the end of the window nearest to it when the
/// window cannot reach it. Steps that keep the bounds are unchanged, so a sequence whose
/// roll-out keeps them is returned as it is, bit for bit. Returns the number of governed
/// steps.
pub(crate) fn govern_heading(
    model: &Bicycle,
    start: &State,
    delta: &mut [f64],
    accel: &[f64],
    bounds: RateBox,
    lower: &[State],
    upper: &[State],
) -> usize {
    let mut z = *start;
    let mut prev = bounds.prev.clamp(bounds.lo, bounds.hi);
    let mut governed = 0;
    for (k, (d, a)) in delta.iter_mut().zip(accel).enumerate() {
        let lo = bounds.lo.max(prev - bounds.rate);
        let hi = bounds.hi.min(prev + bounds.rate);
        *d = d.clamp(lo, hi);
        let psi = model.step(&z, *d, *a)[2];
        let (psi_lo, psi_hi) = (lower[k][2], upper[k][2]);
        let goal = if psi > psi_hi {
            Some(psi_hi)
        } else if psi < psi_lo {
            Some(psi_lo)
        } else {
            None
        };
        if let Some(steer) = goal.and_then(|g| steering_to(model, &z, g)) {
            *d = steer.clamp(lo, hi);
            governed += 1;
        }
        z = model.advance(&z, *d, *a);
        prev = *d;
    }
    governed
}

/// The steering (rad) whose exact step from `z` ends at heading `goal` (rad): the inverse of
/// ψ⁺ = ψ + dt·v·sin β(δ)/l_r with β(δ) = atan(l_r/(l_f+l_r)·tan δ). A turn larger than the
/// model can make in one step gives the steering of the largest one (±π/2, beyond any box).
/// `None` for a vehicle at rest, whose heading no steering changes.
fn steering_to(model: &Bicycle, z: &State, goal: f64) -> Option<f64> {
    let reach = model.dt * z[3] / model.l_r;
    if reach <= 0.0 {
        return None;
    }
    let sin_beta = ((goal - z[2]) / reach).clamp(-1.0, 1.0);
    let beta = sin_beta.asin();
    Some(((model.l_f + model.l_r) / model.l_r * beta.tan()).atan())
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

    fn steering_box(prev: f64) -> RateBox {
        RateBox {
            lo: -0.15,
            hi: 0.15,
            rate: 0.05,
            prev,
        }
    }

    /// Heading bounds ±`h` at every step of a horizon of `t`.
    fn heading_bounds(t: usize, h: f64) -> (Vec<State>, Vec<State>) {
        let lo = State::new(f64::NEG_INFINITY, f64::NEG_INFINITY, -h, f64::NEG_INFINITY);
        let hi = State::new(f64::INFINITY, f64::INFINITY, h, f64::INFINITY);
        (vec![lo; t], vec![hi; t])
    }

    fn rollout(start: &State, delta: &[f64], accel: &[f64]) -> Vec<State> {
        let mut out = vec![State::zeros(); delta.len()];
        model().rollout(start, delta, accel, &mut out);
        out
    }

    /// The inverse lands the exact step on the goal heading (checked with the model's step,
    /// not the inverse's formula).
    #[test]
    fn steering_to_is_the_inverse_of_the_heading_step() {
        let m = model();
        for (v, psi, goal) in [(10.0, 0.17, 0.2), (25.0, -0.1, -0.2), (3.0, 0.0, 0.05)] {
            let z = State::new(0.0, 0.0, psi, v);
            let d = steering_to(&m, &z, goal).unwrap();
            let after = m.step(&z, d, 0.0)[2];
            assert!((after - goal).abs() < 1e-12, "v {v}: ψ⁺ {after} vs {goal}");
        }
        assert_eq!(steering_to(&m, &State::new(0.0, 0.0, 0.1, 0.0), 0.2), None);
    }

    /// A sequence whose roll-out keeps the bounds comes back unchanged, bit for bit.
    #[test]
    fn a_sequence_within_the_bounds_is_unchanged() {
        let start = State::new(0.0, 0.0, 0.05, 12.0);
        let mut delta = vec![0.03, 0.02, 0.0, -0.03, -0.05, -0.02];
        let accel = vec![0.5; 6];
        let before = delta.clone();
        let (lo, hi) = heading_bounds(6, 0.2);
        let n = govern_heading(
            &model(),
            &start,
            &mut delta,
            &accel,
            steering_box(0.02),
            &lo,
            &hi,
        );
        assert_eq!(n, 0);
        assert_eq!(delta, before);
    }

    /// The case seen in closed loop (ψ_0 0.172 rad at 10.5 m/s, steering 0.026 rad): the
    /// exact step passes 0.2 rad by about a milliradian; governed, it ends on the bound.
    #[test]
    fn a_step_past_the_bound_ends_on_it() {
        let start = State::new(0.0, 0.0, 0.172, 10.47);
        let mut delta = vec![0.026, 0.0, -0.04, -0.06, -0.06, -0.04];
        let accel = vec![-1.8; 6];
        let before = rollout(&start, &delta, &accel);
        assert!(before[0][2] > 0.2005, "{}", before[0][2]);
        let (lo, hi) = heading_bounds(6, 0.2);
        let n = govern_heading(
            &model(),
            &start,
            &mut delta,
            &accel,
            steering_box(0.04),
            &lo,
            &hi,
        );
        assert_eq!(n, 1);
        let after = rollout(&start, &delta, &accel);
        assert!((after[0][2] - 0.2).abs() < 1e-12, "{}", after[0][2]);
        assert!(after.iter().all(|z| z[2].abs() <= 0.2 + 1e-12));
    }

    proptest::proptest! {
        /// For any start within the bound and any steering sequence within the box and rate
        /// bounds: the governed steering keeps them, its roll-out (the model's) keeps
        /// |ψ_k| ≤ h wherever the rate window could (the rate bound may leave a step beyond
        /// it; then the steering sits at the window's end nearest the bound; a vehicle at
        /// rest cannot turn), and every step
        /// before the first one the roll-out of the original passes the bound is unchanged.
        #[test]
        fn governed_steering_keeps_the_heading_bound(
            v in 0.0f64..30.0,
            psi in -0.2f64..0.2,
            prev in -0.15f64..0.15,
            steps in proptest::collection::vec(-0.05f64..0.05, 6),
            accel in proptest::collection::vec(-5.0f64..3.0, 6),
        ) {
            let m = model();
            let bx = steering_box(prev);
            let mut delta = Vec::with_capacity(6);
            let mut p = prev;
            for s in &steps {
                p = (p + s).clamp(bx.lo, bx.hi);
                delta.push(p);
            }
            let start = State::new(0.0, 0.0, psi, v);
            let original = rollout(&start, &delta, &accel);
            let first_out = original.iter().position(|z| z[2].abs() > 0.2);
            let (lo, hi) = heading_bounds(6, 0.2);
            let mut governed = delta.clone();
            govern_heading(&m, &start, &mut governed, &accel, bx, &lo, &hi);
            let after = rollout(&start, &governed, &accel);
            let mut p = prev;
            let mut z = start;
            for (k, d) in governed.iter().enumerate() {
                proptest::prop_assert!(*d >= bx.lo && *d <= bx.hi);
                proptest::prop_assert!((d - p).abs() <= bx.rate + 1e-12, "rate at {k}");
                if after[k][2].abs() > 0.2 + 1e-9 && z[3] > 0.0 {
                    // Only where the window's end nearest the bound still passes it (or at
                    // rest, where no steering turns the vehicle).
                    let end = if after[k][2] > 0.0 { (bx.lo).max(p - bx.rate) } else { (bx.hi).min(p + bx.rate) };
                    proptest::prop_assert!((d - end).abs() < 1e-12, "step {k}: δ {d} vs end {end}");
                    let best = m.step(&z, end, accel[k])[2];
                    proptest::prop_assert!(best.abs() > 0.2, "step {k}");
                }
                if first_out.is_none_or(|f| k < f) {
                    proptest::prop_assert_eq!(*d, delta[k]);
                }
                z = after[k];
                p = *d;
            }
        }
    }
}
