//! The ADMM MPC of the paper's Algorithm 1. One call of [`Planner::plan`] is
//!
//! 1. **set-up** ([`linearised`]): the nominal trajectory (the shifted previous plan), the
//!    dynamics linearised around it, the bounds, the checked vehicles ([`constraint`]), the
//!    start of the iterates (the nominal, or the best safe simple candidate when it is unsafe,
//!    [`start`]), and a workspace allocated once for the call ([`workspace`]);
//! 2. **the ADMM loop**, until ‖F‖∞ ≤ eps_primal and ‖Z − Z_prev‖∞ ≤ eps_change or `max_iter`:
//!    the re-linearisation around the current inputs and their roll-out
//!    ([`LinearisedProblem::relinearise`]), the Δ-update and α-update (box/rate QPs solved
//!    by Clarabel, [`inputs`]), the Z-update (projected descent whose every trial point is
//!    checked by the predictor, [`z_update`], the linearised-safety step [`safe_step`]
//!    and the projection onto the linearised safe set [`projection`] among them, with
//!    feasibility restoration from an unsafe Z, [`restoration`]), and the
//!    dual update μ ← μ + ρF; a converged loop whose roll-out is unsafe may go on inside a
//!    raised threshold ([`retighten`]);
//! 3. **the execution check** ([`repair`]): the nonlinear roll-out of (Δ, α) is checked by
//!    the predictor and repaired (backtracking, then simple fallbacks) when unsafe; a QP
//!    failure goes straight to the fallbacks.
//!
//! The solution warm-starts the next call. [`Planner::reference_qp`] solves the same
//! linearised problem as one joint QP ([`reference`]).

mod constraint;
mod heading;
mod inputs;
mod linearised;
mod problem;
mod reference;
mod refine;
mod repair;
mod restoration;
mod workspace;
mod z_update;

#[cfg(test)]
mod ablation_tests;
#[cfg(test)]
mod lead_first_tests;
#[cfg(test)]
mod tests;

use std::time::Instant;

use nudge_predictor::{Checked, ConstantVelocity, Predictor};

use crate::error::PlannerError;
use crate::model::{Bicycle, State};
use crate::qp::QpFailure;
use crate::settings::PlannerSettings;

pub use constraint::{BindingVehicle, CheckedVehicle, PairGeometry, SafetyConstraint};
pub use problem::{
    DecidedBy, EgoState, PhaseTimings, Plan, PlanStatus, PlanningProblem, StepStatus,
};
pub use reference::JointSolution;
pub use repair::{Family, RANK_ORDER, RankKey};

use constraint::{Budget, SafetyEval};
use inputs::Input;
use inputs::InputQps;
use linearised::{LinearisedProblem, WarmStart};
use repair::{Candidate, Repairer};
use workspace::{CurrentSafety, Iterates, Workspace, max_abs};

/// The ADMM MPC planner of the paper's Algorithm 1. One call of [`Planner::plan`] is
///
/// 1. **set-up**: the nominal trajectory (the shifted previous plan, constant velocity on a
///    cold start), the dynamics linearised around it, the input and state bounds, the
///    vehicles the safety constraint checks ([`SafetyConstraint`]), and a workspace allocated
///    once for the call;
/// 2. **the ADMM loop**, until ‖F‖∞ ≤ `eps_primal` and ‖Z − Z_prev‖∞ ≤ `eps_change` or
///    `max_iter`: the re-linearisation around the current inputs (`relinearise`), the
///    Δ-update and the α-update (box/rate QPs solved by Clarabel), the Z-update (projected
///    descent on G whose every trial point, the roll-out of the inputs and the
///    linearised-safety step among them, is checked by the predictor; feasibility
///    restoration from an unsafe Z), the dual update μ ← μ + ρF;
/// 3. **the execution check**: the nonlinear roll-out of (Δ, α), which is what the vehicle
///    does and what the plan's states always are (its steering first governed to the heading
///    bound, `heading_governor`), must be *admissible*: safe by the predictor
///    (b > `safety_min` at every step, with the closing-speed margin `brake_decel` at the
///    last), within the heading bound `heading_max` relative to the road, within the lateral
///    corridor between the start and the target widened by `overshoot_max`, and with every
///    corner of the ego's box on the road. When it is not, **the refinement** takes up to
///    `refine_iters` sequential-QP steps on the nonlinear model ([`PlanStatus::Refined`]),
///    and only then the repairs ([`PlanStatus::Backtracked`], [`PlanStatus::Fallback`]); a
///    QP failure goes straight to the fallbacks ([`PlanStatus::SolverFailed`]).
///
/// **Convergence by design.** Only the ADMM's own iterate whose nonlinear roll-out is
/// admissible (checked by the predictor, within the state bounds) is [`PlanStatus::Converged`]
/// (or [`PlanStatus::MaxIterations`] when the loop stopped at `max_iter`); every repair keeps
/// its own status. Measured on validation scenes (student planner, teacher world, 269 scenes,
/// 3802 steps), the steps that did not end `Converged` failed because (1) the loop reached
/// `max_iter` in 63 % of the steps, in 96 % of those with Z frozen on the safety boundary:
/// every Newton trial crossed it, so the Z-update stalled while F stayed above `eps_primal`;
/// (2) the nominal (shifted previous plan) was already unsafe in 28 %; (3) in 10 % ADMM
/// converged but its roll-out, off Z by a median 0.07 m, left the safe set or the state
/// bounds. The loop therefore has four rules, each a setting (off by default, see below):
///
/// * `z_safe_step`: the Z-update tries G's minimiser under the safety rows of Z linearised in
///   the ego's position, so Z slides along the boundary instead of stalling on it;
/// * `z_rollout_trial`: its first trial is the nonlinear roll-out of the current (Δ, α), where
///   F is the linearisation error alone;
/// * `relinearise`: the dynamics are linearised again around the current inputs and their
///   roll-out at every iteration (a sequential-convex ADMM), so F measures Z's distance from
///   the nonlinear roll-out rather than from the roll-out of the first linearisation;
/// * `plan_buffer` = 0.03: Z is kept that far inside the safe set, the measured drop of b from
///   Z to the roll-out of converged calls (10th percentile −0.03).
///
/// Together (`{"z_safe_step": true, "z_rollout_trial": true, "relinearise": true,
/// "plan_buffer": 0.03}`), on the same validation runs: `Converged` 23.1 % → 44.5 % of the steps, Fallback
/// 7.2 → 5.3 %, Unsafe 9.2 → 7.1 %, success 253 → 257 of 269, no collision (teacher planner,
/// 80 scenes: 24.1 → 40.2 %, success 73 → 72; IDM and log-replay worlds alike,
/// `docs/results/latency.md`); without one of them (the others on) 41.1 % (no re-linearisation),
/// 37.6 % (no roll-out trial), 39.4 % (no safe step), 31.9 % (`plan_buffer` 0). What still
/// keeps the share below 90 %: the loop reaches `max_iter` in 44 % of the steps (82 % of those
/// with Z frozen on the tightened boundary, and 44 % from an unsafe nominal), and the
/// converged Z still differs from its roll-out by a median 0.07 m (F ≤ `eps_primal` per step
/// compounds over the horizon). The steps cost more: student p50 10.9 → 16.1 ms, p99 37.8 →
/// 59.3 ms on that machine (more predictor calls per Z-update).
///
/// **Projection, safe start and re-tightening** (`z_cuts`, `safe_start`, `z_retighten`; off by
/// default). With the rules on, on the curvilinear-frame validation split (300 of its 713
/// scenes, the seeds of `nudge-train closed-loop --seed 0`, student planner, teacher world),
/// the loop still stopped at `max_iter` with an inadmissible roll-out in 38 % of the steps.
/// Two causes, two rules:
///
/// * Z stuck on the tightened boundary. The Newton step's halvings stop Z where the first
///   halving is safe, on the boundary along the one direction of the unconstrained minimiser;
///   the safe step, whose rows hold the prediction fixed, lands outside the boundary when the
///   other vehicles react to the new Z (or the ellipse turns with the ego's heading), and
///   its trial point was then halved back along the same direction, or clamped by the state
///   bounds back onto the unsafe point. With `z_cuts` the Z-update tries, right after the
///   full Newton step, the **projection onto the linearised safe set**
///   (module `projection`): G's minimiser subject to the safety rows of Z, the state bounds as
///   rows (so the step needs no clamping), and, when the predictor finds the trial point
///   unsafe, the cuts of that trial point (its violated rows linearised there, under its own
///   prediction), solved again up to `z_cuts` times; only then the halvings.
/// * An unsafe start. With `safe_start` a nominal whose Z is unsafe is replaced by the best
///   safe simple candidate (keep lane or steer towards the goal at a constant acceleration,
///   least cost J; module `start`), instead of starting in the feasibility restoration.
///
/// Measured (validation, 300 scenes, paired; `docs/results/latency.md`), defaults → the rules
/// → the rules with `z_cuts` 3 and `safe_start`: `Converged` 21.5 → 39.0 → 46.4 % of the
/// steps (teacher world), 24.9 → 39.8 → 47.1 % (IDM), 20.7 → 35.1 → 41.8 % (log replay);
/// loop at `max_iter` with an inadmissible roll-out 51.7 → 38.2 → 26.2 % (teacher world);
/// Fallback 8.4 → 6.5 → 5.7 %; success 256 → 258 → 261, 262 → 267 → 265, 257 → 253 → 258 of
/// 300; at-fault collision events 0 → 0 → 0, 0 → 1 → 1 (one IDM run, the same with the rules
/// alone), 3 → 2 → 2; the teacher planner (teacher world, 60 scenes) 23.4 → 42.3 → 54.6 %,
/// success 55 → 52 → 54 of 60, no at-fault event. On their own account (teacher world, with the rules): the projection
/// 45.1 %, the safe start 42.7 %; the projection and the safe start without the other rules
/// 32.0 %. More loops now converge with an inadmissible roll-out (13.7 → 20.8 %: Z on the
/// boundary, the roll-out just outside it); `z_retighten` 2 (the Z-update's threshold raised
/// by the roll-out's drop from Z when a converged loop's roll-out is unsafe, and the loop
/// goes on; module `retighten`) halves that class (20.8 → 9.9 %) but sends more loops to
/// `max_iter` (26.2 → 33.0 %): `Converged` 46.4 → 48.3 %, success 261 → 259, Fallback
/// 5.7 → 6.7 %. **What bounds the share**: in 12.3 % of the steps (teacher world; 12.1 % IDM,
/// 19.5 % log replay) no candidate at all is admissible (`Unsafe`: the fallbacks and the
/// refinement find none either), so no rule of the optimiser can make those steps
/// `Converged`; 90 % needs the problem itself to change for them (a relaxed, least-violation
/// problem with its own status), not a better loop.
///
/// **Why the rules are off by default.** With them the planner finds admissible plans where
/// it found none before, and the lane-change abort of [`crate::lane`], which fires after
/// consecutive steps *without* an admissible plan, no longer fires in front of a closed convoy
/// in the log-replay world: the ego edges over the lane line with admissible plans and idles
/// there, the behaviour that abort exists to prevent
/// (`blocked_target_lane_aborts_instead_of_idling_across_the_boundary`). The closed loop's
/// stalled-change abort ([`crate::SimConfig::stall_progress`], 0.05 m per step with the rules)
/// closes that gap: a step whose ego moved less than that towards the target lane while its
/// box straddles the line, before the crossing, counts towards the abort like a step without
/// an admissible plan. With it, paired on the validation scenes (269 scenes, one run each, the
/// seeds of `nudge-train closed-loop --seed 0`; the teacher planner on its 60-scene subset),
/// the rules lose no success and add no collision in any world (student planner: teacher
/// world 252 → 255, 5 lost / 8 gained, McNemar p = 0.58; IDM 253 → 257, 5 / 9, p = 0.42;
/// log replay 252 → 254, 0 / 2, p = 0.5; at-fault collision events 0 → 0, 1 → 1, 0 → 0;
/// teacher planner, teacher world: 57 → 58 of 60, 1 / 2) and raise `Converged` from 23.0 to
/// 44.3 % (teacher world), 28.8 → 48.4 % (IDM), 24.4 → 42.0 % (log replay), 28.1 → 47.2 %
/// (teacher planner). They stay off by default because the test split has not been run with
/// them (the note in `docs/results/latency.md` has the commands), and because they are not
/// the cure for what is left: in the teacher world with the rules on, 34.8 % of the steps end
/// with the loop at `max_iter` and an inadmissible roll-out (Z frozen on the tightened
/// boundary, or an unsafe nominal), 11.2 % with a converged loop whose roll-out is
/// inadmissible, and 9.7 % at `max_iter` with an admissible roll-out (ρ adaptation and a
/// convergence test on the roll-out were not tried).
///
/// **The refinement.** When the ADMM roll-out is not admissible, the refinement works on the
/// nonlinear model directly: single shooting in the inputs with the roll-out's sensitivities,
/// the safety rows linearised at the current roll-out with its own prediction (re-predicted
/// after every step) and tightened by `refine_margin`, elastic rows so every step is defined,
/// and a trust region. The refinement's answer is checked like everything else; the repairs
/// remain as the last resort and are counted by status.
///
/// **Retreat.** When neither the refinement nor backtracking finds an admissible plan, the
/// fallbacks also steer back to [`PlanningProblem::y_retreat`] (the lane the ego came from),
/// checked within the corridor of a plan aiming there, but only when the best plan towards the
/// target is unsafe by the prediction: the minimum-risk choice between holding, finishing and
/// cancelling a lane change is then the least-violating. The simulator offers the retreat
/// before the ego's centre crosses the line between the lanes, and after it only while the
/// ego is stuck across the line ([`crate::lane::LaneChange::retreat`]: `abort_after`
/// consecutive steps without an admissible plan, not yet inside the target lane). Measured on
/// validation (269 scenes × 3 seeds, student): the retreat before the crossing cut at-fault
/// collisions in the IDM world 5 → 3 and planned slow steps in 15–46 → 8–34 runs, success
/// unchanged in every world; offering it after every crossing removed 4 of 5 log-replay
/// at-fault collisions but cost 2.3 pp of success in the teacher's world (p = 0.007), so it
/// is not done. Offering it after the crossing only when stuck (an ego holding a straddle in
/// front of a target-lane follower that never yields) cut log-replay at-fault events 5 → 2
/// (student) and 9 → 6 (teacher planner, 60 scenes) with success unchanged in every world
/// (2 of 807 pairs discordant, p = 0.5). The remaining validation cases: a follower that
/// never yields hits an ego that slowed down during aborted attempts; lane changes begun with
/// almost no margin (b < 0.02) next to a target-lane vehicle that the IDM world moves
/// differently from the prediction. Test split: `docs/results/closed_loop.md`.
///
/// **Speed floor** (`fallback_speed_floor`, 0.5 by default). The √2 ellipse reaches 3.4–3.5 m
/// across the road for two cars, about one lane: a vehicle passing in the next lane, both
/// centred in their lanes, makes every candidate inadmissible, and the least total violation
/// was braking at a_min, a planned standstill in a live lane (on validation, student planner,
/// 300 scenes × 3 seeds: the planned-slow steps of the idm and log-replay worlds were almost
/// all `Unsafe` steps of this kind). With the floor, an inadmissible candidate whose only
/// violations come from vehicles beside the ego ([`SafetyConstraint::beside`]: their boxes
/// cannot touch at any offset along the road), within the state bounds, and ending at or
/// above the floor × `v_ref` beats the others; every other case ranks as before (a vehicle
/// in the ego's path still brakes it). Ranking by the violation in the path first (instead of
/// this one class) or choosing by cost among the clear ones was tried and raised the
/// log-replay at-fault collisions (8 → 13 and 20 of 900 runs: a truck ego's swinging tail, and
/// logged drivers drifting into an ego that accelerated beside them). Measured on those
/// validation runs, paired with the floor off (student planner, 900 runs per world, teacher /
/// idm / log replay): runs slow in a live lane (executed) 0 / 4 / 6 → 0 / 0 / 0, planned
/// 8 / 10 / 25 → 4 / 3 / 12; success 86.0 → 85.3 (7 runs lost, 1 gained), 89.4 → 89.8,
/// 84.4 → 84.8 %; at-fault collisions 0 → 0, 1 → 1, 8 → 8 (the same events). Teacher planner,
/// log replay, 100 scenes × 3: success 89.0 → 88.7 %, 0 at-fault collisions either way, slow
/// runs 3 → 0 (planned 12 → 4).
///
/// **Long egos, contact and the road edge** (`ego_segment_length` 6 m, `contact_first`,
/// `edge_first`; the defaults together with `bounds_first`, below: alone they failed the test
/// split). The √2 ellipse of a 19.8 m truck and a car reaches 18.7 m
/// along the road where the boxes touch at 12.2 m, so a car 20 m ahead in the truck's lateral
/// position made every plan inadmissible (validation, `us101-2_1-t06.6-ego513`). Cut into
/// slices of at most 6 m ([`crate::safety::Ellipse::sliced`]) the ellipses still exclude
/// overlap (the slices' union is the box) and reach 15.6 m. Slicing alone let the
/// least-violating fallback steer the truck away from the cars ahead and behind and swing its
/// tail into a car beside it (student planner on the 15 drawn validation scenes with an ego
/// of 6 m or more, × 3 seeds: at-fault runs 0 → 5 in the teacher world), because the
/// total violation weighs a margin violation like a contact; with `contact_first` a fallback
/// predicted to overlap another vehicle's box less (separating-axis depth, m) wins first,
/// and with `edge_first` one whose box's corners reach less far beyond the road's edges
/// wins next (the 6.1 m truck `us101-2_1-t02.7-ego500`, starting 0.62 m over the edge, left
/// the road by 0.008 m beyond the allowance when its fallback steered towards the road and
/// swung its rear corner out). Measured together on validation (300 scenes × 3 seeds,
/// teacher planner on 100; paired with the three off): success teacher world 85.3 → 85.3 %
/// (student) and 86.7 → 87.7 % (teacher planner), idm 89.8 → 89.9 / 93.0 → 93.0 %, log
/// replay 84.8 → 85.3 / 88.7 → 88.7 %, no world losing more than one run and none more than
/// it gained (lost / gained 0 / 0, 0 / 3, 1 / 2, 1 / 1, 0 / 5, 0 / 0); at-fault runs in log
/// replay 8 → 5 (student: the truck starting across the line, `t04.5-ego513`, no longer hit),
/// 0 → 0 elsewhere; off-road runs of the teacher planner 3 → 0 in every world. The long-ego
/// failures of the student in the teacher world stay (37 runs): those trucks ride beside a
/// target-lane car of their own speed, which no geometry lets them pass. The test split, run
/// once with the three on (300 scenes × 3 seeds, teacher planner on 150), confirmed the other
/// worlds (teacher 88.8 → 88.6 / 88.7 → 88.4 %, idm 91.8 → 92.1 / 90.9 → 91.8 %, no at-fault
/// collision) but not log replay: student at-fault runs 6 → 7, off-road runs 0 → 5 (student)
/// and 0 → 1 (teacher planner), the heading bound broken (0.46 and 0.445 rad), all on cars
/// (3.7–6.1 m): with `contact_first` above the state bounds, a fallback that is predicted to
/// touch nobody beats one within the heading bound and on the road, so a squeezed car swerved
/// across a lane (`us101-11_1-t03.0-ego135`: 7.9 m beyond the target lane's centre). So the
/// three alone did not become the defaults (`docs/results/long_egos.md`).
///
/// **Contact within the state bounds** (`bounds_first` with `bounds_slack` 0.05: the defaults,
/// with the three long-ego settings). Among candidates of
/// which none is admissible, each rule below decides only on a tie of those before it:
/// 1. within the state bounds beats outside them: the roll-out's state-bound excess (heading
///    relative to the road, the lateral corridor of the lane change, speed, the box's corners
///    beyond the road's edges, lane extents and the lane-end stopping rule: the excess the
///    total violation weighs) is at most `bounds_slack` (default 0.05; 0: none, up to
///    rounding) (`bounds_first`);
/// 2. the smaller predicted box overlap (`contact_first`);
/// 3. the smaller road-edge excess (`edge_first`);
/// 4. no centre in a lane before it begins; the speed floor's clear path; the smaller total
///    violation (as without these settings).
///
/// The state bounds are what the planner promises about its own motion whatever the
/// prediction says; predicted contact is a prediction, and in log replay, where nobody
/// reacts, the swerve that the prediction saw touching nobody took a car past the heading
/// bound, across a lane and off the road. Ranked after the bounds, contact still decides
/// between fallbacks on the same side of them, which keeps the squeezed truck's tail off the
/// car beside it (its least-contact fallback is within the bounds). The follower-gap rule is
/// not a state bound: it counts in the total violation only. Measured on validation with the
/// three long-ego settings (300 scenes × 3 seeds, teacher planner on 100; paired with the
/// shipped defaults): success teacher world 85.3 → 85.3 / 86.7 → 88.3 % (student / teacher
/// planner), idm 89.8 → 89.8 / 93.0 → 93.0 %, log replay 84.8 → 85.3 / 88.7 → 88.7 %; the
/// teacher planner's off-road runs 3 → 0 in every world; max |ψ| 0.200 rad before and after
/// (validation has no swerve past the bound); but at-fault runs 0 → 2 (teacher world),
/// 1 → 3 (idm), 8 → 7 (log replay; `contact_first` without the rule: 0, 1, 5), all the
/// 19.8 m truck `us101-2_1-t04.5-ego513`: its contact-free fallbacks leave its lateral band by
/// 1.5 cm (Σ over the horizon), and the yes-or-no test weighs that like a swerve, so the
/// rule picks a turn into the car beside it. With `bounds_slack` 0.05 (an excess up to it
/// counts as within; the test split's swerves were 0.46 rad and 7.9 m) the same validation
/// runs give success 85.3 / 87.7 %, 89.9 / 93.0 %, 85.1 / 88.7 %, at-fault runs 0, 1, 5 (the
/// truck no longer hit), the teacher planner's off-road runs 0, max |ψ| 0.200 rad. On the test
/// split, once (300 scenes × 3 seeds, teacher planner on 150): no world loses success (every
/// paired interval includes 0), log-replay at-fault runs 6 → 5 (student) and 7 → 4 (teacher
/// planner), 0 elsewhere, 0 off-road runs and max |ψ| 0.200 rad as with the previous
/// defaults. So the five settings (6 m slices, `bounds_first`, `bounds_slack` 0.05,
/// `contact_first`, `edge_first`) are the defaults, and every figure that depends on the
/// planner was regenerated with them (`docs/results/long_egos.md`,
/// `docs/results/closed_loop.md`, `docs/paper`).
///
/// **The heading governor** (`heading_governor`, on by default). The ADMM iterates keep the
/// heading bound on the linearised dynamics only; the roll-out of their inputs could pass it
/// by a few milliradians. That sent a plan that was safe by the prediction to the repairs,
/// and when nothing was admissible `bounds_slack` let the least-violating plan keep the
/// excess. On the test split one run of 4050 went to 0.2011 rad. Every candidate's steering
/// now goes through the governor before its roll-out is checked. At each step it takes the
/// steering nearest to the candidate's, within the box and rate bounds, from which unwinding
/// the steering as fast as the rate allows, at the fastest speeds `a_max` allows, keeps the
/// heading within the bound for the rest of the horizon on the exact model (looking ahead,
/// because a turn can be within the bound after this step and past stopping before it; at the
/// fastest speeds, because the next planning step may brake less than this candidate: with
/// the candidate's own accelerations a train-split run reached 0.2010 rad); a sequence every
/// step of which passes this test is unchanged, bit for bit.
/// Measured on validation (300 scenes × 3 seeds, teacher planner on 100; paired with it off):
/// * success rose in five of six arms: teacher world 85.3 → 86.4 / 87.7 → 90.0 % (student /
///   teacher planner), idm 89.9 → 90.4 / 93.0 → 92.3 %, log replay 85.1 → 86.4 /
///   88.7 → 89.7 %;
/// * no collision was added; the student's log-replay at-fault runs went 5 → 0, knock-on
///   changes of near misses;
/// * the optimiser's own plan (`Converged` + `MaxIterations`) rose by 2.9–5.4 pp of the steps.
///
/// A first version without the look-ahead passed validation too but broke the bound twice on
/// the test split (0.2054 and 0.2002 rad); both runs and the test split's numbers are in
/// `docs/results/heading_governor.md`.
///
/// **Safety geometry and contingency** (`safety_geometry`, `contingency`; both off by
/// default). The √2 ellipse couples the two directions: it keeps the boxes apart at every
/// angle, so while a target-lane vehicle is level with the ego it asks for 2.85 m between the
/// centres across the road where the boxes need 1.8–1.9 m, and its bumper gap on the axis is
/// 3.4–3.6 m; the ego's near edge stays about 0.4 m short of the lane line (median, dense
/// starts) while the fitted idm followers yield only once it is 0.7 m inside their lane.
/// `SafetyGeometry::Boxes` replaces it by the exact separating-axis distance of the two
/// oriented boxes less the clearances `margin_x` (along the road) and `margin_y` (across),
/// b in metres, with its (sub)gradient for the Z-update, the safe step and the refinement
/// ([`crate::safety::box_separation`]; tested against an independent corner-projection
/// separating-axis test, `OrientedBox::overlaps` and finite differences). The contingency
/// rule (`PlannerSettings::contingency`) makes a plan that takes the ego's box across the line
/// between its own lane and the target lane admissible only if a fixed retreat from the plan's first state
/// across the line (no later than step T − `contingency_steps`) back towards the own lane's
/// centre, braking at `contingency_accel` or else holding acceleration 0, is safe under the
/// predictor's prediction for that retreat path; it is checked in the execution check, so the
/// refinement, backtracking and fallbacks all respect it. Measured on validation (269 scenes ×
/// 3 seeds, paired with the defaults; `docs/results/nudge_safety.md`), no variant passes the
/// bar "at-fault collisions down, success not lower in any world", so both stay off:
///
/// * boxes with the default margins (1.5 m / 0.3 m): more calls converge (`Converged` 2701 →
///   3566 steps, student, teacher world) but the ego drives closer (1.5 m bumper to bumper
///   where the ellipse kept 3.4–3.6 m): student success 94.1 → 85.9, 94.5 → 90.2, 93.2 →
///   88.1 % (teacher, idm, log-replay worlds), log-replay at-fault runs 2 → 18, mostly the ego
///   running into a replayed vehicle it joins or passes;
/// * boxes with `margin_x` 3.4 m (the ellipse's bumper gap): the clearance rectangle is
///   projected on the yawed ego's axes, so it widens the lateral clearance by
///   `margin_x`·|sin ψ| during the lane change: success 68–80 %, log-replay at-fault runs 25;
///   growing the ego's box in its own frame instead (`SafetyGeometry::GrownBoxes`) fares as
///   badly (72–80 %, 18 at-fault runs): its longer ends still swing across the road;
/// * boxes and the contingency: a further 2.6–3.7 pp of success lost, log-replay at-fault
///   runs 13: a retreat that must leave the target lane within 3–5 steps is often unsafe
///   while a target-lane vehicle closes in, so the change is refused, the fallbacks steer
///   back and the ego spends more time across the line (straddle 2.5–2.8 s per run against
///   1.9–2.0 s); and the rule only applies while the own lane is still offered as a retreat.
///
/// **Followers that do not yield** (`follower_ttc`, `follower_min_gap`,
/// `follower_clearance`; off by default). The predictors learned from traffic in which drivers
/// make room, so they predict a target-lane follower yielding to an ego that cuts in, and the
/// safety constraint (checked against that prediction) lets the ego in. Recorded traffic never
/// yields. On the validation scenes (student planner, log-replay world, 300 scenes × 3 seeds)
/// the 8 at-fault runs had three causes: (1) an ego that entered the target lane 1–2 m ahead
/// of a follower 3 m/s faster (22 vs 20 m/s; b of the entry 0.05), then, with no admissible
/// plan, held its straddle and was hit in the side (3 runs, one scene); (2) a 19.8 m truck
/// whose scene starts with its centre already across the line next to a car in the target
/// lane and 2 m behind a slower car in its own lane: no admissible plan from the first step,
/// the least-violating one holds the straddle, and the logged car drifts 0.3 m into it (3
/// runs); (3) an ego squeezed between a faster own-lane follower and a vehicle ahead-left
/// whose log ended and whose constant-velocity extrapolation drifts into the ego's lane:
/// the least-violating fallback accelerates into it (2 runs). The follower-gap rule (the
/// planner's `follower_gap` module) removes cause (1): a plan may not narrow the lateral
/// clearance to a follower on the goal's side below `follower_clearance` (0.8 m) while that
/// follower, driving on at its observed speed, is less than `follower_min_gap` (0.5 m) + its
/// closing speed × `follower_ttc` behind the ego. Tuned in the log-replay world (student):
/// a time gap (0.5 s, or 0.2 s, of the follower's speed) instead of the closing-speed term
/// lost 20 and 10 points of success (the ego waits behind slower followers it was pulling
/// away from); closing speed × 3 s with a 2 m minimum gap lost 7 points; with a 0.5 m minimum
/// gap, 3 s and 2 s lost 1.2 and 1.5 points, all with 5 at-fault runs left (causes 2 and 3).
/// At 2 s in every world (paired with the rule off, 300 scenes × 3 seeds, the teacher
/// planner on 100 of them): log-replay at-fault runs 8 → 5 (student), but success fell in
/// every world (student: teacher world 86.0 → 81.3 %, IDM 89.4 → 86.4 %, log replay 84.4 →
/// 82.9 %; teacher planner 86.7 → 80.7, 92.7 → 88.3, 89.0 → 83.7 %), the lost runs all
/// unfinished lane changes (reactive followers would have yielded), and new at-fault runs
/// appeared (student, teacher world 0 → 3: the truck of cause 2 in another window, yawing its
/// tail into the car beside it; teacher planner, log replay 0 → 3). So the rule stays off
/// (`docs/results/follower_gap.md`). Down-weighting, in the fallbacks' ranking, the
/// violation against vehicles behind the ego in its lane (for cause 3) was tried and dropped:
/// at weight 0.25 it added at-fault and not-at-fault collisions.
///
/// **Bounded work.** `budget_s` (wall time) and `budget_calls` (predictor calls), when set,
/// end the call with [`PlanStatus::BudgetExhausted`] and a checked plan: one predictor call is
/// held back for the shifted previous plan (or the straight fallback).
///
/// **Trial points the predictors refuse.** Every candidate is checked against the predictors'
/// input range (`nudge_predictor::limits::check_candidates` from the ego's last observed
/// position: finite, at most 1 km per step) before the predictor sees it; one outside gets no
/// prediction and is not safe, as after a spent budget, and is counted in
/// [`Plan::refused_candidates`]. ADMM's duals grow over a call whose
/// linearised dynamics the bounded inputs cannot meet, and Z's trial points then overshoot: on
/// one train-split closed-loop run (`heading_max` 0.15) a Z-update tried a point 1.05 km from
/// the previous one, and the predictor's error ended the run. The roll-outs of the execution
/// check are always in range. Bounding Z by the ego's reach along the road instead (no trial
/// point beyond what input sequences within the boxes can drive, 1 m of slack) also keeps
/// the predictor's candidates physical, but changed outcomes: on 600 train scenes × 3 seeds
/// (student planner) log-replay at-fault runs rose 17 → 23 (two scenes) and success fell
/// 81.9 → 81.7 %, IDM 87.4 → 87.5 %, teacher world unchanged; it was not kept.
///
/// Keeps the solution to warm-start the next call; call [`Planner::reset`] between
/// unrelated runs. [`Planner::reference_qp`] solves the same linearised problem as one joint
/// QP.
#[derive(Debug, Clone)]
pub struct Planner {
    settings: PlannerSettings,
    model: Bicycle,
    warm: Option<WarmStart>,
}

/// Why the ADMM loop stopped.
#[derive(Debug, Clone, PartialEq)]
enum Stop {
    /// ‖F‖∞ ≤ eps_primal and ‖Z − Z_prev‖∞ ≤ eps_change.
    Converged,
    /// `max_iter` iterations.
    MaxIterations,
    /// A QP gave no usable solution.
    SolverFailed(QpFailure),
    /// The work budget ran out.
    Budget,
}

/// What the ADMM loop hands to the execution check.
struct AdmmResult {
    iterates: Iterates,
    iterations: usize,
    change_residual: f64,
    qp_solves: usize,
    stop: Stop,
}

/// The plan after the execution check, in the call's frame.
struct Finished {
    delta: Vec<f64>,
    accel: Vec<f64>,
    z: Vec<State>,
    /// ADMM's Z at the end of its loop (empty after a QP failure).
    admm_z: Vec<State>,
    min_b: Option<f64>,
    rollout_min_b: Option<f64>,
    status: PlanStatus,
    decided_by: DecidedBy,
    iterations: usize,
    change_residual: f64,
    qp_solves: usize,
}

impl Planner {
    /// A planner with validated settings.
    ///
    /// # Errors
    /// [`PlannerError::Settings`] when `settings.validate()` fails.
    pub fn new(settings: PlannerSettings) -> Result<Self, PlannerError> {
        settings.validate()?;
        let model = Bicycle {
            l_f: settings.model.l_f,
            l_r: settings.model.l_r,
            dt: settings.model.dt,
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

    /// Solves one MPC call (Algorithm 1) and stores the solution as the next warm start.
    ///
    /// `problem` holds the measured ego state, the history `[n, 8, 2]` and sizes `[n]` of
    /// every vehicle (agent 0 = ego), the lateral target and the road; `predictor` (horizon
    /// T = `settings.horizon`) predicts the other vehicles for every trial trajectory.
    /// Returns inputs `[T]`, states `[T]` (road frame) and how the call ended
    /// ([`Plan::status`]); a Clarabel failure is not an error but the status
    /// [`PlanStatus::SolverFailed`] with a checked fallback plan.
    ///
    /// # Errors
    /// [`PlannerError::BadProblem`] for a malformed problem or an ego that needs more than
    /// [`PlannerSettings::MAX_EGO_SEGMENTS`] safety slices (field `sizes`),
    /// [`PlannerError::HorizonMismatch`] when the predictor's horizon differs,
    /// [`PlannerError::Predictor`] when the predictor
    /// rejects the scene or a candidate, or when a prediction is non-finite or implausible
    /// (every predictor's output is checked, see [`nudge_predictor::Checked`]).
    ///
    /// # Examples
    ///
    /// A lane change to the left lane (y = 3.7 m) on a straight two-lane road with a slower car
    /// ahead, planned with the constant-velocity predictor:
    ///
    /// ```
    /// use nudge_planner::{EgoState, PlanStatus, Planner, PlannerSettings, PlanningProblem};
    /// use nudge_predictor::{ConstantVelocity, History, T_OBS};
    ///
    /// // Ego at (0, 0) and a car 15 m ahead, both observed for T_OBS steps of 0.3 s.
    /// let mut positions = Vec::new();
    /// for (x0, y, v) in [(0.0, 0.0, 12.0), (15.0, 0.0, 9.0)] {
    ///     for t in 0..T_OBS {
    ///         positions.extend([x0 - v * 0.3 * (T_OBS - 1 - t) as f64, y]);
    ///     }
    /// }
    /// let history = History::new(positions, 2)?;
    /// let sizes = [[4.5, 1.9], [4.5, 1.9]];
    /// let problem = PlanningProblem {
    ///     ego: EgoState { x: 0.0, y: 0.0, psi: 0.0, v: 12.0 },
    ///     last_delta: 0.0,
    ///     last_accel: 0.0,
    ///     history: &history,
    ///     sizes: &sizes,
    ///     y_target: 3.7,
    ///     v_ref: 12.0,
    ///     road: [-1.85, 5.55],
    ///     y_retreat: None,
    ///     lanes: None,
    /// };
    /// let mut planner = Planner::new(PlannerSettings::default())?;
    /// let plan = planner.plan(&problem, &mut ConstantVelocity::new(6)?)?;
    /// assert_eq!(plan.states.len(), 6);
    /// assert!(plan.states[5][1] > 0.0, "the ego moves towards the left lane");
    /// assert!(plan.min_safety.is_some_and(|b| b > 0.0) && plan.status != PlanStatus::Unsafe);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        let start = Instant::now();
        self.check(problem, predictor)?;
        // Every prediction is checked finite and plausible, whoever implemented the predictor.
        let mut checked = Checked::new(predictor);
        let predictor: &mut dyn Predictor = &mut checked;
        let s = &self.settings;
        // Set-up: the linearised problem, the checked vehicles, the workspace.
        let mut lp = LinearisedProblem::new(s, &self.model, self.warm.as_ref(), problem);
        let constraint = SafetyConstraint::new(problem, s);
        if !constraint.vehicles().is_empty() {
            predictor.set_scene(problem.history)?;
        }
        let n_agents = problem.history.n_agents();
        let mut safety = SafetyEval::new(
            &constraint,
            lp.origin,
            lp.horizon,
            n_agents,
            s.safety.safety_min,
        );
        safety.budget = Budget::new(s, start);
        safety.count_overlap = true;
        safety.ego_last = Some(problem.history.at(0, nudge_predictor::T_OBS - 1));
        if s.safety.ablate_reaction {
            safety.ablate_reaction(crate::keep_lane_path(&problem.ego, lp.horizon, s.model.dt));
        }
        let mut timings = PhaseTimings::default();
        let iterates = Iterates::start(&lp);
        let first = safety.eval(predictor, &iterates.z)?;
        let current = CurrentSafety::new(first, &safety);
        let mut ws = Workspace::new(s, &lp, iterates, current);
        // ADMM: loop {(re-linearisation;) Δ-update; α-update; Z-update; dual update}.
        let run = admm_loop(s, &mut lp, &mut ws, &mut safety, predictor, &mut timings)?;
        let admm = AdmmResult::new(ws, run.stop, run.iterations, run.qp_solves);
        // Execution check: the roll-out of (Δ, α), repaired when unsafe; it may use the calls
        // the budget held back.
        safety.budget.reserve = 0;
        let mut nonreactive = nonreactive_predictor(&constraint, problem, lp.horizon)?;
        let mut repairer = Repairer {
            s,
            model: &self.model,
            lp: &lp,
            safety: &mut safety,
            predictor,
            nonreactive: nonreactive.as_mut().map(|p| p as &mut dyn Predictor),
        };
        let finished = check_execution(&mut repairer, admm)?;
        let counts = (safety.calls, constraint.vehicles().len(), safety.refused);
        let (mut plan, warm) = finished.into_plan(s, &lp, counts, timings);
        self.warm = Some(warm);
        plan.timings.total_s = start.elapsed().as_secs_f64();
        Ok(plan)
    }

    /// Checks the problem, the number of ego slices it needs (at most
    /// [`PlannerSettings::MAX_EGO_SEGMENTS`]) and the predictor's horizon.
    fn check(
        &self,
        problem: &PlanningProblem<'_>,
        predictor: &dyn Predictor,
    ) -> Result<(), PlannerError> {
        problem.check()?;
        let s = &self.settings;
        let ego_length = problem.sizes[0][0];
        if constraint::ego_slice_count(ego_length, s.safety.ego_segment_length)
            > PlannerSettings::MAX_EGO_SEGMENTS as f64
        {
            return Err(PlannerError::BadProblem {
                field: "sizes",
                reason: format!(
                    "the ego (agent 0) of length {ego_length} m needs more than \
                     MAX_EGO_SEGMENTS = {} slices of ego_segment_length = {} m",
                    PlannerSettings::MAX_EGO_SEGMENTS,
                    s.safety.ego_segment_length
                ),
            });
        }
        if predictor.horizon() != self.settings.model.horizon {
            return Err(PlannerError::HorizonMismatch {
                predictor: predictor.horizon(),
                planner: self.settings.model.horizon,
            });
        }
        Ok(())
    }

    /// Solves the linearised problem this planner's next [`Planner::plan`] call would set up
    /// (same nominal, same warm start) as ONE Clarabel QP in (Δ, α, Z), without the safety
    /// constraint. With no vehicle in range, ADMM converges to this solution.
    ///
    /// # Errors
    /// As [`Planner::plan`] for a malformed problem; [`PlannerError::QpSetup`] /
    /// [`PlannerError::QpFailed`] (QP `joint`) when Clarabel does not solve it.
    pub fn reference_qp(
        &self,
        problem: &PlanningProblem<'_>,
    ) -> Result<JointSolution, PlannerError> {
        problem.check()?;
        let lp = LinearisedProblem::new(&self.settings, &self.model, self.warm.as_ref(), problem);
        reference::solve_joint(&self.settings, &lp)
    }
}

/// How the ADMM loop ended.
struct AdmmRun {
    stop: Stop,
    iterations: usize,
    qp_solves: usize,
}

/// The ADMM loop: Δ-update, α-update, Z-update and dual update until both residuals meet their
/// tolerances ([`Stop::Converged`]), `max_iter` iterations, a QP failure or the budget.
fn admm_loop(
    s: &PlannerSettings,
    lp: &mut LinearisedProblem,
    ws: &mut Workspace,
    safety: &mut SafetyEval<'_>,
    predictor: &mut dyn Predictor,
    timings: &mut PhaseTimings,
) -> Result<AdmmRun, PlannerError> {
    let mut qps = match InputQps::new(s, lp) {
        Ok(qps) => qps,
        Err(failure) => {
            return Ok(AdmmRun {
                stop: Stop::SolverFailed(failure),
                iterations: 0,
                qp_solves: 0,
            });
        }
    };
    let mut stop = Stop::MaxIterations;
    let mut iterations = 0;
    for iteration in 0..s.admm.max_iter {
        if safety.budget.spent(safety.calls) {
            stop = Stop::Budget;
            break;
        }
        iterations = iteration + 1;
        let (delta_s, alpha_s) = (&mut timings.delta_s, &mut timings.alpha_s);
        let inputs = qps
            .update(Input::Steering, s, lp, ws, iteration, delta_s)
            .and_then(|()| qps.update(Input::Acceleration, s, lp, ws, iteration, alpha_s));
        if let Err(failure) = inputs {
            stop = Stop::SolverFailed(failure);
            break;
        }
        ws.update_z(s, lp, safety, predictor, timings)?;
        let converged = ws.update_duals(s, lp);
        if safety.budget.exhausted {
            stop = Stop::Budget;
            break;
        }
        if converged {
            stop = Stop::Converged;
            break;
        }
    }
    Ok(AdmmRun {
        stop,
        iterations,
        qp_solves: qps.solves(),
    })
}

impl AdmmResult {
    /// The workspace's iterates after the loop stopped.
    fn new(ws: Workspace, stop: Stop, iterations: usize, qp_solves: usize) -> Self {
        Self {
            iterations,
            change_residual: ws.change,
            qp_solves,
            iterates: ws.iterates,
            stop,
        }
    }
}

/// The constant-velocity predictor, set to the problem's scene, under which a lattice
/// sequence must hit nobody to replace the fallback ([`repair`]); `None` when nothing is
/// checked.
fn nonreactive_predictor(
    constraint: &SafetyConstraint,
    problem: &PlanningProblem<'_>,
    horizon: usize,
) -> Result<Option<ConstantVelocity>, PlannerError> {
    if constraint.vehicles().is_empty() {
        return Ok(None);
    }
    let mut cv = ConstantVelocity::new(horizon)?;
    cv.set_scene(problem.history)?;
    Ok(Some(cv))
}

/// The execution check: the ADMM roll-out when admissible, else the repairs in order
/// (refinement, backtracking, the best fallback); with nothing admissible the least-violating
/// of the roll-out and the best fallback. Every outcome names what decided it.
fn check_execution(r: &mut Repairer<'_, '_>, admm: AdmmResult) -> Result<Finished, PlannerError> {
    let Iterates {
        delta,
        accel,
        z: admm_z,
        ..
    } = admm.iterates;
    let counts = (admm.iterations, admm.change_residual, admm.qp_solves);
    let status = match admm.stop {
        Stop::SolverFailed(failure) => {
            let c = r.best_fallback()?;
            let status = PlanStatus::SolverFailed {
                qp: failure.qp,
                status: failure.status,
            };
            let by = fallback(&c);
            return Ok(Finished::adopt(c, Vec::new(), (status, by), counts));
        }
        Stop::Converged => PlanStatus::Converged,
        Stop::MaxIterations => PlanStatus::MaxIterations,
        Stop::Budget => PlanStatus::BudgetExhausted,
    };
    let rollout = r.check(delta, accel)?;
    let admm_by = if rollout.governed {
        DecidedBy::AdmmGoverned
    } else {
        DecidedBy::Admm
    };
    if rollout.rank.safe {
        return Ok(Finished::adopt(rollout, admm_z, (status, admm_by), counts));
    }
    let unsafe_outcome = if status == PlanStatus::BudgetExhausted {
        // The budget's reserved second call: the shifted previous plan.
        let nominal = r.check(r.lp.nominal_delta.clone(), r.lp.nominal_accel.clone())?;
        if nominal.rank.safe {
            let outcome = (PlanStatus::BudgetExhausted, DecidedBy::Nominal);
            return Ok(Finished::adopt(nominal, admm_z, outcome, counts));
        }
        (nominal, DecidedBy::Nominal)
    } else {
        if let Some(c) = r.refine(&rollout)? {
            let outcome = (PlanStatus::Refined, DecidedBy::Refined);
            return Ok(Finished::adopt(c, admm_z, outcome, counts));
        }
        if let Some(c) = r.backtrack(&rollout.delta, &rollout.accel)? {
            let outcome = (PlanStatus::Backtracked, DecidedBy::Backtracked);
            return Ok(Finished::adopt(c, admm_z, outcome, counts));
        }
        let c = r.best_fallback()?;
        let by = fallback(&c);
        if c.rank.safe {
            return Ok(Finished::adopt(
                c,
                admm_z,
                (PlanStatus::Fallback, by),
                counts,
            ));
        }
        (c, by)
    };
    // Nothing admissible: the least-violating of the repair and the ADMM roll-out.
    let (best, by) = if unsafe_outcome.0.rank.beats(&rollout.rank) {
        unsafe_outcome
    } else {
        (rollout, admm_by)
    };
    Ok(Finished::adopt(
        best,
        admm_z,
        (PlanStatus::Unsafe, by),
        counts,
    ))
}

/// What decided a candidate returned by [`Repairer::best_fallback`].
fn fallback(c: &Candidate) -> DecidedBy {
    let (family, key) = c.chosen.unwrap_or((Family::Nominal, None));
    DecidedBy::Fallback { family, key }
}

impl Finished {
    /// The plan of candidate `c` with its (status, what decided it); `counts` = (iterations,
    /// change residual, QP solves) of the ADMM loop.
    fn adopt(
        c: Candidate,
        admm_z: Vec<State>,
        (status, decided_by): (PlanStatus, DecidedBy),
        counts: (usize, f64, usize),
    ) -> Self {
        Self {
            delta: c.delta,
            accel: c.accel,
            z: c.rollout,
            admm_z,
            min_b: c.min_b,
            rollout_min_b: c.min_b,
            status,
            decided_by,
            iterations: counts.0,
            change_residual: counts.1,
            qp_solves: counts.2,
        }
    }

    /// The plan in the road frame and the next call's warm start; `counts` = (predictor
    /// calls, checked vehicles, refused candidates).
    fn into_plan(
        self,
        s: &PlannerSettings,
        lp: &LinearisedProblem,
        counts: (usize, usize, usize),
        timings: PhaseTimings,
    ) -> (Plan, WarmStart) {
        let mut residual = vec![State::zeros(); lp.horizon];
        lp.linearisation
            .residual(&self.delta, &self.accel, &self.z, &mut residual);
        let plan = Plan {
            states: lp.to_world(&self.z),
            admm_states: lp.to_world(&self.admm_z),
            cost: lp.cost(s, &self.delta, &self.accel, &self.z),
            primal_residual: max_abs(&residual),
            delta: self.delta.clone(),
            accel: self.accel.clone(),
            iterations: self.iterations,
            predictor_calls: counts.0,
            refused_candidates: counts.2,
            qp_solves: self.qp_solves,
            change_residual: self.change_residual,
            min_safety: self.min_b,
            rollout_min_safety: self.rollout_min_b,
            checked: counts.1,
            lane_violation: lp.lane_violation(&self.z),
            timings,
            status: self.status,
            decided_by: self.decided_by,
        };
        let warm = WarmStart {
            delta: self.delta,
            accel: self.accel,
        };
        (plan, warm)
    }
}
