//! [`PlannerSettings`]: every weight, bound, tolerance and limit of the ADMM MPC in one
//! validated, serde-(de)serialisable struct.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::error::SettingsError;

/// Largest settings file accepted by [`PlannerSettings::from_file`] (bytes).
pub const MAX_SETTINGS_BYTES: u64 = 1 << 20;

fn json_kind(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    }
}

/// Every number the planner uses. Units: metres, seconds, radians, m/s, m/s².
///
/// Deserialises from JSON with every field optional (missing fields take the [`Default`]) and
/// unknown fields rejected; [`PlannerSettings::from_json`] accepts only a JSON object. Always
/// call [`PlannerSettings::validate`] (done by [`crate::Planner::new`]) before use: every
/// numeric field has a documented range in [`RANGES`] (the booleans are valid either way).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerSettings {
    /// Planning horizon T (steps); must equal the predictor's horizon: any for the teacher (a longer
    /// roll-out of its one-step network) and constant velocity, 6 for the shipped student.
    pub horizon: usize,
    /// Step length (s).
    pub dt: f64,
    /// Distance from the centre of gravity to the front axle l_f (m).
    pub l_f: f64,
    /// Distance from the centre of gravity to the rear axle l_r (m).
    pub l_r: f64,

    /// Weight of (y − y_target)² per step (1/m²).
    pub w_y: f64,
    /// Deadline weight of a merge (1/m²): while the ego's centre is in a lane that really ends
    /// d m ahead and the target lies outside it, the lateral weight is w_y + w_deadline ·
    /// clamp(1 − d / `deadline_distance`, 0, 1)² ([`crate::extents`]); 0 disables it.
    pub w_deadline: f64,
    /// Distance to the end of the ego's lane (m) from which the deadline weight counts.
    pub deadline_distance: f64,
    /// Deceleration (m/s², > 0) of the lane-end stopping rule: the last planned state, when
    /// its centre is in a lane that really ends, must be able to stop, braking at this rate,
    /// `stop_margin` before the end: x_T + v_T² / (2 · `stop_decel`) ≤ end − `stop_margin`
    /// (less for a state heading out of the lane: [`crate::extents`]).
    pub stop_decel: f64,
    /// Distance before the real end of a lane (m) by which the stopping rule must stop the
    /// ego's centre, and where the fallback's stopping sequences stop it; a state heading out
    /// of the lane at half `heading_max` or more needs only the distance it takes to leave
    /// the lane ([`crate::extents::Lanes::stop_excess`]). It must leave room to merge from a
    /// standstill: from a lane's centre, a 3.7 m lane, the bicycle at the steering and heading
    /// bounds needs about 10 m of road to get its centre across the line.
    pub stop_margin: f64,
    /// Weight of (v − v_ref)² per step.
    pub w_v: f64,
    /// Weight of ψ² per step (heading relative to the road).
    pub w_psi: f64,
    /// Weight of δ² per step.
    pub w_delta: f64,
    /// Weight of (δ_k − δ_{k−1})² per step.
    pub w_ddelta: f64,
    /// Weight of a² per step.
    pub w_a: f64,
    /// Weight of (a_k − a_{k−1})² per step.
    pub w_da: f64,
    /// ADMM penalty ρ (> 0). Default 1000 rather than PLANNER.md's starting 10: on a
    /// lane change without traffic ADMM reaches ‖F‖∞ ≤ 1e-6 in 86 iterations with ρ = 1000,
    /// in none of 3000 with ρ = 10 (measured by the joint-QP anchor test's scene).
    pub rho: f64,

    /// Steering bound: δ ∈ [−delta_max, delta_max] (rad).
    pub delta_max: f64,
    /// Steering rate bound per step: |δ_k − δ_{k−1}| ≤ ddelta_max (rad per step).
    pub ddelta_max: f64,
    /// Lower acceleration bound (m/s², < a_max).
    pub a_min: f64,
    /// Upper acceleration bound (m/s²).
    pub a_max: f64,
    /// Jerk bound per step: |a_k − a_{k−1}| ≤ da_max (m/s² per step).
    pub da_max: f64,
    /// Upper speed bound (m/s); the lower bound is 0.
    pub v_max: f64,
    /// Extra clearance between the ego's side and the road edges (m, ≥ 0).
    pub edge_margin: f64,
    /// Speed below which the linearisation point's speed is clamped (m/s, > 0).
    pub v_lin_min: f64,

    /// Scale s of the summed half sizes in the ellipse semi-axes (√2: the ellipse
    /// circumscribes the box-overlap rectangle; 1: PLANNER.md's inscribed ellipse).
    pub ellipse_scale: f64,
    /// Lateral scale s_y of the ellipse semi-axes; 0 (the default): `ellipse_scale` on both
    /// axes. Otherwise the lateral semi-axis takes s_y and the longitudinal one
    /// s_x = 1 / √(2 / s² − 1 / s_y²) (s = `ellipse_scale`), which keeps 1/s_x² + 1/s_y² =
    /// 2/s²: with s = √2 the corner of the box-overlap rectangle stays on the ellipse, so it
    /// still circumscribes the rectangle and b > 0 still excludes overlap, with the inflation
    /// moved from across the road to along it ([`crate::axis_scales`]). Must exceed
    /// s / √2. The isotropic √2 ellipse of two 2.0 m wide cars reaches 2.83 m + `margin_y`
    /// across the road, about the lateral distance of two cars centred in adjacent 3.4–3.7 m
    /// lanes, so a vehicle beside the ego in the next lane keeps it from centring in its own.
    /// Off by default: on validation (student planner, 300 scenes × 3 seeds, s_y 1.25, so
    /// s_x 1.67) success fell in every world (teacher 85.3 → 82.4 %, idm 89.9 → 86.3 %, log
    /// replay 85.1 → 76.7 %) and log-replay at-fault runs rose 5 → 14: the longer reach along
    /// the road closes more gaps than the narrower one across it opens
    /// (`docs/results/ellipse_lateral.md`).
    pub ellipse_lateral_scale: f64,
    /// Longitudinal margin m_x (m): added to the ellipse's summed half lengths, or with
    /// `safety_geometry` = `boxes` the clearance between the boxes along the road.
    pub margin_x: f64,
    /// Lateral margin m_y (m): added to the ellipse's summed half widths, or with
    /// `safety_geometry` = `boxes` the clearance between the boxes across the road.
    pub margin_y: f64,
    /// The shape of the safety constraint b_i ([`SafetyGeometry`]): the inflated ellipse
    /// (default; b unitless) or the exact separation of the two oriented boxes with the
    /// margins `margin_x`, `margin_y` as clearances (b in metres; `safety_min`, `plan_buffer`,
    /// `z_step_margin` and `refine_margin` are then in metres too). The ellipse stays the
    /// default: on validation the boxes lowered success (`docs/results/nudge_safety.md`).
    pub safety_geometry: SafetyGeometry,
    /// Longest slice of the ego (m) one safety ellipse covers; 0: off (one ellipse for the
    /// whole ego); otherwise at least 0.5 m ([`Self::MIN_EGO_SEGMENT_LENGTH`]), and an ego
    /// needing more than 64 slices ([`Self::MAX_EGO_SEGMENTS`]) is refused with a typed error.
    /// With `safety_geometry` = `ellipse` and an ego longer than this, the ego is
    /// cut along its heading into k = ⌈length / `ego_segment_length`⌉ equal slices and b_i is
    /// the smallest of the k ellipses of [`crate::safety::Ellipse::oriented`], each sized by
    /// one slice (length / k) and centred on it. The √2 ellipse of one long box reaches
    /// √2 × the summed half lengths along the road (≈ 18.7 m for a 19.8 m truck and a car,
    /// against 12.2 m where the boxes touch); the slices' ellipses still circumscribe the
    /// overlap region (the union of the slices is the ego's box), so b > 0 keeps excluding
    /// overlap, with a reach closer to the box. Cars shorter than this are unaffected.
    /// 6 m by default, with `contact_first`, `edge_first` and `bounds_first` (slack 0.05);
    /// 0 turns it off. Without `bounds_first` the three passed validation (no world lost
    /// success, log-replay at-fault runs 8 → 5) but the test split, run once, left the road
    /// and broke the heading bound in log replay; with it they passed both (see
    /// [`crate::Planner`]'s "Long egos" and "Contact within the state bounds" sections and
    /// `docs/results/long_egos.md`). The validation egos longer than 6 m are trucks of
    /// 6.1–19.8 m.
    pub ego_segment_length: f64,
    /// Deceleration (m/s²) of the terminal closing-speed margin: at the last step of the
    /// horizon the ellipse's longitudinal semi-axis grows by (v_rear² − v_front²)/(2·brake_decel)
    /// when the rear one of the ego and the other vehicle is faster, so a plan never ends in a
    /// gap that it, or a faster vehicle behind it, could only keep by braking harder than this.
    /// 0 disables it.
    pub brake_decel: f64,
    /// Only vehicles whose current centre is within this distance of the ego's are checked (m).
    pub check_range: f64,
    /// A point is safe when every checked b_i ≥ this value (≥ 0; 0 means b_i > 0 strictly
    /// up to rounding).
    pub safety_min: f64,
    /// Constraint tightening (≥ 0, units of b): the Z-update accepts only states with every
    /// b_i > safety_min + plan_buffer, while the executed roll-out must only keep
    /// b_i > safety_min. Z otherwise settles on the constraint boundary and the roll-out of
    /// the inputs, which deviates from Z by the primal residual, dips below it. With the
    /// convergence rules (`z_safe_step`, `z_rollout_trial`, `relinearise`) 0.03: b of the
    /// roll-out of converged ADMM calls fell below Z's by up to 0.03 in 90 % of them
    /// (validation scenes, student planner; see [`crate::Planner`]).
    pub plan_buffer: f64,

    /// Maximum ADMM iterations per MPC call.
    pub max_iter: usize,
    /// Convergence tolerance on the primal residual ‖F‖∞ (m, rad, m/s).
    pub eps_primal: f64,
    /// Convergence tolerance on the change ‖Z − Z_prev‖∞.
    pub eps_change: f64,
    /// Projected-gradient steps per Z-update.
    pub pgd_steps: usize,
    /// Step halvings tried before a Z-update keeps its current point.
    pub pgd_halvings: usize,
    /// Try the Hessian-scaled step H⁻¹∇G (H = ∇²G, constant per call) before the plain 1/L
    /// gradient step in each Z-update step. Plain 1/L steps alone converge slowly (H's
    /// condition number is ~10⁴ at highway speeds).
    pub hessian_scaled: bool,
    /// Weight w_pin of the position pull in the pinned-Newton and restoration trials
    /// (minimise G + w_pin/2 Σ‖p_k − p*_k‖²); large values keep positions near the target.
    pub pin_weight: f64,
    /// Try the linearised-safety step in each Z-update step (after the Newton step, before the
    /// pinned Newton step; first in a feasibility restoration; needs `hessian_scaled`): the
    /// minimiser of G subject to the safety rows of the current Z linearised in the ego's
    /// position, by a small active-set method on H⁻¹. Without it a Z on the constraint
    /// boundary can only take steps that leave it, and the Z-update stalls there. Off by
    /// default, like `z_rollout_trial` and `relinearise` (see [`crate::Planner`], convergence
    /// by design).
    pub z_safe_step: bool,
    /// Target of the linearised safety rows of the Z-update's safe step above the Z-update's
    /// threshold `safety_min + plan_buffer` (units of b, ≥ 0).
    pub z_step_margin: f64,
    /// Cuts of the Z-update's projection onto the linearised safe set (with `z_safe_step`;
    /// 0: off). With cuts, the linearised-safety step is tried right after the full Newton
    /// step, as a projection: when its trial point is unsafe under the prediction of that
    /// trial (the linearisation was wrong: the other vehicles reacted, or the ellipse turned),
    /// the safety rows violated at the trial point, linearised there, join the rows of the
    /// current Z and the step is solved again, at most this many times, before it is halved;
    /// the halvings of the Newton step (which stop Z on the boundary along the one direction
    /// of the unconstrained minimiser) come after it. So Z slides along the boundary instead
    /// of sticking on it (see [`crate::Planner`], convergence by design).
    pub z_cuts: usize,
    /// Start the ADMM loop from the best safe simple candidate when the nominal (the shifted
    /// previous plan) is unsafe: the fallbacks' keep-lane and steer-towards-the-goal input
    /// sequences at their acceleration profiles (constant, and with `fallback_brake_hold`
    /// braking for part of the horizon, then holding; [`crate::Planner`]), whose roll-outs
    /// (clamped into the state bounds) are checked by the predictor at the Z-update's
    /// threshold; the safe one with the least cost J becomes the starting inputs and Z.
    /// Without it the loop starts in the feasibility restoration and rarely reaches an
    /// admissible roll-out within `max_iter`.
    pub safe_start: bool,
    /// Re-tightenings of the Z-update's threshold per call (0: off). When the loop converges
    /// but the predictor finds the nonlinear roll-out of the inputs unsafe (b ≤ `safety_min`),
    /// the threshold `safety_min + plan_buffer` is raised by the drop of b from Z to that
    /// roll-out plus `z_step_margin`, Z is evaluated at the new threshold and the loop goes
    /// on (within `max_iter`), at most this many times: the constraint tightening by the
    /// measured roll-out error of this call rather than a fixed `plan_buffer`. The execution
    /// check and its repairs keep `safety_min`.
    pub z_retighten: usize,
    /// Try the nonlinear roll-out of the current (Δ, α), clamped into the state bounds, as the
    /// first trial of each Z-update: accepted like any trial (safe and lowering G), it puts Z
    /// where the inputs actually take the ego, so the primal residual there is the
    /// linearisation error alone.
    pub z_rollout_trial: bool,
    /// Re-linearise the dynamics around the current inputs and their nonlinear roll-out at
    /// every ADMM iteration after the first (a sequential-convex ADMM): F then measures the
    /// distance of Z from the nonlinear roll-out, not from the roll-out of the dynamics
    /// linearised around the shifted previous plan, so a converged Z is the roll-out of the
    /// inputs up to `eps_primal` per step.
    pub relinearise: bool,
    /// Warm-start the dual variable μ from the previous call (shifted); otherwise μ = 0.
    pub warm_start_dual: bool,
    /// Check the nonlinear roll-out of the returned inputs with the predictor and fall back to
    /// the least-violating simple input sequence when it is unsafe.
    pub rollout_check: bool,
    /// Speed floor of the fallbacks without an admissible plan (fraction of the reference speed
    /// `v_ref`, in [0, 1]; 0: off). When no plan is admissible, a candidate whose path is clear
    /// and that ends at or above `fallback_speed_floor` · `v_ref` beats every other candidate
    /// (among themselves, and among the rest, the least total violation wins as without it).
    /// Its path is clear when it is within the state bounds (up to `bounds_slack`, as for
    /// `bounds_first`), keeps the follower-gap rule (when on) and its only safety violations
    /// come from vehicles **beside** the ego: the lateral
    /// distance of the centres is at least the sum of the half widths of their road-aligned
    /// bounding boxes plus `margin_y`, so the boxes cannot touch at any offset along the road. Without it the least total violation
    /// wins, and a vehicle passing in the next lane, inside the ellipse but never able to
    /// touch the ego, has the ego brake towards a standstill in its own live lane.
    pub fallback_speed_floor: f64,
    /// Add two "brake, then hold" acceleration profiles to the fallbacks' constant ones (0,
    /// a_min/2, a_min, a_max/2): a_min for the first ⌈T/3⌉ or ⌈2T/3⌉ steps, then 0, within the
    /// jerk bound; each with the keep-lane, steer-to-the-goal and retreat steering, ranked like
    /// the others (and among the safe start's candidates). Off by default: measured on 600
    /// training scenes × 3 seeds (student planner, paired; `docs/results/planned_slow.md`) it
    /// cuts runs that plan a slow step on a free road (3 → 1, 10 → 9, 14 → 11 in the teacher,
    /// IDM and log-replay worlds) with no significant change in success (McNemar p ≥ 0.24),
    /// but adds runs slow in a live lane (14 → 20, 26 → 29, 22 → 30) and at-fault collisions
    /// in log replay (17 → 19 runs, 22 → 30 events); taking them only when admissible was
    /// worse (teacher world 1591 → 1585 of 1800 successes, 6 lost and none gained).
    pub fallback_brake_hold: bool,
    /// Add the constant a_max acceleration profile to the fallbacks' constant ones (0,
    /// a_min/2, a_min, a_max/2), with the keep-lane, steer-to-the-goal and retreat steering,
    /// ranked like the others: an escape forwards from a vehicle closing from behind or from
    /// the side. Off by default: on 600 training scenes × 3 seeds (student planner, paired) it
    /// gained success in the teacher world (1592 → 1609 of 1800, 1 lost, 18 gained) and cut
    /// log-replay at-fault runs 17 → 15 (events 22 → 15), but on validation, where settings
    /// are chosen, the teacher planner lost 6 runs and gained none in the teacher world
    /// (270 → 264 of 300, McNemar p = 0.03): with nothing admissible the least-violating
    /// candidate became accelerating past the target-lane gap, which left the ego beside the
    /// traffic (`docs/results/fallback_escape.md`).
    pub fallback_full_accel: bool,
    /// Add "shy" sequences to the fallbacks: each acceleration profile of the fallbacks with
    /// the steering of a move across the ego's own lane, towards the positions where its box
    /// keeps [`crate::SHY_CLEARANCE`] from the lane's right and from its left line (within the
    /// call's lateral bounds), ranked like the others (and among the safe start's
    /// candidates). A driver passing a vehicle that hugs the line moves over in its own lane;
    /// the keep-lane and retreat sequences hold the ego where it is or at its lane's centre,
    /// where the safety ellipse of such a vehicle may still reach it, so the fallback brakes
    /// instead. Off by default: on 600 training scenes × 3 seeds (student planner, paired;
    /// `docs/results/planned_slow.md`) it lifted log-replay success 1485 → 1514 of 1800
    /// (McNemar p = 0.00015) but added an at-fault run in the teacher world (0 → 1) and
    /// off-road steps (a truck starting over the road's edge; 0 → 3 runs in two worlds), and
    /// left the runs with a slow plan on a free road as they were (20 → 19).
    pub fallback_shy: bool,
    /// Add "brake to the speed of the vehicle ahead, then hold" acceleration profiles to the
    /// fallbacks' constant ones: one for each of the (at most [`crate::MATCH_SPEED_PROFILES`])
    /// nearest vehicles ahead of the ego, within `check_range`, whose box reaches into the band
    /// between the ego's lateral position and its goal and whose observed speed along the road
    /// is below the ego's; each brakes as hard as the box and jerk bounds allow while the
    /// speed, after unwinding the brake at the jerk bound, stays at or above that vehicle's,
    /// then holds it. Each with the keep-lane, steer-to-the-goal and retreat steering, ranked
    /// like the others (and among the safe start's candidates), or apart from them with
    /// `match_admissible_only`, and only from `match_min_speed`. Meant for yielding to a
    /// slower vehicle about to enter the ego's path, which the constant profiles do at a_min,
    /// towards a standstill. Off by default: measured on 600 training scenes × 3 seeds
    /// (student planner, paired; `docs/results/match_speed.md`), neither way removed a run
    /// with a slow plan on a free road in any world. Ranked with the others and from any
    /// speed, it lost 9 runs in the teacher world and gained none (McNemar p = 0.004; lane
    /// changes left unfinished, the ego slowing to a slower vehicle's speed where it had
    /// passed it) and raised the log-replay at-fault runs 19 → 32. Apart, admissible only,
    /// from 10 m/s: 5 lost and none gained (p = 0.06), at-fault runs 19 → 22.
    pub fallback_match_speed: bool,
    /// With `fallback_match_speed`: its profiles are checked apart from the others and
    /// replace the best fallback only when admissible (and cheaper, as any admissible one);
    /// they get the keep-lane and steer-to-the-goal steering, not the retreat's, and never
    /// become the least-violating candidate. Off: they join the constant profiles, ranked like
    /// them (the variant measured first, `docs/results/match_speed.md`).
    pub match_admissible_only: bool,
    /// With `fallback_match_speed`: the ego's speed (m/s) at the start of the call from which
    /// the match-speed profiles are built; slower, none (a queue, not a free-flowing road).
    pub match_min_speed: f64,
    /// When no fallback above is admissible, also check the input lattice (over the first six
    /// steps, blocks of two steps, each changing the steering and the acceleration by −, 0
    /// or + their rate bounds per step, clipped to their boxes, the last inputs held after
    /// them: at most 729 sequences whatever the horizon), each on its own roll-out and
    /// prediction like every fallback, and keep the best by the same rank.
    /// The log-replay oracle (`nudge_research::oracle`) found every at-fault collision of the
    /// development runs avoidable from a state 0.6–1.5 s before the contact where the planner
    /// already had nothing admissible; the simple fallbacks miss the sequences that avoid it.
    /// On by default, with `lattice_clear_nonreactive` and `lattice_min_speed`: alone, on 600
    /// training scenes × 3 seeds (student planner, paired), it raised the log-replay at-fault
    /// runs 17 → 26 (events 22 → 34), edging the ego into stop-and-go queues; with both it
    /// cut them 17 → 9 (events 22 → 15) and added none in any world, and on validation it
    /// added no at-fault, off-road or free-road slow run in any arm
    /// (`docs/results/avoidability.md`).
    pub fallback_lattice: bool,
    /// With `fallback_lattice`: a lattice sequence replaces the fallback only when its boxes
    /// overlap no other vehicle's at any step under a constant-velocity prediction (every
    /// other vehicle keeps its last observed displacement per step and does not react), so the
    /// last-resort search never counts on somebody making room. On by default (with
    /// `lattice_min_speed`); without the speed floor it still raised the training log-replay
    /// at-fault runs 17 → 23 (events 22 → 29), all the added ones at walking pace in queues
    /// that were standing when the sequence was chosen (`docs/results/avoidability.md`).
    pub lattice_clear_nonreactive: bool,
    /// With `fallback_lattice`: search the lattice only when the fallback chosen above itself
    /// overlaps another vehicle's box at some step under the constant-velocity prediction
    /// (every other vehicle keeps its last observed displacement per step and does not
    /// react). A fallback that is inadmissible only by the planning predictor's margins, but
    /// hits nobody even if nobody reacts, is kept. Off by default: with
    /// `lattice_clear_nonreactive` (no speed floor) on 600 training scenes × 3 seeds (student
    /// planner, paired) the log-replay at-fault runs went 17 → 21, 5 avoided and 9 added, most
    /// of those at walking pace (`docs/results/avoidability.md`).
    pub lattice_when_fallback_hits: bool,
    /// With `fallback_lattice`: search the lattice only while the ego's speed at the start of
    /// the call is at least this (m/s); 0 searches it at any speed. At walking pace the simple
    /// brake fallback stops the ego within a few metres inside its own lane, while the
    /// lattice's escapes there edged the ego into standing queues. 10 m/s by default, chosen
    /// on the training scenes: without a floor, every log-replay at-fault contact the lattice
    /// added there came at 9.1 m/s or slower and every one it removed at 13.8 m/s or faster
    /// (the ego's speed at the contact; `docs/results/avoidability.md`).
    pub lattice_min_speed: f64,
    /// Rank inadmissible candidates by their worst case over two predictions: the planning
    /// predictor's and a constant-velocity one (every other vehicle keeps its last observed
    /// displacement per step and does not react). An inadmissible candidate's predicted box
    /// overlap (`contact_first`) and safety violation are then each the larger of the two, so
    /// when nothing is admissible the fallback does not count on a yield the planning model
    /// expects but the traffic may not give. Admissibility is unchanged (the planning
    /// predictor alone decides it), so this only changes which plan is applied at steps
    /// without an admissible one. One constant-velocity evaluation per inadmissible candidate
    /// (no network call; not counted in `predictor_calls` or `budget_calls`). Off by default:
    /// on 600 training scenes × 3 seeds (student planner, paired;
    /// `docs/results/follower_gap.md`) it left the log-replay at-fault runs at 17 → 19 (22
    /// events either way) with no significant change in success in any world (McNemar
    /// p ≥ 0.30), and added runs slow in a live lane (14 → 26, 26 → 28, 22 → 27 in the
    /// teacher, IDM and log-replay worlds): in a queue the follower's constant velocity runs
    /// into the ego, so the fallback accelerates towards the vehicle ahead.
    pub fallback_nonreactive: bool,
    /// Among candidates without an admissible plan, one whose box overlaps no other vehicle's
    /// at any step under the constant-velocity prediction (every other vehicle keeps its last
    /// observed displacement per step, its lateral drift included, and does not react) beats
    /// one that overlaps somebody's, after the state-bound, predicted-contact, road-edge and
    /// unbegun-lane rules and before the speed floor and the total violation. A driver the
    /// planning predictor keeps in the next lane while it drifts into the ego's then no longer
    /// has the ego hold its speed beside it by a slightly smaller violation when braking lets
    /// it in. One constant-velocity evaluation per inadmissible candidate (no network call;
    /// not counted in `predictor_calls` or `budget_calls`). Off by default: on 600 training
    /// scenes × 3 seeds (student planner, paired, from `avoid_min_speed`) it added no at-fault
    /// run (log replay 9 → 9 runs, 15 → 12 events; IDM 4 → 4, one avoided and one added;
    /// teacher world unchanged), but on validation the teacher planner in the IDM world gained
    /// one (0 → 1: a rear contact in its lane became a side contact from behind while
    /// straddling), which the adoption rule forbids (`docs/results/avoidability.md`).
    pub fallback_avoid_nonreactive: bool,
    /// With `fallback_avoid_nonreactive`: the rule applies only while the ego's speed at the
    /// start of the call is at least this (m/s); 0 applies it at any speed. 10 m/s by
    /// default, the lattice's floor (`lattice_min_speed`): at any speed the rule added an
    /// at-fault run at 2.2 m/s on the training scenes (IDM world), where braking clear of the
    /// car ahead had the follower hit the ego.
    pub avoid_min_speed: f64,
    /// Extend the planning predictor's forecast of every checked vehicle that is drifting
    /// across the road ([`crate::lateral_drift`]): a vehicle whose mean lateral speed over its
    /// last [`crate::DRIFT_STEPS`] observed steps is at least `lateral_drift_min_speed` is
    /// checked
    /// at least as far along its drift as that speed carries it from its last observed
    /// position (y_k = y_last + k·Δy per step, wherever the network predicts less; its
    /// predicted position along the road is the network's). A driver the network keeps in the
    /// next lane while it cuts in then makes the plans that hold the ego beside it
    /// inadmissible from the first step it drifts. No extra predictor call. Off by default:
    /// on 600 training scenes × 3 seeds (student planner, paired) it removed the five
    /// log-replay at-fault runs with drivers drifting in (9 → 6 runs, 15 → 6 events) but added
    /// one in the IDM world (4 → 5) and lost teacher-world runs (14 lost, 5 gained); at
    /// 0.4 m/s it added at-fault runs in both worlds and lost 11 teacher-world runs for 1
    /// (`docs/results/avoidability.md`).
    pub lateral_drift: bool,
    /// With `lateral_drift`: the smallest mean lateral speed (m/s) over the last
    /// [`crate::DRIFT_STEPS`] observed steps that counts as a drift.
    pub lateral_drift_min_speed: f64,
    /// Rank the road-edge excess first among fallbacks without an admissible plan: the
    /// candidate whose box's corners reach least far beyond the road's edges (Σ over the
    /// horizon, m) wins before the speed floor and the total violation (which otherwise
    /// weighs that excess in one sum with the safety violation, so an ego that starts over
    /// the edge could swing a corner further out to lower its safety violation). On by
    /// default, after `bounds_first` and `contact_first` (`docs/results/long_egos.md`).
    pub edge_first: bool,
    /// Rank predicted contact first among fallbacks without an admissible plan: the candidate
    /// whose box overlaps the predicted boxes of the other vehicles least (Σ over vehicles and
    /// steps of the separating-axis overlap depth, m) wins before the road-edge rule, the
    /// speed floor and the total violation. The total violation alone weighs a margin
    /// violation like a contact, so a long ego could swing its tail into a car beside it to
    /// lower its violation against vehicles ahead and behind. On by default, below
    /// `bounds_first`: ranked above the state bounds, it let cars swerve past the heading
    /// bound and off the road to avoid a predicted contact (test split, log replay;
    /// `docs/results/long_egos.md`).
    pub contact_first: bool,
    /// Rank the safety violation against the vehicles ahead of the ego in its path first
    /// among fallbacks without an admissible plan, after `bounds_first`, `contact_first` and
    /// `edge_first`: the candidate whose violation (Σ of safety_min − b, units of b) over the
    /// pairs whose vehicle is not beside the ego ([`crate::admm::SafetyConstraint::beside`])
    /// and is ahead of it along the road at that step wins before the unbegun-lane rule, the
    /// speed floor and the total violation (from `lead_min_speed`). The total violation
    /// alone weighs a follower closing from behind like the vehicle the ego drives into, so an
    /// ego squeezed between a slower leader and a close follower sped up towards the leader
    /// to lower the follower's violation (the last at-fault run of the test split, a front
    /// contact). On by default, with `lead_in_lane` and `lead_keep_lane`: alone, on 600
    /// training scenes × 3 seeds (student planner, log replay, paired) it cut the at-fault
    /// runs 22 → 19 (events 33 → 24) and added none, but on validation (student planner, log
    /// replay, 300 scenes × 3 seeds) it added 9 at-fault runs to none (a car from behind in
    /// the target lane meeting the side of an ego that held its speed across the line for a
    /// vehicle ahead); the three together added no at-fault run on training, validation or
    /// test and removed the last at-fault run of the test split
    /// (`docs/results/lead_first.md`).
    pub lead_first: bool,
    /// With `lead_first`: the rule applies only while the ego's speed at the start of the
    /// call is at least this (m/s); 0 applies it at any speed. 10 m/s by default, the floor
    /// of the other last-resort rules (`lattice_min_speed`, `avoid_min_speed`): applied at any
    /// speed, the rule added three at-fault runs on the training scenes (an ego at 4.8 m/s
    /// across the line, hit from behind while its front met a car standing in the next lane)
    /// and slow steps in live lanes (75 → 120).
    pub lead_min_speed: f64,
    /// With `lead_first`: the rule applies only while the ego's box at the start of the call
    /// spans no lane line (it is wholly inside one lane, where the at-fault rule counts a
    /// contact from behind as not the ego's); without a lane layout it never applies. Across
    /// the line a contact from behind counts as the ego's, and there `lead_first` alone
    /// swapped contacts the ego drives into for contacts it is driven into. On by default:
    /// without `lead_keep_lane` it added one at-fault run in the teacher world on 600
    /// training scenes × 3 seeds (0 → 1: an ego braking for a slow leader in the target lane
    /// drifted back across the line and was hit from behind), which `lead_keep_lane` removes
    /// (`docs/results/lead_first.md`).
    pub lead_in_lane: bool,
    /// With `lead_first` (while it applies): among fallbacks without an admissible plan, one
    /// whose roll-out keeps the ego's box off every lane line beats every one that puts it
    /// across a line, before the violation ahead decides. Ranked by the violation ahead
    /// alone, a braking ego could steer off its lane's centre to lower that violation and
    /// drift across the line it had crossed (`lead_in_lane`'s training run). On by default:
    /// with `lead_first` and `lead_in_lane`, paired with all three off, it added no at-fault
    /// run in any world on the training scenes (student planner, 600 scenes × 3 seeds; log
    /// replay 22 → 19), on validation or on the test split (both planners, three worlds; test
    /// log replay 1 → 0, not-at-fault collisions 0 → 3), with no significant change in
    /// success (`docs/results/lead_first.md`).
    pub lead_keep_lane: bool,
    /// Rank the state bounds first among fallbacks without an admissible plan: a candidate
    /// whose roll-out is within the state bounds (heading, lateral corridor, speed, road edge,
    /// lane extents and stopping rule: the excess the total violation weighs, 0) beats every
    /// one outside them, before `contact_first`, `edge_first`, the speed floor and the total
    /// violation are compared. With `contact_first` alone, a fallback predicted to touch
    /// nobody beat one within the heading bound and on the road, so in log replay a squeezed
    /// car swerved past the heading bound, across a lane and off the road; with this rule
    /// predicted contact only decides among candidates on the same side of the bounds. On by
    /// default with `bounds_slack` 0.05: strict (slack 0), on validation (with the three
    /// long-ego settings) a 19.8 m truck whose contact-free fallbacks left its lateral band
    /// by 1.5 cm was turned into the car beside it instead (at-fault runs 0 → 2 in the
    /// teacher world, 1 → 3 in idm; `docs/results/long_egos.md`).
    pub bounds_first: bool,
    /// Slack of the `bounds_first` test and of the path test of `fallback_speed_floor` (Σ over
    /// the horizon of the state-bound excess, m, rad and m/s mixed as in the total violation):
    /// a candidate whose excess is at most this counts as within the bounds. 0: only an excess of 0 (up to rounding) does. On
    /// validation a 19.8 m truck's contact-free fallbacks left its lateral band by 1.5 cm and
    /// lost to a turn into the car beside it; the swerves `bounds_first` is for leave the
    /// bounds by tenths of a radian and metres. 0.05 by default.
    pub bounds_slack: f64,
    /// Largest position move (m) of a feasibility-restoration trial.
    pub restore_step: f64,
    /// Ablate the predicted reaction: the predictor sees the ego's keep-lane path
    /// ([`crate::keep_lane_path`]: the measured ego at its measured speed along the road on
    /// its measured lateral position, x_k = x_0 + k·dt·v_0, y_k = y_0 for k = 1..T) instead of
    /// each candidate, so the predicted traffic cannot depend on the ego's plan; the cost, the
    /// safety rule and the fallbacks are unchanged. The prediction is made once per MPC call
    /// (the predictor is called at most once; `budget_calls` counts that call). For the
    /// experiment "interaction-aware planner vs the same model without its reaction".
    pub ablate_reaction: bool,

    /// Heading bound relative to the road (rad): every returned state has |ψ_k| ≤ heading_max
    /// (an ego that starts beyond it gets a bound that returns to it by `heading_recovery`
    /// per step). An admissible plan keeps it by definition; with `heading_governor` every
    /// other plan keeps it too, wherever the steering's box and rate bounds allow. A value
    /// ≥ π/2 leaves the heading unbounded.
    pub heading_max: f64,
    /// Rate (rad per step) at which the heading bound of an ego starting beyond `heading_max`
    /// returns to it.
    pub heading_recovery: f64,
    /// Govern every candidate's steering to the heading bounds before its roll-out is checked:
    /// at each step the steering nearest to the candidate's, within the box and rate bounds,
    /// from which the heading stays within the bound for the rest of the horizon on the exact
    /// model when the steering is then unwound as fast as the rate allows at the fastest
    /// speeds `a_max` allows (so a later plan that brakes less can still unwind in time; the
    /// plan carries the governed steering, and a sequence every step of which passes this test
    /// is unchanged).
    /// Without it the ADMM inputs keep the bound on the linearised dynamics only:
    /// their roll-out can pass it by a few milliradians, which sends the step to the repairs,
    /// and a plan that nothing admissible beats is returned past it (0.2011 rad once in 4050
    /// test-split runs). On by default: on validation, paired with it off, success rose in
    /// five of six arms (the sixth: −0.7 pp, 3 runs lost and 1 gained) and the student
    /// planner's at-fault runs in log replay fell 5 → 0 (`docs/results/heading_governor.md`).
    pub heading_governor: bool,
    /// Lateral overshoot allowed beyond the lateral goal and behind the start (m): the ego's
    /// centre stays within [min(y_0, y_target) − overshoot_max, max(y_0, y_target) +
    /// overshoot_max] (and on the road, its corners included at the heading bound).
    pub overshoot_max: f64,
    /// Iterations of the SQP refinement of the ADMM inputs on the nonlinear roll-out, run when
    /// that roll-out is not admissible (unsafe or out of its bounds); 0 disables it.
    pub refine_iters: usize,
    /// The refinement's target (units of b) above `safety_min` for the linearised safety rows.
    pub refine_margin: f64,
    /// Trust region of one refinement step on each steering input (rad).
    pub refine_trust_delta: f64,
    /// Trust region of one refinement step on each acceleration input (m/s²).
    pub refine_trust_accel: f64,
    /// Wall-clock budget of one MPC call (s): when it is spent the call ends with the best
    /// admissible plan found (status `BudgetExhausted`); 0 means no budget.
    pub budget_s: f64,
    /// Predictor-call budget of one MPC call (deterministic, for tests and reproducible
    /// runs); 0 means no budget.
    pub budget_calls: usize,

    /// The contingency rule (see [`crate::Planner`], "Safety geometry and contingency"): while
    /// the ego may still fall back to its own lane ([`crate::PlanningProblem::y_retreat`]), a
    /// plan one of whose states puts the ego's box across the line between its own lane and
    /// the target lane is admissible only if a retreat from that state (a fixed manoeuvre:
    /// steer back towards the own lane's centre at `contingency_accel`, or else at
    /// acceleration 0) is safe against the predictor's prediction for the retreat path.
    /// Checked on the nonlinear roll-out in the execution check (refinement, backtracking and
    /// fallbacks all respect it); one or two more predictor calls per checked plan that
    /// crosses the line. Off by default: on validation it lowered success
    /// (`docs/results/nudge_safety.md`).
    pub contingency: bool,
    /// Constant acceleration of the contingency retreat (m/s², within the acceleration and
    /// jerk bounds from the plan's acceleration at the branch state); when that retreat is
    /// not safe, the retreat holding acceleration 0 is tried too.
    pub contingency_accel: f64,
    /// Predicted steps the contingency retreat is checked for at least (steps): the retreat
    /// branches off the plan at its first state across the line, but no later than step
    /// T − `contingency_steps`.
    pub contingency_steps: usize,

    /// The follower-gap rule (s; 0, the default, disables it; see `crate::Planner`,
    /// "Followers that do not yield"): a plan may not narrow the lateral clearance between the ego's box and a vehicle
    /// behind it on the goal's side below `follower_clearance` while that vehicle, driving on
    /// along the road at its last observed speed without reacting, is closer behind the ego
    /// (bumper to bumper) than `follower_min_gap` plus its closing speed times this time to
    /// collision. Checked on the nonlinear roll-out in the execution check, with no predictor
    /// call; a plan that breaks it is not admissible, and among inadmissible fallbacks its
    /// violation (m) ranks like a bound excess. Off by default: at 2 s it removed the
    /// log-replay at-fault collisions it targets but lowered success in every world on
    /// validation; at 1 s with a 0.5 m clearance, measured again with the planner of December
    /// 2026, validation had no at-fault run left for it to remove and it lost 29 runs and
    /// gained 19 over the six arms (`docs/results/follower_gap.md`).
    pub follower_ttc: f64,
    /// Bumper gap (m) every follower of the follower-gap rule must keep behind the ego, however
    /// slow it is.
    pub follower_min_gap: f64,
    /// Lateral clearance (m) between the ego's box and a follower's below which the ego is in
    /// that follower's path for the follower-gap rule (boxes side by side in adjacent lanes
    /// keep about 1.1–1.5 m on NGSIM roads).
    pub follower_clearance: f64,
}

/// The shape of the safety constraint b_i between the ego and one other vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum SafetyGeometry {
    /// b = ((Δx/a_x)² + (Δy/a_y)² − 1 with the semi-axes of [`crate::safety::Ellipse`]
    /// (`ellipse_scale` × the summed half extents of the bounding boxes + margins; unitless).
    #[default]
    Ellipse,
    /// b = the separating-axis distance of the two oriented boxes minus the clearance
    /// (`margin_x` along the road, `margin_y` across it, projected on the separating axis;
    /// m): [`crate::safety::box_separation`]. b > 0 exactly when the boxes grown by the
    /// margins do not overlap, so the ego may come as close sideways as `margin_y` while it
    /// is level with another vehicle. The clearance is a road-aligned rectangle, so while the
    /// ego is yawed by ψ it also widens the clearance across the ego by m_x·|sin ψ|.
    Boxes,
    /// As `Boxes`, but the clearance grows the ego's box in its own frame (`margin_x` at each
    /// end along its heading, `margin_y` at each side): b is the separating-axis distance of
    /// that grown box and the other vehicle's box (m), exact for two rectangles. The clearance
    /// follows the ego's heading: `margin_y` beside its sides, `margin_x` beyond its ends (so
    /// a yawed ego's extended ends still reach `margin_x`·|sin ψ| further across the road).
    GrownBoxes,
}

/// The default speed (m/s) from which the last-resort rules that rank or search against the
/// constant-velocity prediction apply (`lattice_min_speed` and `avoid_min_speed`), and of
/// `lead_min_speed` and `match_min_speed`.
const LAST_RESORT_MIN_SPEED: f64 = 10.0;

impl Default for PlannerSettings {
    fn default() -> Self {
        Self {
            horizon: 6,
            dt: 0.3,
            l_f: 1.4,
            l_r: 1.4,
            w_y: 15.0,
            w_deadline: 60.0,
            deadline_distance: 100.0,
            stop_decel: 3.0,
            stop_margin: 12.0,
            w_v: 3.0,
            w_psi: 1.0,
            w_delta: 3.0,
            w_ddelta: 3.0,
            w_a: 1.0,
            w_da: 1.0,
            rho: 1000.0,
            delta_max: 0.15,
            ddelta_max: 0.05,
            a_min: -5.0,
            a_max: 3.0,
            da_max: 1.5,
            v_max: 30.0,
            edge_margin: 0.0,
            v_lin_min: 1.0,
            ellipse_scale: std::f64::consts::SQRT_2,
            ellipse_lateral_scale: 0.0,
            margin_x: 1.5,
            margin_y: 0.3,
            brake_decel: 4.0,
            check_range: 60.0,
            safety_min: 0.0,
            plan_buffer: 0.0,
            max_iter: 30,
            eps_primal: 1e-2,
            eps_change: 1e-2,
            pgd_steps: 5,
            pgd_halvings: 3,
            hessian_scaled: true,
            pin_weight: 1e4,
            z_safe_step: false,
            z_step_margin: 0.01,
            z_cuts: 0,
            safe_start: false,
            z_retighten: 0,
            z_rollout_trial: false,
            relinearise: false,
            warm_start_dual: false,
            rollout_check: true,
            fallback_speed_floor: 0.5,
            fallback_brake_hold: false,
            fallback_full_accel: false,
            fallback_shy: false,
            fallback_match_speed: false,
            match_admissible_only: true,
            match_min_speed: LAST_RESORT_MIN_SPEED,
            fallback_lattice: true,
            lattice_clear_nonreactive: true,
            lattice_when_fallback_hits: false,
            lattice_min_speed: LAST_RESORT_MIN_SPEED,
            fallback_nonreactive: false,
            fallback_avoid_nonreactive: false,
            avoid_min_speed: LAST_RESORT_MIN_SPEED,
            lateral_drift: false,
            lateral_drift_min_speed: 0.25,
            edge_first: true,
            contact_first: true,
            lead_first: true,
            lead_min_speed: LAST_RESORT_MIN_SPEED,
            lead_in_lane: true,
            lead_keep_lane: true,
            bounds_first: true,
            bounds_slack: 0.05,
            restore_step: 1.0,
            ablate_reaction: false,
            heading_max: 0.2,
            heading_recovery: 0.05,
            heading_governor: true,
            overshoot_max: 0.3,
            refine_iters: 5,
            refine_margin: 0.02,
            refine_trust_delta: 0.05,
            refine_trust_accel: 2.0,
            budget_s: 0.0,
            budget_calls: 0,
            safety_geometry: SafetyGeometry::Ellipse,
            ego_segment_length: 6.0,
            contingency: false,
            contingency_accel: -2.0,
            contingency_steps: 3,
            follower_ttc: 0.0,
            follower_min_gap: 0.5,
            follower_clearance: 0.8,
        }
    }
}

/// The admissible range of one numeric setting: `min <= value <= max` (a bound marked open
/// excludes its end point). Integer settings use the same table (their values are exact in
/// f64).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldRange {
    /// Name of the field (as in the serde representation).
    pub field: &'static str,
    /// Lower bound.
    pub min: f64,
    /// Whether `min` itself is excluded.
    pub min_open: bool,
    /// Upper bound.
    pub max: f64,
    /// Whether `max` itself is excluded.
    pub max_open: bool,
    /// Unit, for messages and docs.
    pub unit: &'static str,
}

pub(crate) const fn closed(
    field: &'static str,
    min: f64,
    max: f64,
    unit: &'static str,
) -> FieldRange {
    FieldRange {
        field,
        min,
        min_open: false,
        max,
        max_open: false,
        unit,
    }
}

const fn open_min(field: &'static str, min: f64, max: f64, unit: &'static str) -> FieldRange {
    FieldRange {
        field,
        min,
        min_open: true,
        max,
        max_open: false,
        unit,
    }
}

impl FieldRange {
    /// Whether `v` lies in the range (NaN never does).
    #[must_use]
    pub fn contains(&self, v: f64) -> bool {
        let lo = if self.min_open {
            v > self.min
        } else {
            v >= self.min
        };
        let hi = if self.max_open {
            v < self.max
        } else {
            v <= self.max
        };
        lo && hi
    }
}

/// A number for messages: plain for ordinary magnitudes, scientific for huge or tiny ones.
pub(crate) fn show(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && a.is_finite() && !(1e-3..1e6).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl std::fmt::Display for FieldRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}{}, {}{}{}{}",
            if self.min_open { '(' } else { '[' },
            show(self.min),
            show(self.max),
            if self.max_open { ')' } else { ']' },
            if self.unit.is_empty() { "" } else { " " },
            self.unit
        )
    }
}

/// Weight bound: a quadratic weight above 1e6 only rescales the cost into ill-conditioning.
const W_MAX: f64 = 1e6;

/// Every numeric setting's admissible range, in field order. Physical quantities are bounded
/// by what a road vehicle can do (speeds ≤ 60 m/s, accelerations within ±15 m/s², wheelbase
/// halves 0.5–5 m, steering below 1.5 rad), counts by what one planning step may do, and
/// tolerances by what is meaningful in f64. The shipped defaults lie well inside each range.
/// `a_max` must also exceed `a_min` (checked after the ranges).
pub const RANGES: &[FieldRange] = &[
    closed("horizon", 1.0, nudge_predictor::MAX_HORIZON as f64, "steps"),
    closed("dt", 0.01, 1.0, "s"),
    closed("l_f", 0.5, 5.0, "m"),
    closed("l_r", 0.5, 5.0, "m"),
    closed("w_y", 0.0, W_MAX, "1/m²"),
    closed("w_deadline", 0.0, W_MAX, "1/m²"),
    open_min("deadline_distance", 0.0, 1e4, "m"),
    open_min("stop_decel", 0.0, 15.0, "m/s²"),
    closed("stop_margin", 0.0, 1e3, "m"),
    closed("w_v", 0.0, W_MAX, "s²/m²"),
    closed("w_psi", 0.0, W_MAX, "1/rad²"),
    closed("w_delta", 0.0, W_MAX, "1/rad²"),
    closed("w_ddelta", 0.0, W_MAX, "1/rad²"),
    closed("w_a", 0.0, W_MAX, "s⁴/m²"),
    closed("w_da", 0.0, W_MAX, "s⁴/m²"),
    closed("rho", 1e-6, 1e8, ""),
    FieldRange {
        field: "delta_max",
        min: 0.0,
        min_open: true,
        max: 1.5,
        max_open: true,
        unit: "rad",
    },
    open_min("ddelta_max", 0.0, 1.5, "rad per step"),
    FieldRange {
        field: "a_min",
        min: -15.0,
        min_open: false,
        max: 15.0,
        max_open: true,
        unit: "m/s²",
    },
    open_min("a_max", -15.0, 15.0, "m/s²"),
    open_min("da_max", 0.0, 30.0, "m/s² per step"),
    open_min("v_max", 0.0, 60.0, "m/s"),
    closed("edge_margin", 0.0, 5.0, "m"),
    open_min("v_lin_min", 0.0, 10.0, "m/s"),
    closed("ellipse_scale", 1.0, 4.0, ""),
    closed("ellipse_lateral_scale", 0.0, 4.0, ""),
    closed("margin_x", 0.0, 20.0, "m"),
    closed("margin_y", 0.0, 5.0, "m"),
    closed("ego_segment_length", 0.0, 100.0, "m"),
    closed("brake_decel", 0.0, 15.0, "m/s²"),
    closed(
        "check_range",
        0.0,
        nudge_predictor::limits::MAX_AGENT_OFFSET,
        "m",
    ),
    closed("safety_min", 0.0, 10.0, "units of b"),
    closed("plan_buffer", 0.0, 10.0, "units of b"),
    closed(
        "max_iter",
        1.0,
        PlannerSettings::MAX_ITER as f64,
        "iterations",
    ),
    closed("eps_primal", 1e-9, 1.0, ""),
    closed("eps_change", 1e-9, 1.0, ""),
    closed("pgd_steps", 1.0, 100.0, "steps"),
    closed("pgd_halvings", 0.0, 30.0, "halvings"),
    closed("pin_weight", 0.0, 1e8, "1/m²"),
    closed("z_step_margin", 0.0, 10.0, "units of b"),
    closed("z_cuts", 0.0, 8.0, "cuts"),
    closed("z_retighten", 0.0, 10.0, "re-tightenings"),
    closed("fallback_speed_floor", 0.0, 1.0, "–"),
    closed("lattice_min_speed", 0.0, 100.0, "m/s"),
    closed("avoid_min_speed", 0.0, 100.0, "m/s"),
    closed("lead_min_speed", 0.0, 100.0, "m/s"),
    closed("match_min_speed", 0.0, 100.0, "m/s"),
    closed("lateral_drift_min_speed", 0.0, 10.0, "m/s"),
    closed(
        "bounds_slack",
        0.0,
        10.0,
        "m, rad, m/s (Σ over the horizon)",
    ),
    open_min("restore_step", 0.0, 10.0, "m"),
    open_min("heading_max", 0.0, 10.0, "rad"),
    open_min("heading_recovery", 0.0, 1.5, "rad per step"),
    closed("overshoot_max", 0.0, 100.0, "m"),
    closed("refine_iters", 0.0, 20.0, "iterations"),
    closed("refine_margin", 0.0, 10.0, "units of b"),
    open_min("refine_trust_delta", 0.0, 1.5, "rad"),
    open_min("refine_trust_accel", 0.0, 30.0, "m/s²"),
    closed("budget_s", 0.0, 3600.0, "s"),
    closed("budget_calls", 0.0, 1e9, "predictor calls"),
    closed("contingency_accel", -15.0, 0.0, "m/s²"),
    closed(
        "contingency_steps",
        1.0,
        nudge_predictor::MAX_HORIZON as f64,
        "steps",
    ),
    closed("follower_ttc", 0.0, 30.0, "s"),
    closed("follower_min_gap", 0.0, 50.0, "m"),
    closed("follower_clearance", 0.0, 5.0, "m"),
];

impl PlannerSettings {
    /// Largest horizon accepted (steps): the predictors' [`nudge_predictor::MAX_HORIZON`].
    pub const MAX_HORIZON: usize = nudge_predictor::MAX_HORIZON;
    /// Largest ADMM iteration count accepted.
    pub const MAX_ITER: usize = 10_000;
    /// Shortest non-zero `ego_segment_length` accepted (m): finer slices than this add safety
    /// evaluations, not accuracy (the ellipse's margins are tens of centimetres).
    pub const MIN_EGO_SEGMENT_LENGTH: f64 = 0.5;
    /// Most slices one ego may be cut into (`ego_segment_length`): a plausible 30 m vehicle
    /// in slices of [`Self::MIN_EGO_SEGMENT_LENGTH`] needs 60. A longer ego is a
    /// [`crate::PlannerError::BadProblem`] naming `sizes`.
    pub const MAX_EGO_SEGMENTS: usize = 64;

    /// The value of numeric field `field` as f64 (`None` for a boolean or unknown name).
    #[must_use]
    pub fn numeric(&self, field: &str) -> Option<f64> {
        Some(match field {
            "horizon" => self.horizon as f64,
            "dt" => self.dt,
            "l_f" => self.l_f,
            "l_r" => self.l_r,
            "w_y" => self.w_y,
            "w_deadline" => self.w_deadline,
            "deadline_distance" => self.deadline_distance,
            "stop_decel" => self.stop_decel,
            "stop_margin" => self.stop_margin,
            "w_v" => self.w_v,
            "w_psi" => self.w_psi,
            "w_delta" => self.w_delta,
            "w_ddelta" => self.w_ddelta,
            "w_a" => self.w_a,
            "w_da" => self.w_da,
            "rho" => self.rho,
            "delta_max" => self.delta_max,
            "ddelta_max" => self.ddelta_max,
            "a_min" => self.a_min,
            "a_max" => self.a_max,
            "da_max" => self.da_max,
            "v_max" => self.v_max,
            "edge_margin" => self.edge_margin,
            "v_lin_min" => self.v_lin_min,
            "ellipse_scale" => self.ellipse_scale,
            "ellipse_lateral_scale" => self.ellipse_lateral_scale,
            "margin_x" => self.margin_x,
            "margin_y" => self.margin_y,
            "ego_segment_length" => self.ego_segment_length,
            "brake_decel" => self.brake_decel,
            "check_range" => self.check_range,
            "safety_min" => self.safety_min,
            "plan_buffer" => self.plan_buffer,
            "max_iter" => self.max_iter as f64,
            "eps_primal" => self.eps_primal,
            "eps_change" => self.eps_change,
            "pgd_steps" => self.pgd_steps as f64,
            "pgd_halvings" => self.pgd_halvings as f64,
            "pin_weight" => self.pin_weight,
            "z_step_margin" => self.z_step_margin,
            "z_cuts" => self.z_cuts as f64,
            "z_retighten" => self.z_retighten as f64,
            "fallback_speed_floor" => self.fallback_speed_floor,
            "lattice_min_speed" => self.lattice_min_speed,
            "avoid_min_speed" => self.avoid_min_speed,
            "lead_min_speed" => self.lead_min_speed,
            "match_min_speed" => self.match_min_speed,
            "lateral_drift_min_speed" => self.lateral_drift_min_speed,
            "bounds_slack" => self.bounds_slack,
            "restore_step" => self.restore_step,
            "heading_max" => self.heading_max,
            "heading_recovery" => self.heading_recovery,
            "overshoot_max" => self.overshoot_max,
            "refine_iters" => self.refine_iters as f64,
            "refine_margin" => self.refine_margin,
            "refine_trust_delta" => self.refine_trust_delta,
            "refine_trust_accel" => self.refine_trust_accel,
            "budget_s" => self.budget_s,
            "budget_calls" => self.budget_calls as f64,
            "contingency_accel" => self.contingency_accel,
            "contingency_steps" => self.contingency_steps as f64,
            "follower_ttc" => self.follower_ttc,
            "follower_min_gap" => self.follower_min_gap,
            "follower_clearance" => self.follower_clearance,
            _ => return None,
        })
    }

    /// Checks every field against [`RANGES`], then `a_max > a_min`.
    ///
    /// # Errors
    /// [`SettingsError::Invalid`] naming the first field out of its range (NaN and infinity
    /// never are in range), with the range in the message.
    pub fn validate(&self) -> Result<(), SettingsError> {
        for r in RANGES {
            let v = self.numeric(r.field).unwrap_or(f64::NAN);
            if !r.contains(v) {
                return Err(SettingsError::OutOfRange {
                    field: r.field,
                    value: v,
                    range: *r,
                });
            }
        }
        if self.a_max <= self.a_min {
            return Err(SettingsError::Invalid {
                field: "a_max",
                value: format!("{}", self.a_max),
                reason: "must be > a_min (empty acceleration bounds)",
            });
        }
        if self.ego_segment_length != 0.0 && self.ego_segment_length < Self::MIN_EGO_SEGMENT_LENGTH
        {
            return Err(SettingsError::Invalid {
                field: "ego_segment_length",
                value: format!("{}", self.ego_segment_length),
                reason: "must be 0 (off) or at least MIN_EGO_SEGMENT_LENGTH = 0.5 m",
            });
        }
        if self.ellipse_lateral_scale != 0.0
            && self.ellipse_lateral_scale <= self.ellipse_scale / std::f64::consts::SQRT_2
        {
            return Err(SettingsError::Invalid {
                field: "ellipse_lateral_scale",
                value: format!("{}", self.ellipse_lateral_scale),
                reason: "must be 0 or > ellipse_scale / √2 (no longitudinal scale keeps the \
                         ellipse's reach otherwise)",
            });
        }
        Ok(())
    }

    /// Parses a JSON object (missing fields default; unknown and repeated fields rejected) and
    /// validates.
    ///
    /// # Errors
    /// [`SettingsError::Invalid`] with field `"<json>"` when the text is not a JSON object
    /// (serde would otherwise read an array positionally: `[7, 0.5]` as horizon and dt) or
    /// does not parse, otherwise as [`Self::validate`].
    pub fn from_json(text: &str) -> Result<Self, SettingsError> {
        let not_json = |e: serde_json::Error| SettingsError::Invalid {
            field: "<json>",
            value: e.to_string(),
            reason: "not valid planner settings JSON",
        };
        // A repeated key is an error naming it (serde_json would keep the last one).
        let value = nudge_predictor::json::parse(text).map_err(not_json)?;
        if !value.is_object() {
            return Err(SettingsError::Invalid {
                field: "<json>",
                value: json_kind(&value).to_owned(),
                reason: "planner settings must be a JSON object of named fields",
            });
        }
        // Parsed again from the text (not the value) so that a repeated key is an error.
        let s: Self = serde_json::from_str(text).map_err(not_json)?;
        s.validate()?;
        Ok(s)
    }

    /// Reads a settings JSON file (a regular file of at most [`MAX_SETTINGS_BYTES`]) and
    /// parses it as [`Self::from_json`].
    ///
    /// # Errors
    /// [`SettingsError::File`] when the file cannot be read or is not a regular file of
    /// bounded size (message names the file), otherwise as [`Self::from_json`].
    pub fn from_file(path: impl AsRef<std::path::Path>) -> Result<Self, SettingsError> {
        let path = path.as_ref();
        let bytes = nudge_predictor::file::read_bounded(path, MAX_SETTINGS_BYTES)
            .map_err(|e| SettingsError::File(e.to_string()))?;
        let text = String::from_utf8(bytes)
            .map_err(|e| SettingsError::File(format!("{}: not UTF-8 text: {e}", path.display())))?;
        Self::from_json(&text)
    }
}
