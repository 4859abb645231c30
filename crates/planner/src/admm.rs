//! The ADMM MPC of the paper's Algorithm 1: Δ- and α-updates as Clarabel QPs, the Z-update as
//! projected gradient descent whose every trial point is checked by the predictor, the dual
//! update, warm starts across calls.

use std::time::Instant;

use nudge_predictor::{History, Predictor, T_OBS};
use serde::{Deserialize, Serialize};

use crate::error::PlannerError;
use crate::model::{Bicycle, Linearisation, State};
use crate::qp::{
    BoxRateQp, RateBox, box_rate_rows, clarabel_settings, triplets_csc, upper_csc, usable,
    zero_cone,
};
use crate::safety::{Ellipse, motion_direction};
use crate::settings::PlannerSettings;

/// The ego's measured state in the road frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EgoState {
    /// Longitudinal position of the centre of gravity (m).
    pub x: f64,
    /// Lateral position (m, positive left).
    pub y: f64,
    /// Heading (rad, 0 = along the road, positive left).
    pub psi: f64,
    /// Speed (m/s).
    pub v: f64,
}

/// Everything one MPC call needs besides the settings and the predictor.
#[derive(Debug, Clone, Copy)]
pub struct PlanningProblem<'a> {
    /// The ego's current state.
    pub ego: EgoState,
    /// Steering applied at the previous step δ_{−1} (rad).
    pub last_delta: f64,
    /// Acceleration applied at the previous step a_{−1} (m/s²).
    pub last_accel: f64,
    /// Observed positions `[n, T_OBS, 2]`, agent 0 = ego (its last entry should be the ego's
    /// current position).
    pub history: &'a History,
    /// Vehicle sizes `[n]` of (length, width) (m), agent 0 = ego.
    pub sizes: &'a [[f64; 2]],
    /// Lateral target y (m): the target lane's centre.
    pub y_target: f64,
    /// Reference speed (m/s).
    pub v_ref: f64,
    /// Road edges (right, left) as lateral y (m), right < left.
    pub road: [f64; 2],
}

/// How an MPC call ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum PlanStatus {
    /// ‖F‖∞ ≤ eps_primal and ‖Z − Z_prev‖∞ ≤ eps_change; the plan is safe.
    Converged,
    /// `max_iter` reached; the plan is safe (every accepted Z is).
    MaxIterations,
    /// The states could not be made safe (feasibility restoration failed); the plan is the
    /// least-violating one found.
    Unsafe,
    /// The roll-out of the ADMM inputs was unsafe (Z sat on the constraint boundary, or ADMM
    /// stopped before F ≈ 0); the plan is the ADMM inputs pulled towards the shifted previous
    /// plan (by 3/4, 1/2 or 1/4) until the roll-out was safe, and that roll-out.
    Backtracked,
    /// The roll-out of the ADMM inputs was unsafe and backtracking did not help; the plan is
    /// the cheapest safe (else the least-violating) simple input sequence and its roll-out.
    Fallback,
}

/// Wall-clock time of each ADMM phase over one MPC call.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PhaseTimings {
    /// All Δ-updates (s).
    pub delta_s: f64,
    /// All α-updates (s).
    pub alpha_s: f64,
    /// All Z-updates (s).
    pub z_s: f64,
    /// Each Z-update (s), in order.
    pub z_updates_s: Vec<f64>,
    /// The whole call, set-up included (s).
    pub total_s: f64,
}

/// The result of one MPC call.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Steering δ_0..δ_{T−1} (rad), `[T]`.
    pub delta: Vec<f64>,
    /// Acceleration a_0..a_{T−1} (m/s²), `[T]`.
    pub accel: Vec<f64>,
    /// Planned states z_1..z_T as (x, y, ψ, v) in the road frame, `[T]`.
    pub states: Vec<[f64; 4]>,
    /// Cost J = Φ1 + Φ2 + Φ3 at the returned (Δ, α, Z).
    pub cost: f64,
    /// ADMM iterations run.
    pub iterations: usize,
    /// Predictor calls (one candidate each).
    pub predictor_calls: usize,
    /// Clarabel solves (retries included).
    pub qp_solves: usize,
    /// Final primal residual ‖F(Δ, α, Z)‖∞.
    pub primal_residual: f64,
    /// Final change residual ‖Z − Z_prev‖∞.
    pub change_residual: f64,
    /// Minimum b_i over checked vehicles and steps under the predictor's prediction of the
    /// returned states (`None` when no vehicle is checked).
    pub min_safety: Option<f64>,
    /// Minimum b_i under the predictor's prediction of the nonlinear roll-out of the returned
    /// (Δ, α) from the measured state (what the vehicle will actually do); `None` when no
    /// vehicle is checked.
    pub rollout_min_safety: Option<f64>,
    /// Number of vehicles checked (within `check_range`).
    pub checked: usize,
    /// Phase timings.
    pub timings: PhaseTimings,
    /// How the call ended.
    pub status: PlanStatus,
}

/// The solution of the linearised problem as one joint QP (no safety constraint).
#[derive(Debug, Clone, PartialEq)]
pub struct JointSolution {
    /// Steering `[T]` (rad).
    pub delta: Vec<f64>,
    /// Acceleration `[T]` (m/s²).
    pub accel: Vec<f64>,
    /// States z_1..z_T in the road frame, `[T]`.
    pub states: Vec<[f64; 4]>,
    /// Cost J at the solution.
    pub cost: f64,
}

/// Warm-start data kept between calls.
#[derive(Debug, Clone)]
struct Warm {
    delta: Vec<f64>,
    accel: Vec<f64>,
    mu: Vec<State>,
}

/// The ADMM MPC planner. Keeps the previous solution to warm-start the next call; call
/// [`Planner::reset`] between unrelated runs.
#[derive(Debug, Clone)]
pub struct Planner {
    settings: PlannerSettings,
    model: Bicycle,
    warm: Option<Warm>,
}

/// The per-call set-up shared by [`Planner::plan`] and [`Planner::reference_qp`].
struct Setup {
    t: usize,
    origin: [f64; 2],
    z0: State,
    lin: Linearisation,
    nom_delta: Vec<f64>,
    nom_accel: Vec<f64>,
    roll: Vec<State>,
    mu: Vec<State>,
    /// Per-step weights (0, w_y, w_ψ, w_v) on (x, y, ψ, v).
    wdiag: State,
    /// Reference state (x ignored).
    zref: State,
    /// Lower and upper state bounds (x, ψ unbounded).
    zlo: State,
    zhi: State,
    dbox: RateBox,
    abox: RateBox,
}

fn shift(v: &[f64]) -> Vec<f64> {
    let mut s: Vec<f64> = v.iter().skip(1).copied().collect();
    s.push(*v.last().unwrap_or(&0.0));
    s
}

fn amax(v: &[State]) -> f64 {
    v.iter().map(|s| s.amax()).fold(0.0, f64::max)
}

/// Φ1 or Φ2 of an input sequence: w Σu² + w_d Σ(u_k − u_{k−1})².
fn input_cost(u: &[f64], prev: f64, w: f64, wd: f64) -> f64 {
    let mut p = prev;
    let mut c = 0.0;
    for &x in u {
        c += w * x * x + wd * (x - p) * (x - p);
        p = x;
    }
    c
}

/// Hessian (`[t, t]` row-major) of w Σu² + w_d Σ(u_k − u_{k−1})², plus `extra` on the
/// diagonal.
fn input_hessian(t: usize, w: f64, wd: f64, extra: &[f64]) -> Vec<f64> {
    let mut p = vec![0.0; t * t];
    for k in 0..t {
        let dd = 1.0 + if k + 1 < t { 1.0 } else { 0.0 };
        p[k * t + k] = 2.0 * (w + wd * dd) + extra[k];
        if k + 1 < t {
            p[k * t + k + 1] = -2.0 * wd;
            p[(k + 1) * t + k] = -2.0 * wd;
        }
    }
    p
}

impl Planner {
    /// A planner with validated settings.
    ///
    /// # Errors
    /// [`PlannerError::Settings`] when `settings.validate()` fails.
    pub fn new(settings: PlannerSettings) -> Result<Self, PlannerError> {
        settings.validate()?;
        let model = Bicycle {
            l_f: settings.l_f,
            l_r: settings.l_r,
            dt: settings.dt,
        };
        Ok(Self {
            settings,
            model,
            warm: None,
        })
    }

    /// The settings in use.
    #[must_use]
    pub fn settings(&self) -> &PlannerSettings {
        &self.settings
    }

    /// The bicycle model in use.
    #[must_use]
    pub fn model(&self) -> &Bicycle {
        &self.model
    }

    /// Forgets the warm start (the next call starts from a constant-velocity roll-out).
    pub fn reset(&mut self) {
        self.warm = None;
    }

    fn check_problem(&self, p: &PlanningProblem<'_>) -> Result<(), PlannerError> {
        let bad =
            |field: &'static str, reason: String| Err(PlannerError::BadProblem { field, reason });
        let e = p.ego;
        for (field, v) in [
            ("ego.x", e.x),
            ("ego.y", e.y),
            ("ego.psi", e.psi),
            ("ego.v", e.v),
            ("last_delta", p.last_delta),
            ("last_accel", p.last_accel),
            ("y_target", p.y_target),
            ("v_ref", p.v_ref),
            ("road", p.road[0]),
            ("road", p.road[1]),
        ] {
            if !v.is_finite() {
                return bad(field, format!("non-finite value {v}"));
            }
        }
        if e.v < 0.0 {
            return bad("ego.v", format!("negative speed {}", e.v));
        }
        if e.psi.abs() > std::f64::consts::FRAC_PI_2 {
            return bad(
                "ego.psi",
                format!("heading {} rad points off the road", e.psi),
            );
        }
        if p.road[0] >= p.road[1] {
            return bad(
                "road",
                format!(
                    "right edge {} is not below left edge {}",
                    p.road[0], p.road[1]
                ),
            );
        }
        let n = p.history.n_agents();
        if p.sizes.len() != n {
            return bad("sizes", format!("{} sizes for {n} agents", p.sizes.len()));
        }
        for (i, s) in p.sizes.iter().enumerate() {
            if !(s[0].is_finite() && s[1].is_finite() && s[0] > 0.0 && s[1] > 0.0) {
                return bad("sizes", format!("agent {i} has size {s:?}"));
            }
        }
        Ok(())
    }

    fn setup(&self, p: &PlanningProblem<'_>) -> Setup {
        let s = &self.settings;
        let t = s.horizon;
        let origin = [p.ego.x, p.ego.y];
        let z0 = State::new(0.0, 0.0, p.ego.psi, p.ego.v);
        let dbox = RateBox {
            lo: -s.delta_max,
            hi: s.delta_max,
            rate: s.ddelta_max,
            prev: p.last_delta.clamp(-s.delta_max, s.delta_max),
        };
        let abox = RateBox {
            lo: s.a_min,
            hi: s.a_max,
            rate: s.da_max,
            prev: p.last_accel.clamp(s.a_min, s.a_max),
        };
        let (mut nom_delta, mut nom_accel, mu) = match &self.warm {
            Some(w) if w.delta.len() == t => {
                let mut mu: Vec<State> = w.mu.iter().skip(1).copied().collect();
                mu.push(*w.mu.last().unwrap_or(&State::zeros()));
                if !s.warm_start_dual {
                    mu.iter_mut().for_each(|m| *m = State::zeros());
                }
                (shift(&w.delta), shift(&w.accel), mu)
            }
            _ => (vec![0.0; t], vec![0.0; t], vec![State::zeros(); t]),
        };
        crate::qp::repair_box_rate(&mut nom_delta, dbox);
        crate::qp::repair_box_rate(&mut nom_accel, abox);
        let mut roll = vec![State::zeros(); t];
        rollout_clamped(&self.model, &z0, &nom_delta, &nom_accel, &mut roll);
        let mut nominal = Vec::with_capacity(t);
        nominal.push(z0);
        nominal.extend_from_slice(&roll[..t - 1]);
        let lin = Linearisation::new(
            &self.model,
            &z0,
            &nominal,
            &nom_delta,
            &nom_accel,
            s.v_lin_min,
        );
        let half_w = 0.5 * p.sizes[0][1] + s.edge_margin;
        let mut ylo = p.road[0] + half_w - origin[1];
        let mut yhi = p.road[1] - half_w - origin[1];
        if ylo > yhi {
            let mid = 0.5 * (ylo + yhi);
            ylo = mid;
            yhi = mid;
        }
        // The ego may start slightly outside the band (data noise): widen to include it.
        ylo = ylo.min(0.0);
        yhi = yhi.max(0.0);
        Setup {
            t,
            origin,
            z0,
            lin,
            nom_delta,
            nom_accel,
            roll,
            mu,
            wdiag: State::new(0.0, s.w_y, s.w_psi, s.w_v),
            zref: State::new(0.0, p.y_target - origin[1], 0.0, p.v_ref),
            zlo: State::new(f64::NEG_INFINITY, ylo, f64::NEG_INFINITY, 0.0),
            zhi: State::new(f64::INFINITY, yhi, f64::INFINITY, s.v_max.max(p.ego.v)),
            dbox,
            abox,
        }
    }

    fn phi3(su: &Setup, z: &[State]) -> f64 {
        z.iter()
            .map(|zk| {
                let e = zk - su.zref;
                su.wdiag[1] * e[1] * e[1] + su.wdiag[2] * e[2] * e[2] + su.wdiag[3] * e[3] * e[3]
            })
            .sum()
    }

    fn cost(&self, su: &Setup, delta: &[f64], accel: &[f64], z: &[State]) -> f64 {
        let s = &self.settings;
        input_cost(delta, su.dbox.prev, s.w_delta, s.w_ddelta)
            + input_cost(accel, su.abox.prev, s.w_a, s.w_da)
            + Self::phi3(su, z)
    }

    fn to_world(su: &Setup, z: &[State]) -> Vec<[f64; 4]> {
        z.iter()
            .map(|s| [s[0] + su.origin[0], s[1] + su.origin[1], s[2], s[3]])
            .collect()
    }

    /// Solves one MPC call (Algorithm 1) and stores the solution as the next warm start.
    ///
    /// # Errors
    /// [`PlannerError::BadProblem`] for a malformed problem, [`PlannerError::HorizonMismatch`]
    /// when the predictor's horizon differs, [`PlannerError::Predictor`] when the predictor
    /// rejects the scene, [`PlannerError::QpSetup`] / [`PlannerError::QpFailed`] when Clarabel
    /// fails (also after the equilibration-off retry).
    pub fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        let start = Instant::now();
        self.check_problem(problem)?;
        let s = self.settings.clone();
        if predictor.horizon() != s.horizon {
            return Err(PlannerError::HorizonMismatch {
                predictor: predictor.horizon(),
                planner: s.horizon,
            });
        }
        let su = self.setup(problem);
        let t = su.t;
        let lin = &su.lin;
        let n = problem.history.n_agents();

        // Checked vehicles: size, last observed position and heading direction from the last
        // observed motion (used when a predicted step shows too little forward motion).
        let ego_size = problem.sizes[0];
        let mut checked: Vec<CheckedVehicle> = Vec::new();
        for i in 1..n {
            let p = problem.history.at(i, T_OBS - 1);
            let d = ((p[0] - su.origin[0]).powi(2) + (p[1] - su.origin[1]).powi(2)).sqrt();
            if d <= s.check_range {
                let q = problem.history.at(i, T_OBS - 2);
                checked.push(CheckedVehicle {
                    index: i,
                    size: problem.sizes[i],
                    last: [p[0], p[1]],
                    dir: motion_direction([q[0], q[1]], [p[0], p[1]], [1.0, 0.0]),
                });
            }
        }
        if !checked.is_empty() {
            predictor.set_scene(problem.history)?;
        }

        // Iterates and buffers (allocated once per call).
        let mut delta = su.nom_delta.clone();
        let mut accel = su.nom_accel.clone();
        let mut z: Vec<State> = su
            .roll
            .iter()
            .map(|r| r.sup(&su.zlo).inf(&su.zhi))
            .collect();
        let mut mu = su.mu.clone();
        let mut f = vec![State::zeros(); t];
        let mut w = vec![State::zeros(); t];
        let mut grad = vec![State::zeros(); t];
        let mut trial = vec![State::zeros(); t];
        let mut best = vec![State::zeros(); t];
        let mut z_prev = vec![State::zeros(); t];
        let mut q = vec![0.0; t];
        let mut sol = vec![0.0; t];
        // The Z-update's tightened threshold.
        let zmin = s.safety_min + s.plan_buffer;
        let mut safety = SafetyEval {
            cand: vec![0.0; t * 2],
            out: vec![0.0; (n - 1) * t * 2],
            rgrad: vec![[0.0; 2]; t],
            calls: 0,
            origin: su.origin,
            horizon: t,
            checked: &checked,
            ego_size,
            ego_dir: vec![[1.0, 0.0]; t],
            scale: s.ellipse_scale,
            margins: [s.margin_x, s.margin_y],
            safety_min: zmin,
        };

        // QPs: Hessians fixed for this call.
        let a_diag: Vec<f64> = lin.jd.iter().map(|g| s.rho * g.norm_squared()).collect();
        let p_delta = input_hessian(t, s.w_delta, s.w_ddelta, &a_diag);
        let b_diag = vec![s.rho * lin.ja.norm_squared(); t];
        let p_accel = input_hessian(t, s.w_a, s.w_da, &b_diag);
        let mut qp_delta = BoxRateQp::new("delta", &p_delta, t, su.dbox)?;
        let mut qp_accel = BoxRateQp::new("alpha", &p_accel, t, su.abox)?;

        // H = 2W + ρCᵀC (constant this call): Gershgorin bound L for the 1/L gradient step,
        // and H⁻¹ for the Hessian-scaled step.
        let m4 = 4 * t;
        let (lip, hinv, hinv_pin) = {
            let c = lin.dense_c();
            let mut h = nalgebra::DMatrix::<f64>::zeros(m4, m4);
            for i in 0..m4 {
                for j in 0..m4 {
                    let mut v: f64 = (0..m4).map(|r| c[r * m4 + i] * c[r * m4 + j]).sum();
                    v *= s.rho;
                    if i == j {
                        v += 2.0 * su.wdiag[i % 4];
                    }
                    h[(i, j)] = v;
                }
            }
            let lip = (0..m4)
                .map(|i| (0..m4).map(|j| h[(i, j)].abs()).sum::<f64>())
                .fold(0.0, f64::max)
                .max(1e-9);
            let flat_inverse = |m: nalgebra::DMatrix<f64>| {
                m.cholesky().map(|ch| {
                    let inv = ch.inverse();
                    (0..m4 * m4)
                        .map(|k| inv[(k / m4, k % m4)])
                        .collect::<Vec<f64>>()
                })
            };
            if s.hessian_scaled {
                // H_pin = H + w_pin·P (P selects positions): minimising G plus a pull of the
                // positions towards a target keeps the states dynamically consistent.
                let mut hp = h.clone();
                for k in 0..t {
                    hp[(4 * k, 4 * k)] += s.pin_weight;
                    hp[(4 * k + 1, 4 * k + 1)] += s.pin_weight;
                }
                (lip, flat_inverse(h), flat_inverse(hp))
            } else {
                (lip, None, None)
            }
        };
        let mut dirp = vec![State::zeros(); t];
        let mut rhs = vec![State::zeros(); t];
        let mut dirn = vec![State::zeros(); t];
        let mut cur_rgrad = vec![[0.0; 2]; t];
        let mut best_rgrad = vec![[0.0; 2]; t];

        let (mut cur_min_b, mut cur_viol) = safety.eval(predictor, &z)?;
        cur_rgrad.copy_from_slice(&safety.rgrad);
        let mut timings = PhaseTimings::default();
        let mut status = PlanStatus::MaxIterations;
        let mut iterations = 0;
        let mut change = f64::INFINITY;
        for it in 0..s.max_iter {
            iterations = it + 1;
            // Δ-update: q = q1 + Aᵀ(μ + ρ(F − AΔ)).
            let t0 = Instant::now();
            lin.residual(&delta, &accel, &z, &mut f);
            for k in 0..t {
                let wk = mu[k] + s.rho * (f[k] - lin.jd[k] * delta[k]);
                q[k] = lin.jd[k].dot(&wk);
            }
            q[0] -= 2.0 * s.w_ddelta * su.dbox.prev;
            qp_delta.solve(&q, &mut sol, it)?;
            delta.copy_from_slice(&sol);
            timings.delta_s += t0.elapsed().as_secs_f64();

            // α-update.
            let t0 = Instant::now();
            lin.residual(&delta, &accel, &z, &mut f);
            for k in 0..t {
                let wk = mu[k] + s.rho * (f[k] - lin.ja * accel[k]);
                q[k] = lin.ja.dot(&wk);
            }
            q[0] -= 2.0 * s.w_da * su.abox.prev;
            qp_accel.solve(&q, &mut sol, it)?;
            accel.copy_from_slice(&sol);
            timings.alpha_s += t0.elapsed().as_secs_f64();

            // Z-update: projected gradient descent on G with safety-checked trial points.
            let t0 = Instant::now();
            z_prev.copy_from_slice(&z);
            let gval = |zz: &[State], f: &mut [State]| -> f64 {
                lin.residual(&delta, &accel, zz, f);
                let mut g = Self::phi3(&su, zz);
                for k in 0..t {
                    g += mu[k].dot(&f[k]) + 0.5 * s.rho * f[k].norm_squared();
                }
                g
            };
            let mut g_cur = gval(&z, &mut f);
            for _ in 0..s.pgd_steps {
                // ∇G = 2W(Z − Zref) + Cᵀ(μ + ρF), F at the current Z (in f).
                for k in 0..t {
                    w[k] = mu[k] + s.rho * f[k];
                }
                lin.apply_ct(&w, &mut grad);
                for k in 0..t {
                    let e = z[k] - su.zref;
                    grad[k] += 2.0 * su.wdiag.component_mul(&e);
                }
                // Trial directions (Z⁺ = Π(Z − η·d)):
                // * Newton d = H⁻¹∇G, η = 1, 1/2, ... (η = 1 is G's exact minimiser when no
                //   bound is active);
                // * pinned Newton d = H_pin⁻¹∇G, η = 1: minimises G while holding the
                //   positions near the current (safe) ones, so ψ and v become consistent;
                // * plain gradient d = ∇G, η = 1/L, 1/(2L), ... when Hessian scaling is off.
                if let Some(hi) = hinv.as_ref() {
                    mat_vec(hi, &grad, &mut dirn);
                }
                if let Some(hp) = hinv_pin.as_ref() {
                    mat_vec(hp, &grad, &mut dirp);
                }
                let safe_now = cur_min_b.is_none_or(|b| b > zmin);
                let mut moved = false;
                if safe_now {
                    let mut tries: [(u8, f64); 3] = [(0, 1.0), (1, 1.0), (2, 1.0 / lip)];
                    let list: &mut [(u8, f64)] = if hinv.is_some() {
                        &mut tries[..2]
                    } else {
                        &mut tries[2..]
                    };
                    'dirs: for (kind, eta0) in list.iter_mut() {
                        let dir = match kind {
                            0 => &dirn,
                            1 => &dirp,
                            _ => &grad,
                        };
                        let halvings = if *kind == 1 { 0 } else { s.pgd_halvings };
                        let mut eta = *eta0;
                        for _ in 0..=halvings {
                            project_step(&z, dir, eta, &su, &mut trial);
                            if max_diff(&trial, &z) < 1e-12 {
                                if *kind == 1 {
                                    continue 'dirs;
                                }
                                break 'dirs;
                            }
                            let g_t = gval(&trial, &mut w);
                            if g_t < g_cur {
                                let (mb, _) = safety.eval(predictor, &trial)?;
                                if mb.is_none_or(|b| b > zmin) {
                                    z.copy_from_slice(&trial);
                                    g_cur = g_t;
                                    cur_min_b = mb;
                                    cur_viol = 0.0;
                                    moved = true;
                                    break 'dirs;
                                }
                            }
                            eta *= 0.5;
                        }
                    }
                } else {
                    // Feasibility restoration: among Newton trials and pinned-Newton moves
                    // whose position target is pushed along the violation's descent direction
                    // (prediction frozen), take the one that most reduces the total violation.
                    let mut best_viol = cur_viol;
                    let mut best_b = cur_min_b;
                    let mut found = false;
                    let rmax = cur_rgrad
                        .iter()
                        .map(|g| g[0].abs().max(g[1].abs()))
                        .fold(0.0, f64::max);
                    let mut eta = if hinv.is_some() { 1.0 } else { 1.0 / lip };
                    let mut step = s.restore_step;
                    for _ in 0..=s.pgd_halvings {
                        for kind in 0..2 {
                            if kind == 0 {
                                let dir = if hinv.is_some() { &dirn } else { &grad };
                                project_step(&z, dir, eta, &su, &mut trial);
                            } else {
                                if rmax <= 0.0 || !rmax.is_finite() {
                                    continue;
                                }
                                // Target p* = p − step·∇V/max|∇V|.
                                rhs.copy_from_slice(&grad);
                                for (r, g) in rhs.iter_mut().zip(&cur_rgrad) {
                                    r[0] += s.pin_weight * step * g[0] / rmax;
                                    r[1] += s.pin_weight * step * g[1] / rmax;
                                }
                                if let Some(hp) = hinv_pin.as_ref() {
                                    mat_vec(hp, &rhs, &mut dirp);
                                    project_step(&z, &dirp, 1.0, &su, &mut trial);
                                } else {
                                    for k in 0..t {
                                        trial[k] = z[k];
                                        trial[k][0] -= step * cur_rgrad[k][0] / rmax;
                                        trial[k][1] -= step * cur_rgrad[k][1] / rmax;
                                        trial[k] = trial[k].sup(&su.zlo).inf(&su.zhi);
                                    }
                                }
                            }
                            let (mb, viol) = safety.eval(predictor, &trial)?;
                            if viol < best_viol {
                                best_viol = viol;
                                best_b = mb;
                                best.copy_from_slice(&trial);
                                best_rgrad.copy_from_slice(&safety.rgrad);
                                found = true;
                            }
                        }
                        eta *= 0.5;
                        step *= 0.5;
                    }
                    if found {
                        z.copy_from_slice(&best);
                        cur_viol = best_viol;
                        cur_min_b = best_b;
                        cur_rgrad.copy_from_slice(&best_rgrad);
                        moved = true;
                    }
                }
                if !moved {
                    break;
                }
                g_cur = gval(&z, &mut f);
            }
            let dz = t0.elapsed().as_secs_f64();
            timings.z_s += dz;
            timings.z_updates_s.push(dz);

            // Dual update and convergence.
            lin.residual(&delta, &accel, &z, &mut f);
            for k in 0..t {
                mu[k] += s.rho * f[k];
            }
            let primal = amax(&f);
            change = max_diff(&z, &z_prev);
            if primal <= s.eps_primal && change <= s.eps_change {
                status = PlanStatus::Converged;
                break;
            }
        }
        lin.residual(&delta, &accel, &z, &mut f);
        let primal = amax(&f);
        let safe_final = cur_min_b.is_none_or(|b| b > s.safety_min);
        if !safe_final {
            status = PlanStatus::Unsafe;
        }
        // Execution check: the vehicle follows the nonlinear roll-out of (Δ, α), not Z. When
        // ADMM stopped before F ≈ 0 the two differ, and Z tends to sit on the constraint
        // boundary, so the roll-out can dip below it. Then (1) backtrack: pull (Δ, α) towards
        // the nominal (the shifted previous plan) by θ = 3/4, 1/2, 1/4 and take the first safe
        // roll-out; else (2) fall back to the cheapest safe (else the least-violating) of a few
        // simple input sequences (the nominal, steering straight with constant
        // accelerations, and steering towards the lateral goal with those accelerations).
        let mut rollout = vec![State::zeros(); t];
        rollout_clamped(&self.model, &su.z0, &delta, &accel, &mut rollout);
        let (mut rollout_min_b, rviol) = safety.eval(predictor, &rollout)?;
        let is_safe = |b: Option<f64>| b.is_none_or(|b| b > s.safety_min);
        if s.rollout_check && !is_safe(rollout_min_b) {
            let mut chosen: Option<Repair> = None;
            for theta in [0.75, 0.5, 0.25] {
                let mix = |u: &[f64], nom: &[f64]| -> Vec<f64> {
                    u.iter()
                        .zip(nom)
                        .map(|(u, n)| n + theta * (u - n))
                        .collect()
                };
                let mut d = mix(&delta, &su.nom_delta);
                let mut a = mix(&accel, &su.nom_accel);
                crate::qp::repair_box_rate(&mut d, su.dbox);
                crate::qp::repair_box_rate(&mut a, su.abox);
                rollout_clamped(&self.model, &su.z0, &d, &a, &mut trial);
                let (mb, _) = safety.eval(predictor, &trial)?;
                if is_safe(mb) {
                    chosen = Some((d, a, mb, PlanStatus::Backtracked));
                    break;
                }
            }
            if chosen.is_none() {
                let mut cands = vec![(su.nom_delta.clone(), su.nom_accel.clone())];
                let mut straight = vec![0.0; t];
                crate::qp::repair_box_rate(&mut straight, su.dbox);
                for a_cmd in [0.0, 0.5 * s.a_min, s.a_min, 0.5 * s.a_max] {
                    let mut a = vec![a_cmd; t];
                    crate::qp::repair_box_rate(&mut a, su.abox);
                    cands.push((straight.clone(), a.clone()));
                    let d = steer_towards(&self.model, &su.z0, &a, su.zref[1], su.dbox);
                    cands.push((d, a));
                }
                // (safe, cost or violation) of the best candidate so far.
                let mut best_key = (false, rviol);
                for (d, a) in cands {
                    rollout_clamped(&self.model, &su.z0, &d, &a, &mut trial);
                    let (mb, viol) = safety.eval(predictor, &trial)?;
                    let key = if is_safe(mb) {
                        (true, self.cost(&su, &d, &a, &trial))
                    } else {
                        (false, viol)
                    };
                    let better = match (key.0, best_key.0) {
                        (true, false) => true,
                        (false, true) => false,
                        _ => key.1 < best_key.1,
                    };
                    if better {
                        best_key = key;
                        chosen = Some((d, a, mb, PlanStatus::Fallback));
                    }
                }
            }
            if let Some((d, a, mb, st)) = chosen {
                delta = d;
                accel = a;
                rollout_clamped(&self.model, &su.z0, &delta, &accel, &mut z);
                cur_min_b = mb;
                rollout_min_b = mb;
                status = st;
                lin.residual(&delta, &accel, &z, &mut f);
            }
        }
        let primal = if matches!(status, PlanStatus::Fallback | PlanStatus::Backtracked) {
            amax(&f)
        } else {
            primal
        };
        let cost = self.cost(&su, &delta, &accel, &z);
        self.warm = Some(Warm {
            delta: delta.clone(),
            accel: accel.clone(),
            mu,
        });
        timings.total_s = start.elapsed().as_secs_f64();
        Ok(Plan {
            states: Self::to_world(&su, &z),
            delta,
            accel,
            cost,
            iterations,
            predictor_calls: safety.calls,
            qp_solves: qp_delta.solves + qp_accel.solves,
            primal_residual: primal,
            change_residual: change,
            min_safety: cur_min_b,
            rollout_min_safety: rollout_min_b,
            checked: checked.len(),
            timings,
            status,
        })
    }

    /// Solves the linearised problem this planner's next [`Planner::plan`] call would set up
    /// (same nominal, same warm start) as ONE Clarabel QP in (Δ, α, Z), without the safety
    /// constraint. With no vehicle in range, ADMM converges to this solution.
    ///
    /// # Errors
    /// As [`Planner::plan`] for a malformed problem; [`PlannerError::QpFailed`] (qp `"joint"`)
    /// when Clarabel does not solve it.
    pub fn reference_qp(
        &self,
        problem: &PlanningProblem<'_>,
    ) -> Result<JointSolution, PlannerError> {
        self.check_problem(problem)?;
        let s = &self.settings;
        let su = self.setup(problem);
        let t = su.t;
        let lin = &su.lin;
        let nv = 6 * t;
        // Objective.
        let mut p = vec![0.0; nv * nv];
        let pd = input_hessian(t, s.w_delta, s.w_ddelta, &vec![0.0; t]);
        let pa = input_hessian(t, s.w_a, s.w_da, &vec![0.0; t]);
        for i in 0..t {
            for j in 0..t {
                p[i * nv + j] = pd[i * t + j];
                p[(t + i) * nv + t + j] = pa[i * t + j];
            }
        }
        let mut q = vec![0.0; nv];
        q[0] = -2.0 * s.w_ddelta * su.dbox.prev;
        q[t] = -2.0 * s.w_da * su.abox.prev;
        for k in 0..t {
            for j in 0..4 {
                let idx = 2 * t + 4 * k + j;
                p[idx * nv + idx] = 2.0 * su.wdiag[j];
                q[idx] = -2.0 * su.wdiag[j] * su.zref[j];
            }
        }
        let pm = upper_csc(&p, nv);
        // Constraints: dynamics (equalities), then box/rate on Δ, α, then state bounds.
        let mut trip = Vec::new();
        let mut b = Vec::new();
        let (da, db, dc) = (lin.dense_a(), lin.dense_b(), lin.dense_c());
        let m4 = 4 * t;
        for r in 0..m4 {
            for c in 0..t {
                if da[r * t + c] != 0.0 {
                    trip.push((r, c, da[r * t + c]));
                }
                if db[r * t + c] != 0.0 {
                    trip.push((r, t + c, db[r * t + c]));
                }
            }
            for c in 0..m4 {
                if dc[r * m4 + c] != 0.0 {
                    trip.push((r, 2 * t + c, dc[r * m4 + c]));
                }
            }
            b.push(-lin.d[r / 4][r % 4]);
        }
        box_rate_rows(&mut trip, &mut b, 0, t, su.dbox);
        box_rate_rows(&mut trip, &mut b, t, t, su.abox);
        for k in 0..t {
            for j in [1usize, 3] {
                let idx = 2 * t + 4 * k + j;
                let r = b.len();
                trip.push((r, idx, 1.0));
                b.push(su.zhi[j]);
                trip.push((r + 1, idx, -1.0));
                b.push(-su.zlo[j]);
            }
        }
        let m = b.len();
        let am = triplets_csc(m, nv, trip);
        let cones = vec![zero_cone(m4), clarabel::solver::NonnegativeConeT(m - m4)];
        let mut last_status = String::new();
        for equilibrate in [true, false] {
            let mut solver = clarabel::solver::DefaultSolver::new(
                &pm,
                &q,
                &am,
                &b,
                &cones,
                clarabel_settings(equilibrate),
            )
            .map_err(|e| PlannerError::QpSetup {
                qp: "joint",
                reason: e.to_string(),
            })?;
            clarabel::solver::IPSolver::solve(&mut solver);
            let st = solver.solution.status;
            if usable(st) {
                let x = &solver.solution.x;
                let delta = x[..t].to_vec();
                let accel = x[t..2 * t].to_vec();
                let z: Vec<State> = (0..t)
                    .map(|k| State::from_column_slice(&x[2 * t + 4 * k..2 * t + 4 * k + 4]))
                    .collect();
                let cost = self.cost(&su, &delta, &accel, &z);
                return Ok(JointSolution {
                    states: Self::to_world(&su, &z),
                    delta,
                    accel,
                    cost,
                });
            }
            last_status = format!("{st:?}");
        }
        Err(PlannerError::QpFailed {
            qp: "joint",
            iteration: 0,
            status: last_status,
        })
    }
}

/// Nonlinear roll-out with the speed clamped at 0 (the simulator's vehicle does not reverse).
fn rollout_clamped(model: &Bicycle, z0: &State, delta: &[f64], accel: &[f64], out: &mut [State]) {
    let mut z = *z0;
    for ((d, a), o) in delta.iter().zip(accel).zip(out.iter_mut()) {
        z = model.step(&z, *d, *a);
        z[3] = z[3].max(0.0);
        *o = z;
    }
}

/// A repaired input sequence: steering, acceleration, its roll-out's minimum b, the status.
type Repair = (Vec<f64>, Vec<f64>, Option<f64>, PlanStatus);

/// Steering that turns the vehicle towards the lateral goal `y_goal` (m, same frame as `z0`)
/// while it follows `accel`: each step aims at the heading ψ* = clamp(0.05·(y_goal − y), ±0.08)
/// rad and steers to reach it in one step, within the box and rate bounds.
fn steer_towards(model: &Bicycle, z0: &State, accel: &[f64], y_goal: f64, bx: RateBox) -> Vec<f64> {
    let mut z = *z0;
    let mut prev = bx.prev.clamp(bx.lo, bx.hi);
    let mut out = Vec::with_capacity(accel.len());
    for a in accel {
        let psi_goal = (0.05 * (y_goal - z[1])).clamp(-0.08, 0.08);
        // ψ⁺ − ψ ≈ dt·v·sin β / l_r with β ≈ δ·l_r/(l_f + l_r).
        let gain = model.dt * z[3].max(1.0) / (model.l_f + model.l_r);
        let d =
            ((psi_goal - z[2]) / gain).clamp(bx.lo.max(prev - bx.rate), bx.hi.min(prev + bx.rate));
        z = model.step(&z, d, *a);
        z[3] = z[3].max(0.0);
        out.push(d);
        prev = d;
    }
    out
}

/// `out = M v` for a flat row-major `[4T, 4T]` matrix and stacked states.
fn mat_vec(m: &[f64], v: &[State], out: &mut [State]) {
    let n = 4 * v.len();
    for r in 0..n {
        let row = &m[r * n..(r + 1) * n];
        let mut acc = 0.0;
        for (c, mv) in row.iter().enumerate() {
            acc += mv * v[c / 4][c % 4];
        }
        out[r / 4][r % 4] = acc;
    }
}

/// Z⁺ = Π(Z − η∇G), Π clamping y and v to their bounds.
fn project_step(z: &[State], grad: &[State], eta: f64, su: &Setup, out: &mut [State]) {
    for ((o, zk), gk) in out.iter_mut().zip(z).zip(grad) {
        *o = (zk - eta * gk).sup(&su.zlo).inf(&su.zhi);
    }
}

fn max_diff(a: &[State], b: &[State]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).amax())
        .fold(0.0, f64::max)
}

/// One vehicle the safety constraint checks.
struct CheckedVehicle {
    /// Agent index (≥ 1).
    index: usize,
    /// (length, width) (m).
    size: [f64; 2],
    /// Last observed position (m).
    last: [f64; 2],
    /// (|cos ψ|, |sin ψ|) of its last observed motion.
    dir: [f64; 2],
}

/// Runs the predictor on candidate states and evaluates b_i for every checked vehicle and step,
/// with each ellipse sized by both vehicles' bounding boxes at their headings (the ego's from
/// the candidate's ψ_k, the other's from its predicted motion).
struct SafetyEval<'c> {
    cand: Vec<f64>,
    out: Vec<f64>,
    /// ∂(total violation)/∂(x_k, y_k) at the last evaluated point, prediction and ellipse
    /// sizes frozen.
    rgrad: Vec<[f64; 2]>,
    calls: usize,
    origin: [f64; 2],
    horizon: usize,
    checked: &'c [CheckedVehicle],
    ego_size: [f64; 2],
    /// (|cos ψ_k|, |sin ψ_k|) of the candidate, per step (scratch).
    ego_dir: Vec<[f64; 2]>,
    scale: f64,
    /// (m_x, m_y) (m).
    margins: [f64; 2],
    safety_min: f64,
}

impl SafetyEval<'_> {
    /// Returns (min b over checked vehicles and steps, total violation Σ max(0, b_min − b));
    /// `None` for the minimum when nothing is checked (no predictor call then).
    fn eval(
        &mut self,
        predictor: &mut dyn Predictor,
        z: &[State],
    ) -> Result<(Option<f64>, f64), PlannerError> {
        if self.checked.is_empty() {
            return Ok((None, 0.0));
        }
        let t = self.horizon;
        for (k, zk) in z.iter().enumerate().take(t) {
            self.cand[2 * k] = zk[0] + self.origin[0];
            self.cand[2 * k + 1] = zk[1] + self.origin[1];
            self.rgrad[k] = [0.0; 2];
            let (sn, cs) = zk[2].sin_cos();
            self.ego_dir[k] = [cs.abs(), sn.abs()];
        }
        predictor.predict(&self.cand, &mut self.out)?;
        self.calls += 1;
        let mut min_b = f64::INFINITY;
        let mut viol = 0.0;
        for v in self.checked {
            let base = (v.index - 1) * t * 2;
            let mut prev = v.last;
            for k in 0..t {
                let ego = [self.cand[2 * k], self.cand[2 * k + 1]];
                let other = [self.out[base + 2 * k], self.out[base + 2 * k + 1]];
                let ell = Ellipse::oriented(
                    self.ego_size,
                    self.ego_dir[k],
                    v.size,
                    motion_direction(prev, other, v.dir),
                    self.scale,
                    self.margins[0],
                    self.margins[1],
                );
                prev = other;
                let b = ell.value(ego, other);
                min_b = min_b.min(b);
                if b <= self.safety_min {
                    viol += self.safety_min - b;
                    let g = ell.gradient(ego, other);
                    self.rgrad[k][0] -= g[0];
                    self.rgrad[k][1] -= g[1];
                }
            }
        }
        // A NaN prediction is never safe.
        if min_b.is_nan() {
            return Ok((Some(f64::NEG_INFINITY), f64::INFINITY));
        }
        Ok((Some(min_b), viol))
    }
}
