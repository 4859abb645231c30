//! The joint reference QP: the linearised problem of one call solved as ONE Clarabel QP in
//! (Δ, α, Z), without the safety constraint. With no vehicle in range ADMM must converge to
//! its solution (the planner's correctness anchor).

use clarabel::solver::{DefaultSolver, IPSolver, NonnegativeConeT};

use crate::error::PlannerError;
use crate::model::State;
use crate::qp::{
    QpFailure, QpName, QpStatus, box_rate_rows, clarabel_settings, triplets_csc, upper_csc, usable,
    zero_cone,
};
use crate::settings::PlannerSettings;

use super::linearised::{LinearisedProblem, input_hessian};

/// The solution of the linearised problem as one joint QP (no safety constraint).
#[derive(Debug, Clone, PartialEq)]
pub struct JointSolution {
    /// Steering `[T]` (rad).
    pub delta: Vec<f64>,
    /// Acceleration `[T]` (m/s²).
    pub accel: Vec<f64>,
    /// States z_1..z_T in the road frame (m, m, rad, m/s), `[T]`.
    pub states: Vec<[f64; 4]>,
    /// Cost J at the solution.
    pub cost: f64,
}

/// The joint QP's data: min ½xᵀPx + qᵀx s.t. A x + s = b, s in the zero cone (dynamics, the
/// first 4T rows) then the non-negative cone (box/rate bounds of Δ and α, y and v bounds);
/// x = (Δ, α, z_1..z_T).
struct JointQp {
    /// Dense P `[6T, 6T]` row-major.
    p: Vec<f64>,
    q: Vec<f64>,
    /// (row, column, value) triplets of A.
    a: Vec<(usize, usize, f64)>,
    b: Vec<f64>,
}

impl JointQp {
    fn new(s: &PlannerSettings, lp: &LinearisedProblem) -> Self {
        let t = lp.horizon;
        let nv = 6 * t;
        let mut qp = Self {
            p: vec![0.0; nv * nv],
            q: vec![0.0; nv],
            a: Vec::new(),
            b: Vec::new(),
        };
        qp.objective(s, lp);
        qp.dynamics(lp);
        box_rate_rows(&mut qp.a, &mut qp.b, 0, t, lp.delta_box);
        box_rate_rows(&mut qp.a, &mut qp.b, t, t, lp.accel_box);
        qp.state_bounds(lp);
        qp
    }

    /// J = Φ1 + Φ2 + Φ3 as ½xᵀPx + qᵀx (+ constant).
    fn objective(&mut self, s: &PlannerSettings, lp: &LinearisedProblem) {
        let t = lp.horizon;
        let nv = 6 * t;
        let pd = input_hessian(t, s.cost.w_delta, s.cost.w_ddelta, &vec![0.0; t]);
        let pa = input_hessian(t, s.cost.w_a, s.cost.w_da, &vec![0.0; t]);
        for i in 0..t {
            for j in 0..t {
                self.p[i * nv + j] = pd[i * t + j];
                self.p[(t + i) * nv + t + j] = pa[i * t + j];
            }
        }
        self.q[0] = -2.0 * s.cost.w_ddelta * lp.delta_box.prev;
        self.q[t] = -2.0 * s.cost.w_da * lp.accel_box.prev;
        for k in 0..t {
            for j in 0..4 {
                let idx = 2 * t + 4 * k + j;
                self.p[idx * nv + idx] = 2.0 * lp.weights[j];
                self.q[idx] = -2.0 * lp.weights[j] * lp.reference[j];
            }
        }
    }

    /// AΔ + Bα + CZ = −D (the first 4T rows).
    fn dynamics(&mut self, lp: &LinearisedProblem) {
        let t = lp.horizon;
        let lin = &lp.linearisation;
        let (da, db, dc) = (lin.dense_a(), lin.dense_b(), lin.dense_c());
        let m4 = 4 * t;
        for r in 0..m4 {
            for c in 0..t {
                if da[r * t + c] != 0.0 {
                    self.a.push((r, c, da[r * t + c]));
                }
                if db[r * t + c] != 0.0 {
                    self.a.push((r, t + c, db[r * t + c]));
                }
            }
            for c in 0..m4 {
                if dc[r * m4 + c] != 0.0 {
                    self.a.push((r, 2 * t + c, dc[r * m4 + c]));
                }
            }
            self.b.push(-lin.d[r / 4][r % 4]);
        }
    }

    /// lower_k ≤ (y_k, ψ_k, v_k) ≤ upper_k (infinite bounds are left out).
    fn state_bounds(&mut self, lp: &LinearisedProblem) {
        let t = lp.horizon;
        for k in 0..t {
            for j in [1usize, 2, 3] {
                let idx = 2 * t + 4 * k + j;
                if lp.upper[k][j].is_finite() {
                    let r = self.b.len();
                    self.a.push((r, idx, 1.0));
                    self.b.push(lp.upper[k][j]);
                }
                if lp.lower[k][j].is_finite() {
                    let r = self.b.len();
                    self.a.push((r, idx, -1.0));
                    self.b.push(-lp.lower[k][j]);
                }
            }
        }
    }

    /// Solves with Clarabel (equilibration on, then off); the primal solution x.
    fn solve(self) -> Result<Vec<f64>, QpFailure> {
        let nv = self.q.len();
        let m4 = 4 * (nv / 6);
        let p = upper_csc(&self.p, nv);
        let m = self.b.len();
        let a = triplets_csc(m, nv, self.a);
        let cones = vec![zero_cone(m4), NonnegativeConeT(m - m4)];
        let mut status = QpStatus::Unsolved;
        for equilibrate in [true, false] {
            let settings = clarabel_settings(equilibrate);
            let mut solver = DefaultSolver::new(&p, &self.q, &a, &self.b, &cones, settings)
                .map_err(|e| QpFailure {
                    qp: QpName::Joint,
                    iteration: 0,
                    status: QpStatus::Setup,
                    detail: Some(e.to_string()),
                })?;
            solver.solve();
            if usable(solver.solution.status) {
                return Ok(solver.solution.x.clone());
            }
            status = solver.solution.status.into();
        }
        Err(QpFailure {
            qp: QpName::Joint,
            iteration: 0,
            status,
            detail: None,
        })
    }
}

/// Solves `lp` as one joint QP.
pub(crate) fn solve_joint(
    s: &PlannerSettings,
    lp: &LinearisedProblem,
) -> Result<JointSolution, PlannerError> {
    let t = lp.horizon;
    let x = JointQp::new(s, lp).solve()?;
    let delta = x[..t].to_vec();
    let accel = x[t..2 * t].to_vec();
    let z: Vec<State> = (0..t)
        .map(|k| State::from_column_slice(&x[2 * t + 4 * k..2 * t + 4 * k + 4]))
        .collect();
    let cost = lp.cost(s, &delta, &accel, &z);
    Ok(JointSolution {
        states: lp.to_world(&z),
        delta,
        accel,
        cost,
    })
}
