//! The heading governor: the steering of a candidate limited so that its nonlinear roll-out
//! keeps the heading bounds.
//!
//! The ADMM iterates keep |ψ_k| within the heading bound on the *linearised* dynamics only;
//! the nonlinear roll-out of their inputs, which is what the vehicle does, can pass it by a
//! few milliradians, and a plan that nothing admissible beats is returned as it is. So
//! every candidate's steering goes through
//! [`govern_heading`] before its roll-out is checked.
//!
//! The rule looks ahead because the steering rate is bounded: a heading may be within the
//! bound after this step and still be unable to stop before it (at 11.5 m/s with a steering
//! of 0.06 rad and a rate of 0.05 rad per step, the least steering the next step allows still
//! turns the car 0.02 rad further). A steering δ_k is *viable* for the upper bound when the
//! roll-out that follows it by unwinding the steering as fast as the rate allows
//! (δ_j = max(δ_{j−1} − rate, lo)) at the **fastest** speeds the acceleration box allows
//! (a_j = a_max for j > k) keeps ψ ≤ upper at every later step of the horizon. The
//! continuation's turn is thus the most any later plan can be forced into: the heading rate
//! dt·v·sin β(δ)/l_r grows with δ and, while the steering is still turning the car towards
//! the bound, with v; so however the next planning steps choose their accelerations (a
//! fallback that holds the speed after a plan that braked), they can still unwind in time.
//! With the candidate's own accelerations in the continuation, a plan could keep the bound
//! by braking and leave the next step, holding its speed, no viable steering (0.2010 rad on
//! a train-split run, `docs/results/heading_governor.md`). The lower bound mirrors it.

use crate::model::{Bicycle, State};
use crate::qp::RateBox;

/// Heading tolerance of the viability test (rad): rounding, not a margin.
const TOLERANCE: f64 = 1e-12;

/// Bisection steps of the viable steering's search (the interval shrinks below 1e-16 rad).
const BISECTIONS: usize = 60;

/// Limits the steering `delta` (`[T]`, rad; changed in place) so that the roll-out from
/// `start` under `delta` and `accel` (`[T]`, m/s²) keeps ψ_{k+1} within
/// [`lower[k][2]`, `upper[k][2]`] (rad, the call's frame) at every step, within the box and
/// rate bounds `bounds`, and so that it could still do so if every later step accelerated at
/// `accel_max` (m/s²; the module docs).
///
/// Step k, from the governed state z_k: the steering is first brought into the box and the
/// rate window of the governed δ_{k−1} (a no-op for a sequence that keeps them, until an
/// earlier step was governed); then, when it is not viable (module docs) for a bound, it is
/// replaced by the viable steering of the window nearest to it (found by bisection; the
/// roll-out then reaches that bound at some later step), or by the window's end towards the
/// other bound when none is. When no steering of the window is viable for both bounds, the
/// steering between the two limits nearest to the candidate's is taken. A sequence every
/// step of which is viable is returned as it is, bit for bit. Returns the number of governed
/// steps.
#[allow(clippy::too_many_arguments)]
pub(crate) fn govern_heading(
    model: &Bicycle,
    start: &State,
    delta: &mut [f64],
    accel: &[f64],
    accel_max: f64,
    bounds: RateBox,
    lower: &[State],
    upper: &[State],
) -> usize {
    let view = Lookahead {
        model,
        accel,
        bounds_accel_hi: accel_max,
        bounds,
        lower,
        upper,
    };
    let mut z = *start;
    let mut prev = bounds.prev.clamp(bounds.lo, bounds.hi);
    let mut governed = 0;
    for k in 0..delta.len() {
        let lo = bounds.lo.max(prev - bounds.rate);
        let hi = bounds.hi.min(prev + bounds.rate);
        let d = delta[k].clamp(lo, hi);
        // The largest steering viable for the upper bound, the smallest for the lower one.
        let most = view.limit(&z, k, lo, hi, Side::Upper);
        let least = view.limit(&z, k, lo, hi, Side::Lower);
        let governed_d = if least <= most {
            d.clamp(least, most)
        } else {
            d.clamp(most, least)
        };
        governed += usize::from(governed_d != delta[k]);
        delta[k] = governed_d;
        z = model.advance(&z, governed_d, accel[k]);
        prev = governed_d;
    }
    governed
}

/// Which heading bound a viability test is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    /// ψ ≤ upper: the continuation unwinds the steering downwards.
    Upper,
    /// ψ ≥ lower: the continuation unwinds it upwards.
    Lower,
}

/// What a viability test needs besides the state and the step.
struct Lookahead<'a> {
    model: &'a Bicycle,
    accel: &'a [f64],
    /// The largest acceleration (m/s²): the continuation's, after the governed step.
    bounds_accel_hi: f64,
    bounds: RateBox,
    lower: &'a [State],
    upper: &'a [State],
}

impl Lookahead<'_> {
    /// Whether steering `d` at step `k` from `z` is viable for `side`: the roll-out of `d`
    /// (with the candidate's acceleration at k), then of the steering unwound at the rate
    /// bound away from that bound at the largest acceleration, keeps ψ within it (up to
    /// [`TOLERANCE`]) at steps k + 1..T.
    fn viable(&self, z: &State, k: usize, d: f64, side: Side) -> bool {
        let mut z = *z;
        let mut d = d;
        for j in k..self.accel.len() {
            if j > k {
                d = match side {
                    Side::Upper => (d - self.bounds.rate).max(self.bounds.lo),
                    Side::Lower => (d + self.bounds.rate).min(self.bounds.hi),
                };
            }
            let a = if j > k {
                self.bounds_accel_hi
            } else {
                self.accel[j]
            };
            z = self.model.advance(&z, d, a);
            let within = match side {
                Side::Upper => z[2] <= self.upper[j][2] + TOLERANCE,
                Side::Lower => z[2] >= self.lower[j][2] - TOLERANCE,
            };
            if !within {
                return false;
            }
        }
        true
    }

    /// The viable steering of the window [`lo`, `hi`] nearest to the bound's side: for
    /// [`Side::Upper`] the largest viable one (`hi` when it is viable, `lo` when nothing is),
    /// for [`Side::Lower`] the smallest. Viability is monotone in the steering (a larger one
    /// turns the roll-out further left at every step), so bisection finds the limit.
    fn limit(&self, z: &State, k: usize, lo: f64, hi: f64, side: Side) -> f64 {
        let (mut good, mut bad) = match side {
            Side::Upper => (lo, hi),
            Side::Lower => (hi, lo),
        };
        if self.viable(z, k, bad, side) {
            return bad;
        }
        if !self.viable(z, k, good, side) {
            return good;
        }
        for _ in 0..BISECTIONS {
            let mid = 0.5 * (good + bad);
            if mid == good || mid == bad {
                break;
            }
            if self.viable(z, k, mid, side) {
                good = mid;
            } else {
                bad = mid;
            }
        }
        good
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::PlannerSettings;

    /// The default bicycle (l_f = l_r = 1.4 m, dt = 0.3 s).
    fn model() -> Bicycle {
        crate::admm::tests::model(&PlannerSettings::default())
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

    /// The default largest acceleration (m/s²): the continuation's.
    const A_MAX: f64 = 3.0;

    fn govern(start: &State, delta: &mut [f64], accel: &[f64], prev: f64) -> usize {
        let (lo, hi) = heading_bounds(delta.len(), 0.2);
        govern_heading(
            &model(),
            start,
            delta,
            accel,
            A_MAX,
            steering_box(prev),
            &lo,
            &hi,
        )
    }

    /// The fastest unwinding of the steering from `d0` at the fastest speeds (the
    /// continuation of the viability test, written out here) from `start`, the first step at
    /// `accel`, the rest at [`A_MAX`]: the largest heading it reaches (rad).
    fn unwound_peak(start: &State, d0: f64, accel: f64, steps: usize) -> f64 {
        let mut z = *start;
        let mut peak = f64::NEG_INFINITY;
        let mut d = d0;
        for j in 0..steps {
            let a = if j > 0 {
                d = (d - 0.05).max(-0.15);
                A_MAX
            } else {
                accel
            };
            z = model().advance(&z, d, a);
            peak = peak.max(z[2]);
        }
        peak
    }

    /// A gentle sequence (its roll-out keeps the bounds with room to unwind at the fastest
    /// speeds) comes back unchanged, bit for bit.
    #[test]
    fn a_sequence_within_the_bounds_is_unchanged() {
        let start = State::new(0.0, 0.0, 0.05, 12.0);
        let mut delta = vec![0.03, 0.02, 0.0, -0.03, -0.05, -0.02];
        let accel = vec![0.5; 6];
        let before = delta.clone();
        assert_eq!(govern(&start, &mut delta, &accel, 0.02), 0);
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
        assert_eq!(govern(&start, &mut delta, &accel, 0.04), 1);
        let after = rollout(&start, &delta, &accel);
        assert!((after[0][2] - 0.2).abs() < 1e-9, "{}", after[0][2]);
        assert!(after.iter().all(|z| z[2].abs() <= 0.2 + 1e-12));
    }

    /// The case the look-ahead is for (as seen in closed loop at 11.5 m/s): within the bound
    /// after the first step (0.161 rad), but the least steering the rate allows next (0.04
    /// rad) still turns the car to 0.210 rad, so limiting each step alone cannot keep the
    /// bound. Governed, the first step already steers less, the roll-out keeps the bound,
    /// and it reaches it (the limit is exact, not a margin).
    #[test]
    fn a_turn_that_cannot_be_stopped_in_time_is_limited_before() {
        let start = State::new(0.0, 0.0, 0.05, 11.5);
        let mut delta = vec![0.09, 0.06, 0.01, -0.03, -0.05, -0.05];
        let accel = vec![0.0; 6];
        let before = rollout(&start, &delta, &accel);
        assert!(
            before[0][2] < 0.2 && before.iter().any(|z| z[2] > 0.2005),
            "{before:?}"
        );
        let n = govern(&start, &mut delta, &accel, 0.06);
        assert!(n >= 1);
        assert!(delta[0] < 0.09, "{delta:?}");
        let after = rollout(&start, &delta, &accel);
        let peak = after.iter().map(|z| z[2]).fold(f64::NEG_INFINITY, f64::max);
        assert!(
            peak <= 0.2 + 1e-9 && peak > 0.2 - 1e-6,
            "peak {peak}: {after:?}"
        );
        // The first steering is where the fastest unwinding just reaches the bound.
        let at = unwound_peak(&start, delta[0], 0.0, 6);
        assert!((at - 0.2).abs() < 1e-9, "{at}");
    }

    /// The case the fastest continuation is for (a closed loop's two planning steps): the
    /// first plan brakes hard and keeps the bound, the ego executes its first step, and the
    /// next plan holds its speed. With the continuation at each plan's own accelerations the
    /// first plan steered so close to the bound that the second could not unwind in time
    /// (its roll-out passed 0.2 rad); with the fastest continuation it can, whatever it does.
    #[test]
    fn a_plan_that_brakes_leaves_the_next_plan_room_to_hold_its_speed() {
        let m = model();
        let (lo, hi) = heading_bounds(6, 0.2);
        let start = State::new(0.0, 0.0, 0.05, 8.0);
        let braking = vec![-5.0; 6];
        let holding = vec![0.0; 6];
        let two_steps = |accel_max_first: f64| {
            let mut first = vec![0.15; 6];
            govern_heading(
                &m,
                &start,
                &mut first,
                &braking,
                accel_max_first,
                steering_box(0.07),
                &lo,
                &hi,
            );
            let next = m.advance(&start, first[0], braking[0]);
            let mut second = vec![first[0]; 6];
            govern_heading(
                &m,
                &next,
                &mut second,
                &holding,
                A_MAX,
                steering_box(first[0]),
                &lo,
                &hi,
            );
            let out = rollout(&next, &second, &holding);
            out.iter().map(|z| z[2]).fold(next[2], f64::max)
        };
        // The first plan's continuation at its own braking: the second plan passes the bound.
        let own = two_steps(-5.0);
        assert!(own > 0.2 + 1e-6, "{own}");
        // At the fastest speeds: it keeps it.
        let fastest = two_steps(A_MAX);
        assert!(fastest <= 0.2 + 1e-9, "{fastest}");
    }

    proptest::proptest! {
        /// For any start from which the steering can still keep the bound (checked by the
        /// fastest unwinding at the fastest speeds, written out in the test), any steering
        /// sequence within the box and rate bounds and any accelerations: the governed
        /// steering keeps the box and the rate, its roll-out (the model's) keeps |ψ_k| ≤ 0.2
        /// rad at every step, and a sequence every step of which is viable (its roll-out to
        /// that step, then the fastest unwinding at the fastest speeds, keeps the bound;
        /// written out too) is unchanged.
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
            // The fastest unwinding from steering `d0` at step `k` of state `z` (mirrored by
            // `sign`), the first step at the drawn acceleration and the rest at A_MAX, keeps
            // the bound over the rest of the horizon (written out here, independently of the
            // module).
            let unwinds = |z: State, d0: f64, k: usize, sign: f64| {
                let mut z = State::new(z[0], sign * z[1], sign * z[2], z[3]);
                let mut d = sign * d0;
                for (j, a_j) in accel.iter().enumerate().skip(k) {
                    let a = if j > k {
                        d = (d - 0.05).max(-0.15);
                        A_MAX
                    } else {
                        *a_j
                    };
                    z = m.advance(&z, d, a);
                    if z[2] > 0.2 + 1e-12 {
                        return false;
                    }
                }
                true
            };
            // The start can keep both bounds: from the window's end nearest each.
            let start = State::new(0.0, 0.0, psi, v);
            let keeps = |sign: f64| unwinds(start, sign * (sign * prev - 0.05).max(-0.15), 0, sign);
            proptest::prop_assume!(keeps(1.0) && keeps(-1.0));
            let original = rollout(&start, &delta, &accel);
            let within = (0..6).all(|k| {
                let z = if k == 0 { start } else { original[k - 1] };
                unwinds(z, delta[k], k, 1.0) && unwinds(z, delta[k], k, -1.0)
            });
            let mut governed = delta.clone();
            govern(&start, &mut governed, &accel, prev);
            let after = rollout(&start, &governed, &accel);
            let mut p = prev;
            for (k, d) in governed.iter().enumerate() {
                proptest::prop_assert!(*d >= bx.lo && *d <= bx.hi);
                proptest::prop_assert!((d - p).abs() <= bx.rate + 1e-12, "rate at {k}");
                proptest::prop_assert!(after[k][2].abs() <= 0.2 + 1e-9, "step {k}: {:?}", after[k]);
                p = *d;
            }
            if within {
                proptest::prop_assert_eq!(governed, delta);
            }
        }
    }
}
