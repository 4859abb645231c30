//! The linearised-safety step of the Z-update: the minimiser of G(Z + dZ) over dZ (G is
//! exactly quadratic in Z: ½ dZᵀ H dZ + ∇G·dZ) subject to the safety rows of the current Z
//! linearised in the ego's position,
//!
//!   b_ik + ∇b_ik · (dx_k, dy_k) ≥ target  for every (vehicle, step) with b_ik < `ROW_B`,
//!
//! the prediction and the ellipse held at the current Z. The plain Newton step −H⁻¹∇G is G's
//! minimiser without the safety constraint: when Z sits on the constraint boundary every
//! Newton trial crosses it and the Z-update stalls (measured on validation scenes: 96 % of the
//! calls that reach `max_iter` end with Z frozen on the boundary); this step slides Z along
//! the boundary instead, and from an unsafe Z it moves towards safety.
//!
//! Solved by a small active-set method on H⁻¹ (constant per call): the most violated row
//! joins the active set, the multipliers λ solve (A H⁻¹ Aᵀ) λ = c − A d₀ with d₀ = −H⁻¹∇G,
//! negative ones leave it, and d = d₀ + H⁻¹ Aᵀ λ; at most [`MAX_ACTIVE`] rounds. The state
//! bounds are left to the projection of the trial point, and every trial point is checked by
//! the predictor like any other, so an approximate step costs a predictor call, never safety.

use nalgebra::{DMatrix, DVector};

use crate::model::State;

use super::constraint::SafetyRow;

/// Rounds of the active-set method (rows added at most).
pub(crate) const MAX_ACTIVE: usize = 8;

/// A row counts as violated above this (units of b).
const ROW_TOLERANCE: f64 = 1e-9;

/// Largest component of a step (m, rad, m/s): nearly parallel active rows make the
/// multipliers, and the step, huge; such a step is no trial point (a horizon of 6 × 0.3 s at
/// 30 m/s covers 54 m).
pub(crate) const MAX_STEP: f64 = 50.0;

/// One linear row Σ coef · d[index] ≥ `need` on the stacked step d (`[4T]`, Z⁺ = Z + d), with
/// at most two non-zero coefficients: a safety row (∇b on x_k, y_k) or a state bound (±1 on
/// one component).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StepRow {
    /// (index into the stacked step, coefficient); an unused term has coefficient 0.
    pub terms: [(usize, f64); 2],
    /// The right-hand side.
    pub need: f64,
}

impl StepRow {
    /// The safety row `r` at `target`: ∇b_r · d_xy ≥ target − b_r.
    pub(crate) fn safety(r: &SafetyRow, target: f64) -> Self {
        Self {
            terms: [(4 * r.step, r.gradient[0]), (4 * r.step + 1, r.gradient[1])],
            need: target - r.b,
        }
    }

    /// Σ coef · v[index].
    pub(crate) fn along(&self, v: &[f64]) -> f64 {
        self.terms.iter().map(|&(i, c)| c * v[i]).sum()
    }
}

/// The step d (`[T]` states, Z⁺ = Π(Z − η d) as every Z-update trial) of the problem above,
/// with H⁻¹ `inverse` (`[4T, 4T]` row-major), ∇G `gradient` (`[T]`), the safety `rows` of Z
/// and their `target` (units of b). Writes `out`; returns `false` when no step is defined
/// (a singular active set, or a component that is non-finite or beyond [`MAX_STEP`]).
pub(crate) fn linearised_step(
    inverse: &[f64],
    gradient: &[State],
    rows: &[SafetyRow],
    target: f64,
    out: &mut [State],
) -> bool {
    let rows: Vec<StepRow> = rows.iter().map(|r| StepRow::safety(r, target)).collect();
    constrained_step(inverse, gradient, &rows, MAX_ACTIVE, out)
}

/// The minimiser d of ½dᵀHd + ∇G·d subject to the linear `rows` (the same active-set method,
/// for rows of any two components, at most `rounds` rows added), written as `out` = −d;
/// `false` when no step is defined.
pub(crate) fn constrained_step(
    inverse: &[f64],
    gradient: &[State],
    rows: &[StepRow],
    rounds: usize,
    out: &mut [State],
) -> bool {
    let nz = 4 * gradient.len();
    let g: Vec<f64> = gradient.iter().flat_map(|s| s.iter().copied()).collect();
    // d0 = −H⁻¹ g.
    let d0: Vec<f64> = (0..nz)
        .map(|r| -(0..nz).map(|c| inverse[r * nz + c] * g[c]).sum::<f64>())
        .collect();
    // H⁻¹ aᵣ for every row (H⁻¹ is symmetric).
    let hinv_a: Vec<Vec<f64>> = rows
        .iter()
        .map(|r| {
            (0..nz)
                .map(|i| r.terms.iter().map(|&(j, c)| inverse[i * nz + j] * c).sum())
                .collect()
        })
        .collect();
    let mut active: Vec<usize> = Vec::new();
    let mut d = d0.clone();
    for _ in 0..rounds {
        let worst = rows
            .iter()
            .enumerate()
            .filter(|(j, _)| !active.contains(j))
            .map(|(j, r)| (j, r.need - r.along(&d)))
            .filter(|&(_, v)| v > ROW_TOLERANCE)
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let Some((j, _)) = worst else {
            break;
        };
        active.push(j);
        loop {
            let m = active.len();
            let mat = DMatrix::from_fn(m, m, |a, b| rows[active[a]].along(&hinv_a[active[b]]));
            let rhs = DVector::from_fn(m, |a, _| rows[active[a]].need - rows[active[a]].along(&d0));
            let Some(lambda) = mat.lu().solve(&rhs) else {
                return false;
            };
            if let Some((drop, _)) = lambda
                .iter()
                .enumerate()
                .filter(|(_, l)| **l < 0.0)
                .min_by(|a, b| a.1.total_cmp(b.1))
            {
                active.remove(drop);
                if active.is_empty() {
                    d.copy_from_slice(&d0);
                    break;
                }
                continue;
            }
            d.copy_from_slice(&d0);
            for (a, l) in active.iter().zip(lambda.iter()) {
                for (di, hi) in d.iter_mut().zip(&hinv_a[*a]) {
                    *di += l * hi;
                }
            }
            break;
        }
    }
    for (k, o) in out.iter_mut().enumerate() {
        *o = -State::new(d[4 * k], d[4 * k + 1], d[4 * k + 2], d[4 * k + 3]);
    }
    d.iter().all(|v| v.is_finite() && v.abs() <= MAX_STEP)
}
