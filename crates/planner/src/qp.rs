//! Box- and rate-constrained QPs in one input sequence (Δ or α), solved by Clarabel.
//!
//! min ½ uᵀPu + qᵀu  s.t.  lo ≤ u_k ≤ hi,  |u_k − u_{k−1}| ≤ r  (u_{−1} = the last applied
//! input). P is fixed for one MPC call; q changes every ADMM iteration.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, SupportedConeT,
    ZeroConeT,
};
use serde::{Deserialize, Serialize};

/// Which QP of the planner.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QpName {
    /// The Δ-update (steering sequence).
    Delta,
    /// The α-update (acceleration sequence).
    Alpha,
    /// The joint reference QP in (Δ, α, Z) ([`crate::Planner::reference_qp`]).
    Joint,
}

impl QpName {
    /// The name used in messages and records: `delta`, `alpha`, `joint`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Delta => "delta",
            Self::Alpha => "alpha",
            Self::Joint => "joint",
        }
    }
}

impl std::fmt::Display for QpName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why Clarabel gave no usable solution: the solver could not be built (`Setup`), or its
/// termination status (Clarabel's `SolverStatus`, any but `Solved` / `AlmostSolved`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum QpStatus {
    /// Clarabel refused the problem data (e.g. a non-finite matrix entry).
    Setup,
    /// The solver has not run.
    Unsolved,
    /// A solution (counted as usable).
    Solved,
    /// A solution of reduced accuracy (counted as usable).
    AlmostSolved,
    /// Certificate of primal infeasibility.
    PrimalInfeasible,
    /// Certificate of dual infeasibility.
    DualInfeasible,
    /// Primal infeasibility at reduced accuracy.
    AlmostPrimalInfeasible,
    /// Dual infeasibility at reduced accuracy.
    AlmostDualInfeasible,
    /// Iteration limit reached.
    MaxIterations,
    /// Time limit reached.
    MaxTime,
    /// Numerical error.
    NumericalError,
    /// No progress.
    InsufficientProgress,
    /// Stopped by a callback.
    CallbackTerminated,
}

impl From<SolverStatus> for QpStatus {
    fn from(s: SolverStatus) -> Self {
        match s {
            SolverStatus::Unsolved => Self::Unsolved,
            SolverStatus::Solved => Self::Solved,
            SolverStatus::AlmostSolved => Self::AlmostSolved,
            SolverStatus::PrimalInfeasible => Self::PrimalInfeasible,
            SolverStatus::DualInfeasible => Self::DualInfeasible,
            SolverStatus::AlmostPrimalInfeasible => Self::AlmostPrimalInfeasible,
            SolverStatus::AlmostDualInfeasible => Self::AlmostDualInfeasible,
            SolverStatus::MaxIterations => Self::MaxIterations,
            SolverStatus::MaxTime => Self::MaxTime,
            SolverStatus::NumericalError => Self::NumericalError,
            SolverStatus::InsufficientProgress => Self::InsufficientProgress,
            SolverStatus::CallbackTerminated => Self::CallbackTerminated,
        }
    }
}

/// A QP that gave no usable solution, also after the equilibration-off retry.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct QpFailure {
    /// Which QP.
    pub qp: QpName,
    /// ADMM iteration (0-based) of the failed solve.
    pub iteration: usize,
    /// Clarabel's status (`Setup` when the solver could not be built or updated).
    pub status: QpStatus,
    /// Clarabel's message for a set-up failure.
    pub detail: Option<String>,
}

impl QpFailure {
    fn setup(qp: QpName, iteration: usize, e: &impl std::fmt::Display) -> Self {
        Self {
            qp,
            iteration,
            status: QpStatus::Setup,
            detail: Some(e.to_string()),
        }
    }
}

/// Clarabel settings used everywhere: quiet, no presolve (q/b are updated), one thread.
pub(crate) fn clarabel_settings(equilibrate: bool) -> DefaultSettings<f64> {
    DefaultSettings {
        verbose: false,
        presolve_enable: false,
        equilibrate_enable: equilibrate,
        max_threads: 1,
        ..DefaultSettings::default()
    }
}

/// Dense upper triangle of a symmetric `[n, n]` row-major matrix as CSC with an explicit,
/// complete pattern (zeros kept).
pub(crate) fn upper_csc(dense: &[f64], n: usize) -> CscMatrix<f64> {
    let mut colptr = Vec::with_capacity(n + 1);
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    colptr.push(0);
    for j in 0..n {
        for i in 0..=j {
            rowval.push(i);
            nzval.push(dense[i * n + j]);
        }
        colptr.push(rowval.len());
    }
    CscMatrix::new(n, n, colptr, rowval, nzval)
}

/// Triplets → CSC (column-major, rows sorted, duplicates summed).
pub(crate) fn triplets_csc(m: usize, n: usize, mut t: Vec<(usize, usize, f64)>) -> CscMatrix<f64> {
    t.sort_by_key(|a| (a.1, a.0));
    let mut colptr = vec![0usize; n + 1];
    let mut rowval: Vec<usize> = Vec::with_capacity(t.len());
    let mut nzval: Vec<f64> = Vec::with_capacity(t.len());
    let mut last: Option<(usize, usize)> = None;
    for (i, j, v) in t {
        if last == Some((i, j)) {
            if let Some(x) = nzval.last_mut() {
                *x += v;
            }
            continue;
        }
        last = Some((i, j));
        rowval.push(i);
        nzval.push(v);
        colptr[j + 1] += 1;
    }
    for j in 0..n {
        colptr[j + 1] += colptr[j];
    }
    CscMatrix::new(m, n, colptr, rowval, nzval)
}

/// Box and rate bounds of one input sequence: lo ≤ u_k ≤ hi, |u_k − u_{k−1}| ≤ rate,
/// u_{−1} = prev.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RateBox {
    /// Lower bound.
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
    /// Rate bound per step.
    pub rate: f64,
    /// The last applied value (clamped into [lo, hi] by the users).
    pub prev: f64,
}

/// Appends the 4T rows of box and rate constraints on variables `offset..offset+t` to a
/// triplet list and right-hand side (all of the form row·x ≤ b).
pub(crate) fn box_rate_rows(
    trip: &mut Vec<(usize, usize, f64)>,
    rhs: &mut Vec<f64>,
    offset: usize,
    t: usize,
    bx: RateBox,
) {
    let RateBox { lo, hi, rate, prev } = bx;
    let row0 = rhs.len();
    for k in 0..t {
        trip.push((row0 + k, offset + k, 1.0));
        rhs.push(hi);
    }
    for k in 0..t {
        trip.push((row0 + t + k, offset + k, -1.0));
        rhs.push(-lo);
    }
    for k in 0..t {
        trip.push((row0 + 2 * t + k, offset + k, 1.0));
        if k > 0 {
            trip.push((row0 + 2 * t + k, offset + k - 1, -1.0));
        }
        rhs.push(if k == 0 { rate + prev } else { rate });
    }
    for k in 0..t {
        trip.push((row0 + 3 * t + k, offset + k, -1.0));
        if k > 0 {
            trip.push((row0 + 3 * t + k, offset + k - 1, 1.0));
        }
        rhs.push(if k == 0 { rate - prev } else { rate });
    }
}

/// Projects `u` onto {lo ≤ u_k ≤ hi, |u_k − u_{k−1}| ≤ rate} sequentially (always feasible
/// when `prev` ∈ [lo, hi]); removes Clarabel's interior-point rounding so bounds hold exactly.
pub(crate) fn repair_box_rate(u: &mut [f64], bx: RateBox) {
    let RateBox { lo, hi, rate, prev } = bx;
    let mut p = prev.clamp(lo, hi);
    for x in u.iter_mut() {
        let l = lo.max(p - rate);
        let h = hi.min(p + rate);
        *x = x.clamp(l, h);
        p = *x;
    }
}

/// Is a status a usable solution?
pub(crate) fn usable(status: SolverStatus) -> bool {
    matches!(status, SolverStatus::Solved | SolverStatus::AlmostSolved)
}

/// A Clarabel QP whose P, A, b are fixed and whose q is updated per solve, with the
/// equilibration-off retry.
pub(crate) struct BoxRateQp {
    name: QpName,
    solver: DefaultSolver<f64>,
    p: CscMatrix<f64>,
    a: CscMatrix<f64>,
    b: Vec<f64>,
    cones: Vec<SupportedConeT<f64>>,
    retried: bool,
    bx: RateBox,
    qbuf: Vec<f64>,
    /// Number of Clarabel solves (retries included).
    pub solves: usize,
}

impl BoxRateQp {
    /// Builds the solver for Hessian `p_dense` (`[t, t]` row-major, symmetric).
    pub(crate) fn new(
        name: QpName,
        p_dense: &[f64],
        t: usize,
        bx: RateBox,
    ) -> Result<Self, QpFailure> {
        let bx = RateBox {
            prev: bx.prev.clamp(bx.lo, bx.hi),
            ..bx
        };
        let p = upper_csc(p_dense, t);
        let mut trip = Vec::with_capacity(6 * t);
        let mut b = Vec::with_capacity(4 * t);
        box_rate_rows(&mut trip, &mut b, 0, t, bx);
        let a = triplets_csc(4 * t, t, trip);
        let cones = vec![NonnegativeConeT(4 * t)];
        let q = vec![0.0; t];
        let solver = DefaultSolver::new(&p, &q, &a, &b, &cones, clarabel_settings(true))
            .map_err(|e| QpFailure::setup(name, 0, &e))?;
        Ok(Self {
            name,
            solver,
            p,
            a,
            b,
            cones,
            retried: false,
            bx,
            qbuf: q,
            solves: 0,
        })
    }

    /// Solves with linear term `q`, writing the (exactly feasible) minimiser into `out`.
    pub(crate) fn solve(
        &mut self,
        q: &[f64],
        out: &mut [f64],
        iteration: usize,
    ) -> Result<(), QpFailure> {
        self.qbuf.copy_from_slice(q);
        self.solver
            .update_q(&self.qbuf)
            .map_err(|e| QpFailure::setup(self.name, iteration, &e))?;
        self.solver.solve();
        self.solves += 1;
        let mut status = self.solver.solution.status;
        if !usable(status) && !self.retried {
            // Known small-QP trouble with equilibration: rebuild once without it and keep that
            // solver for the rest of the MPC call.
            self.retried = true;
            self.solver = DefaultSolver::new(
                &self.p,
                q,
                &self.a,
                &self.b,
                &self.cones,
                clarabel_settings(false),
            )
            .map_err(|e| QpFailure::setup(self.name, iteration, &e))?;
            self.solver.solve();
            self.solves += 1;
            status = self.solver.solution.status;
        }
        if !usable(status) {
            return Err(QpFailure {
                qp: self.name,
                iteration,
                status: status.into(),
                detail: None,
            });
        }
        out.copy_from_slice(&self.solver.solution.x);
        repair_box_rate(out, self.bx);
        Ok(())
    }
}

/// The equality cone constructor re-exported for the joint QP.
pub(crate) fn zero_cone(m: usize) -> SupportedConeT<f64> {
    ZeroConeT(m)
}
