//! The execution check and its repairs. The vehicle follows the nonlinear roll-out of (Δ, α),
//! not Z, and a plan is *admissible* when that roll-out is safe (every checked b > safety_min
//! under the predictor's prediction of it) and within the state bounds (heading, lateral
//! corridor, road). When ADMM stopped before F ≈ 0 the roll-out and Z differ, and Z tends to
//! sit on the constraint boundary, so the roll-out can leave it. Then
//! 1. [`Repairer::refine`]: SQP steps on the nonlinear roll-out from the ADMM inputs
//!    ([`super::refine`]); the first admissible roll-out;
//! 2. else [`Repairer::backtrack`]: pull (Δ, α) towards the nominal (the shifted previous
//!    plan) by θ = 3/4, 1/2, 1/4 and take the first admissible roll-out;
//! 3. else [`Repairer::best_fallback`]: the cheapest admissible (else the least-violating) of
//!    a few simple input sequences: the nominal, [`align_with_road`] with constant
//!    accelerations, [`steer_towards`] the lateral goal with those accelerations, the
//!    [`stop_inputs`] that stop before the end of a lane that ends, and
//!    when the best of these is unsafe by the prediction, [`steer_towards`] the retreat
//!    lane's centre (checked within the bounds of a plan aiming there): with nothing
//!    admissible, the least-violating of holding, finishing or cancelling a lane change.
//!
//! With `PlannerSettings::contingency`, a roll-out that is otherwise admissible and puts the
//! ego across the line between its own lane and the target lane is admissible only when its
//! retreat is safe (`super::contingency`); every candidate above is checked by that rule.
//!
//! A lane that has not begun is never entered for a smaller violation elsewhere: among
//! inadmissible candidates, one whose roll-out puts a centre in a lane before it begins
//! ([`crate::LaneViolationKind::NotBegun`]) ranks below every one that does not
//! ([`Rank::unbegun`], the rule of [`crate::extents`]).
//!
//! With `PlannerSettings::follower_ttc`, a roll-out that narrows the lateral clearance to a
//! follower on the goal's side whose non-reacting gap behind the ego is too short is not
//! admissible either (`super::follower_gap`); among inadmissible candidates its violation
//! ranks like a bound excess.
//!
//! A failed QP skips the check: the ADMM iterates are dropped and the best fallback is the plan.

use nudge_predictor::Predictor;

use crate::error::PlannerError;
use crate::extents::LaneViolationKind;
use crate::model::{Bicycle, State};
use crate::qp::{RateBox, repair_box_rate};
use crate::settings::PlannerSettings;

use super::constraint::{Evaluation, SafetyEval, SafetyRow};
use super::contingency::Contingency;
use super::follower_gap::FollowerGap;
use super::heading::govern_heading;
use super::linearised::LinearisedProblem;
use super::refine;

/// An input sequence checked on its roll-out.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Candidate {
    /// Steering `[T]` (rad).
    pub delta: Vec<f64>,
    /// Acceleration `[T]` (m/s²).
    pub accel: Vec<f64>,
    /// Its roll-out z_1..z_T (call frame).
    pub rollout: Vec<State>,
    /// Minimum b of the roll-out (`None` when nothing is checked).
    pub min_b: Option<f64>,
    /// The predictor's verdict: the roll-out is safe at `safety_min` (state bounds aside),
    /// its contingency retreat included when the rule applies, and it keeps the follower-gap
    /// rule (`super::follower_gap`) when that applies.
    pub predicted_safe: bool,
    /// The contingency rule refused the roll-out: otherwise admissible, its retreat is not
    /// safe (`super::contingency`).
    pub retreat_blocked: bool,
    /// How it ranks among fallbacks.
    pub rank: Rank,
    /// The safety rows of the roll-out's evaluation (for the refinement).
    pub rows: Vec<SafetyRow>,
}

/// Weight of the state-bound excess (per m or rad) against the safety violation (units of b)
/// in the rank of an inadmissible candidate.
const EXCESS_WEIGHT: f64 = 10.0;

/// Bound excess below this counts as within the bounds (rounding).
const EXCESS_TOLERANCE: f64 = 1e-9;

/// A candidate's rank: an admissible sequence by its cost J, another by its total violation
/// (safety violation + [`EXCESS_WEIGHT`] × state-bound excess); any admissible one beats
/// every other. With a positive `PlannerSettings::fallback_speed_floor`, an inadmissible one
/// whose path is clear (no violation from a vehicle that is not beside the ego,
/// [`super::SafetyConstraint::beside`], and a state-bound excess of at most
/// `PlannerSettings::bounds_slack`) and that ends at or above
/// the floor beats every other inadmissible one: a vehicle whose box cannot touch the ego's
/// never calls for braking towards a standstill. With `PlannerSettings::edge_first`, among
/// inadmissible ones the smaller road-edge excess wins before anything else (an ego that
/// starts over the road's edge never picks a fallback that swings a corner further out to
/// lower its safety violation). With `PlannerSettings::contact_first`, the smaller predicted
/// box overlap wins before that. With `PlannerSettings::bounds_first`, one within the state
/// bounds wins before that (predicted contact never buys a swerve past the heading bound,
/// out of the lateral corridor or off the road). After those, an inadmissible one that puts
/// a centre in a lane before it begins loses to every inadmissible one that does not. With
/// `PlannerSettings::fallback_avoid_nonreactive`, after that, one whose box meets nobody
/// under the constant-velocity prediction beats one whose box meets somebody's. With
/// `PlannerSettings::lead_first` (from `PlannerSettings::lead_min_speed`), after the road
/// edge, the smaller safety violation against the vehicles ahead of the ego in its path wins.
///
/// The order among inadmissible candidates, each rule deciding only on a tie of those before
/// it: `out_of_bounds` (false first), `contact`, `edge`, `ahead` (smaller first), `unbegun`
/// (false first), `hits_nonreactive` (false first), `clear` (true first), `value` (smaller
/// first).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rank {
    /// The roll-out is admissible: safe at `safety_min` and within the state bounds.
    pub safe: bool,
    /// A state of the roll-out has its centre in a lane that really begins after its x
    /// ([`crate::LaneViolationKind::NotBegun`]; never for an admissible one).
    pub unbegun: bool,
    /// Inadmissible, but its path is clear and it keeps the speed floor (false unless the
    /// floor is on).
    pub clear: bool,
    /// Cost when admissible, total violation when not.
    pub value: f64,
    /// The roll-out leaves the state bounds (its [`LinearisedProblem::bound_excess`], or that
    /// within the retreat's bounds, exceeds `PlannerSettings::bounds_slack`, at least the
    /// rounding tolerance) when inadmissible and `PlannerSettings::bounds_first` is on, else
    /// false.
    pub out_of_bounds: bool,
    /// Predicted box overlap of the roll-out (m, [`super::constraint::Evaluation::overlap`])
    /// when inadmissible and `PlannerSettings::contact_first` is on, else 0.
    pub contact: f64,
    /// Road-edge excess of the roll-out (m, [`LinearisedProblem::edge_excess`]) when
    /// inadmissible and `PlannerSettings::edge_first` is on, else 0.
    pub edge: f64,
    /// Inadmissible, and its box overlaps another vehicle's at some step under the
    /// constant-velocity prediction ([`Repairer::clear_without_reaction`]) with
    /// `PlannerSettings::fallback_avoid_nonreactive` on and the ego at least as fast as
    /// `PlannerSettings::avoid_min_speed`; else false.
    pub hits_nonreactive: bool,
    /// Safety violation (units of b) against the vehicles ahead of the ego in its path
    /// ([`super::constraint::Evaluation::ahead_violation`]) when inadmissible and
    /// `PlannerSettings::lead_first` is on, else 0.
    pub ahead: f64,
    /// Inadmissible, and the box of some state of the roll-out spans a lane line, with
    /// `PlannerSettings::lead_keep_lane` on while `PlannerSettings::lead_first` applies
    /// ([`Repairer::lead_applies`]); else false.
    pub leaves_lane: bool,
}

impl Rank {
    /// Strictly better than `other`.
    pub(crate) fn beats(&self, other: &Rank) -> bool {
        match (self.safe, other.safe) {
            (true, false) => true,
            (false, true) => false,
            (false, false) if self.out_of_bounds != other.out_of_bounds => other.out_of_bounds,
            (false, false) if (self.contact - other.contact).abs() > EXCESS_TOLERANCE => {
                self.contact < other.contact
            }
            (false, false) if (self.edge - other.edge).abs() > EXCESS_TOLERANCE => {
                self.edge < other.edge
            }
            (false, false) if self.leaves_lane != other.leaves_lane => other.leaves_lane,
            (false, false) if (self.ahead - other.ahead).abs() > EXCESS_TOLERANCE => {
                self.ahead < other.ahead
            }
            _ if self.unbegun != other.unbegun => other.unbegun,
            _ if self.hits_nonreactive != other.hits_nonreactive => other.hits_nonreactive,
            _ if self.clear != other.clear => self.clear,
            _ => self.value < other.value,
        }
    }

    /// The rank of an inadmissible candidate: its `violations`, of which the settings' rules
    /// keep the parts they rank by (`bounds_first`: whether it leaves the state bounds by
    /// more than `bounds_slack`;
    /// `contact_first`: its predicted contact; `edge_first`: its road-edge excess; each
    /// off: false or 0, so it never decides).
    pub(crate) fn inadmissible(s: &PlannerSettings, violations: &Violations) -> Rank {
        Rank {
            safe: false,
            unbegun: violations.unbegun,
            clear: violations.clear,
            value: violations.value,
            out_of_bounds: s.bounds_first
                && violations.bound_excess > s.bounds_slack.max(EXCESS_TOLERANCE),
            contact: if s.contact_first {
                violations.contact
            } else {
                0.0
            },
            edge: if s.edge_first { violations.edge } else { 0.0 },
            hits_nonreactive: violations.hits_nonreactive,
            ahead: if s.lead_first { violations.ahead } else { 0.0 },
            leaves_lane: s.lead_first && s.lead_keep_lane && violations.leaves_lane,
        }
    }
}

/// What an inadmissible candidate's [`Rank`] is made of, before the settings choose the
/// rules ([`Rank::inadmissible`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Violations {
    /// A state of the roll-out has its centre in a lane before it begins.
    pub unbegun: bool,
    /// Its path is clear and it keeps the speed floor ([`Rank::clear`]).
    pub clear: bool,
    /// Total violation: safety violation (units of b) + [`EXCESS_WEIGHT`] × (state-bound
    /// excess + follower-gap violation), or the contingency retreat's violation.
    pub value: f64,
    /// State-bound excess of the roll-out (Σ over steps, m, rad and m/s mixed, as
    /// [`LinearisedProblem::bound_excess`]): heading, lateral corridor, speed, the box's
    /// corners beyond the road's edges, lane extents and the stopping rule; 0 within them.
    pub bound_excess: f64,
    /// Predicted box overlap (m, [`super::constraint::Evaluation::overlap`]; 0 when not
    /// counted).
    pub contact: f64,
    /// Road-edge excess of the box's corners (m, [`LinearisedProblem::edge_excess`]).
    pub edge: f64,
    /// Its box overlaps another vehicle's under the constant-velocity prediction (false
    /// when not checked: `PlannerSettings::fallback_avoid_nonreactive` off, or the ego
    /// slower than `PlannerSettings::avoid_min_speed`).
    pub hits_nonreactive: bool,
    /// Safety violation (units of b) against the vehicles ahead of the ego in its path.
    pub ahead: f64,
    /// The box of some state of the roll-out spans a lane line (false when not checked:
    /// the lead rule does not apply to the call or `PlannerSettings::lead_keep_lane` is off).
    pub leaves_lane: bool,
}

/// What an inadmissible candidate's safety ranks by ([`Repairer::worst_case`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct WorstCase {
    /// Safety violation (units of b, as [`Violations::value`] without the bound excess).
    violation: f64,
    /// Predicted box overlap (m).
    contact: f64,
}

/// The lateral goal whose state bounds a candidate is checked within.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Goal {
    /// The call's target (its corridor from the start to `y_target`).
    Target,
    /// The retreat lane ([`super::linearised::Retreat`]).
    Retreat,
}

/// The context every repair needs.
pub(crate) struct Repairer<'a, 'c> {
    pub s: &'a PlannerSettings,
    pub model: &'a Bicycle,
    pub lp: &'a LinearisedProblem,
    pub safety: &'a mut SafetyEval<'c>,
    pub predictor: &'a mut dyn Predictor,
    /// The contingency rule of the call (`None` when it does not apply).
    pub contingency: Option<Contingency>,
    /// The follower-gap rule of the call (`None` when it does not apply).
    pub follower_gap: Option<FollowerGap>,
    /// The non-reactive predictor inadmissible candidates are also ranked against
    /// (`PlannerSettings::fallback_nonreactive`,
    /// `PlannerSettings::fallback_avoid_nonreactive`), lattice sequences must be clear under
    /// (`PlannerSettings::lattice_clear_nonreactive`) and the fallback must hit somebody under
    /// before the lattice is searched (`PlannerSettings::lattice_when_fallback_hits`); `None`
    /// when no such rule is on or nothing is checked.
    pub nonreactive: Option<&'a mut dyn Predictor>,
}

impl Repairer<'_, '_> {
    /// Rolls `delta`, `accel` out from the measured state and checks the roll-out.
    pub(crate) fn check(
        &mut self,
        delta: Vec<f64>,
        accel: Vec<f64>,
    ) -> Result<Candidate, PlannerError> {
        self.check_within(delta, accel, Goal::Target)
    }

    /// [`Self::check`] within the state bounds of a plan aiming at `goal`; with
    /// `PlannerSettings::heading_governor` the steering is first governed to those bounds'
    /// heading ([`govern_heading`]), and the candidate carries the governed steering.
    fn check_within(
        &mut self,
        mut delta: Vec<f64>,
        accel: Vec<f64>,
        goal: Goal,
    ) -> Result<Candidate, PlannerError> {
        let (lower, upper) = match (goal, &self.lp.retreat) {
            (Goal::Retreat, Some(r)) => (&r.lower, &r.upper),
            _ => (&self.lp.lower, &self.lp.upper),
        };
        if self.s.heading_governor {
            govern_heading(
                self.model,
                &self.lp.start,
                &mut delta,
                &accel,
                self.lp.accel_box.hi,
                self.lp.delta_box,
                lower,
                upper,
            );
        }
        let mut rollout = vec![State::zeros(); self.lp.horizon];
        self.model
            .rollout(&self.lp.start, &delta, &accel, &mut rollout);
        let e = self.safety.eval(self.predictor, &rollout)?;
        let excess = match (goal, &self.lp.retreat) {
            (Goal::Retreat, Some(r)) => self.lp.bound_excess_within(&r.lower, &r.upper, &rollout),
            _ => self.lp.bound_excess(&rollout),
        };
        let rows = self.safety.rows.clone();
        let gap_violation = self
            .follower_gap
            .as_ref()
            .map_or(0.0, |g| g.violation(&rollout));
        let mut predicted_safe = e.is_safe(self.s.safety_min) && gap_violation <= EXCESS_TOLERANCE;
        let mut retreat_violation = None;
        if predicted_safe && excess <= EXCESS_TOLERANCE && goal == Goal::Target {
            retreat_violation = self.check_retreat(&delta, &accel, &rollout)?;
            predicted_safe = retreat_violation.is_none();
        }
        let unbegun = self.lp.lanes.as_ref().is_some_and(|lanes| {
            let lanes = lanes.view();
            self.lp.to_world(&rollout).iter().any(|z| {
                matches!(
                    lanes.outside(z[0], z[1]),
                    Some((_, LaneViolationKind::NotBegun))
                )
            })
        });
        let rank = if let Some(v) = retreat_violation {
            Rank::inadmissible(
                self.s,
                &Violations {
                    unbegun,
                    clear: false,
                    value: v,
                    bound_excess: excess,
                    contact: e.overlap,
                    edge: self.edge_rank(&rollout),
                    hits_nonreactive: self.hits_without_reaction(&rollout)?,
                    ahead: self.ahead_rank(&e),
                    leaves_lane: self.leave_rank(&rollout),
                },
            )
        } else if predicted_safe && excess <= EXCESS_TOLERANCE {
            Rank {
                safe: true,
                unbegun,
                clear: false,
                value: self.lp.cost(self.s, &delta, &accel, &rollout),
                out_of_bounds: false,
                contact: 0.0,
                edge: 0.0,
                hits_nonreactive: false,
                ahead: 0.0,
                leaves_lane: false,
            }
        } else {
            let worst = self.worst_case(&rollout, &e)?;
            let floor = self.s.fallback_speed_floor;
            let v_end = rollout.last().map_or(self.lp.start[3], |z| z[3]);
            let clear = floor > 0.0
                && excess <= self.s.bounds_slack.max(EXCESS_TOLERANCE)
                && gap_violation <= EXCESS_TOLERANCE
                && safety_violation(e.path_min_b, e.path_violation, self.s.safety_min) == 0.0
                && v_end >= floor * self.lp.reference[3];
            let hits_nonreactive = self.hits_without_reaction(&rollout)?;
            Rank::inadmissible(
                self.s,
                &Violations {
                    unbegun,
                    clear,
                    value: worst.violation + EXCESS_WEIGHT * (excess + gap_violation),
                    bound_excess: excess,
                    contact: worst.contact,
                    edge: self.edge_rank(&rollout),
                    hits_nonreactive,
                    ahead: self.ahead_rank(&e),
                    leaves_lane: self.leave_rank(&rollout),
                },
            )
        };
        Ok(Candidate {
            delta,
            accel,
            rollout,
            min_b: e.min_b,
            predicted_safe,
            retreat_blocked: retreat_violation.is_some(),
            rank,
            rows,
        })
    }

    /// The safety violation (units of b) and predicted box overlap (m) an inadmissible
    /// `rollout` ranks by: those of `learned`, the planning predictor's evaluation, or with
    /// `PlannerSettings::fallback_nonreactive` each the larger of that and the non-reactive
    /// predictor's.
    fn worst_case(
        &mut self,
        rollout: &[State],
        learned: &Evaluation,
    ) -> Result<WorstCase, PlannerError> {
        let mut worst = WorstCase {
            violation: safety_violation(learned.min_b, learned.violation, self.s.safety_min),
            contact: learned.overlap,
        };
        if let (true, Some(p)) = (self.s.fallback_nonreactive, self.nonreactive.as_deref_mut()) {
            let e = self.safety.eval_nonreactive(p, rollout)?;
            worst.violation =
                worst
                    .violation
                    .max(safety_violation(e.min_b, e.violation, self.s.safety_min));
            worst.contact = worst.contact.max(e.overlap);
        }
        Ok(worst)
    }

    /// Whether an inadmissible `rollout` ranks as meeting somebody without reaction
    /// ([`Rank::hits_nonreactive`]): with `PlannerSettings::fallback_avoid_nonreactive` on and
    /// the ego at least as fast as `PlannerSettings::avoid_min_speed` at the start of the
    /// call, its box overlaps another vehicle's under the constant-velocity prediction
    /// ([`Self::clear_without_reaction`]); else false.
    fn hits_without_reaction(&mut self, rollout: &[State]) -> Result<bool, PlannerError> {
        Ok(self.s.fallback_avoid_nonreactive
            && self.lp.start[3] >= self.s.avoid_min_speed
            && !self.clear_without_reaction(rollout)?)
    }

    /// The safety violation against the vehicles ahead in the path an inadmissible
    /// candidate of evaluation `e` ranks by (units of b): its
    /// [`super::constraint::Evaluation::ahead_violation`] with `PlannerSettings::lead_first`
    /// while the ego is at least as fast as `PlannerSettings::lead_min_speed` at the start of
    /// the call (and, with `PlannerSettings::lead_in_lane`, its box spans no lane line there,
    /// [`LinearisedProblem::starts_in_one_lane`]), else 0.
    fn ahead_rank(&self, e: &Evaluation) -> f64 {
        if self.lead_applies() {
            e.ahead_violation
        } else {
            0.0
        }
    }

    /// Whether `PlannerSettings::lead_first` ranks this call's inadmissible candidates: on,
    /// the ego at least as fast as `PlannerSettings::lead_min_speed` at the start of the call
    /// and, with `PlannerSettings::lead_in_lane`, its box spanning no lane line there
    /// ([`LinearisedProblem::starts_in_one_lane`]).
    fn lead_applies(&self) -> bool {
        self.s.lead_first
            && self.lp.start[3] >= self.s.lead_min_speed
            && (!self.s.lead_in_lane || self.lp.starts_in_one_lane())
    }

    /// Whether an inadmissible `rollout` ranks as leaving its lane ([`Rank::leaves_lane`]):
    /// with `PlannerSettings::lead_keep_lane` while the lead rule applies
    /// ([`Self::lead_applies`]), the box of one of its states spans a lane line
    /// ([`LinearisedProblem::spans_line`]); else false.
    fn leave_rank(&self, rollout: &[State]) -> bool {
        self.s.lead_keep_lane && self.lead_applies() && self.lp.spans_line(rollout)
    }

    /// The road-edge excess an inadmissible `rollout` ranks by first (m): its
    /// [`LinearisedProblem::edge_excess`] with `PlannerSettings::edge_first`, else 0.
    fn edge_rank(&self, rollout: &[State]) -> f64 {
        if self.s.edge_first {
            self.lp.edge_excess(rollout)
        } else {
            0.0
        }
    }

    /// The contingency rule on a plan (`delta`, `accel` and their `rollout`): `None` when it
    /// does not apply or one of its retreats is safe at `safety_min`, else the least violation
    /// of the retreats (> 0, units of b).
    fn check_retreat(
        &mut self,
        delta: &[f64],
        accel: &[f64],
        rollout: &[State],
    ) -> Result<Option<f64>, PlannerError> {
        let Some(c) = &self.contingency else {
            return Ok(None);
        };
        let Some(k) = c.first_across(self.lp.ego_size, rollout) else {
            return Ok(None);
        };
        let j = c.branch(k, self.lp.horizon);
        let mut least = f64::INFINITY;
        for &a in c.accels() {
            let path = c.path(self.model, self.lp, (delta, accel, rollout), j, a);
            let e = self.safety.eval(self.predictor, &path)?;
            if e.is_safe(self.s.safety_min) {
                return Ok(None);
            }
            let v = safety_violation(e.min_b, e.violation, self.s.safety_min);
            least = least.min(v.max(f64::MIN_POSITIVE));
        }
        Ok(Some(least))
    }

    /// Up to `refine_iters` SQP steps ([`refine::step`]) from the inadmissible `from`; the
    /// first admissible roll-out, or `None`.
    pub(crate) fn refine(&mut self, from: &Candidate) -> Result<Option<Candidate>, PlannerError> {
        let (mut delta, mut accel, mut rows) =
            (from.delta.clone(), from.accel.clone(), from.rows.clone());
        for _ in 0..self.s.refine_iters {
            let Some((d, a)) = refine::step(self.s, self.model, self.lp, &delta, &accel, &rows)
            else {
                return Ok(None);
            };
            let c = self.check(d, a)?;
            if c.rank.safe {
                return Ok(Some(c));
            }
            if self.safety.budget.exhausted {
                return Ok(None);
            }
            (delta, accel, rows) = (c.delta, c.accel, c.rows);
        }
        Ok(None)
    }

    /// The first of (Δ, α) pulled towards the nominal by θ = 3/4, 1/2, 1/4 whose roll-out is
    /// safe.
    pub(crate) fn backtrack(
        &mut self,
        delta: &[f64],
        accel: &[f64],
    ) -> Result<Option<Candidate>, PlannerError> {
        for theta in [0.75, 0.5, 0.25] {
            let d = towards(delta, &self.lp.nominal_delta, theta, self.lp.delta_box);
            let a = towards(accel, &self.lp.nominal_accel, theta, self.lp.accel_box);
            let c = self.check(d, a)?;
            if c.rank.safe {
                return Ok(Some(c));
            }
        }
        Ok(None)
    }

    /// The best by [`Rank`] (the first on ties) of the nominal and the [`simple_inputs`]; when
    /// that one is unsafe by the prediction (not only outside the state bounds), the
    /// [`retreat_inputs`] too (checked within the retreat's bounds). With nothing admissible
    /// this is the minimum-risk choice between holding, finishing and cancelling a lane
    /// change: the least-violating; a change is cancelled only for what the predictor sees.
    /// With `PlannerSettings::fallback_lattice` and still nothing admissible, the lattice too
    /// ([`Self::best_of_lattice`]) while the ego is at least as fast as
    /// `PlannerSettings::lattice_min_speed`; with `PlannerSettings::lattice_when_fallback_hits`
    /// only when the best so far is not [`Self::clear_without_reaction`].
    pub(crate) fn best_fallback(&mut self) -> Result<Candidate, PlannerError> {
        let nominal = (self.lp.nominal_delta.clone(), self.lp.nominal_accel.clone());
        let mut best = self.check(nominal.0, nominal.1)?;
        for (d, a) in simple_inputs(self.s, self.model, self.lp) {
            let c = self.check(d, a)?;
            if c.rank.beats(&best.rank) {
                best = c;
            }
        }
        if self.s.match_admissible_only {
            for (d, a) in match_inputs(self.s, self.model, self.lp) {
                let c = self.check(d, a)?;
                if c.rank.safe && c.rank.beats(&best.rank) {
                    best = c;
                }
            }
        }
        if best.predicted_safe {
            return Ok(best);
        }
        for (d, a) in retreat_inputs(self.s, self.model, self.lp) {
            let c = self.check_within(d, a, Goal::Retreat)?;
            if c.rank.beats(&best.rank) {
                best = c;
            }
        }
        if self.s.fallback_lattice
            && !best.rank.safe
            && self.lp.start[3] >= self.s.lattice_min_speed
            && (!self.s.lattice_when_fallback_hits
                || !self.clear_without_reaction(&best.rollout)?)
        {
            best = self.best_of_lattice(best)?;
        }
        Ok(best)
    }

    /// The best by [`Rank`] of `best` and the [`lattice_inputs`] (the first on ties), stopping
    /// at the first admissible one or when the budget is spent. With
    /// `PlannerSettings::lattice_clear_nonreactive` a lattice sequence replaces the best only
    /// when [`Self::clear_without_reaction`].
    fn best_of_lattice(&mut self, mut best: Candidate) -> Result<Candidate, PlannerError> {
        for (d, a) in lattice_inputs(self.lp) {
            let c = self.check(d, a)?;
            if c.rank.beats(&best.rank)
                && (!self.s.lattice_clear_nonreactive || self.clear_without_reaction(&c.rollout)?)
            {
                best = c;
                if best.rank.safe {
                    break;
                }
            }
            if self.safety.budget.exhausted {
                break;
            }
        }
        Ok(best)
    }

    /// Whether `rollout`'s box overlaps no other vehicle's under the non-reactive
    /// (constant-velocity) prediction, at any step: a sequence found by the lattice search
    /// must not count on anybody making room. True when nothing is checked.
    fn clear_without_reaction(&mut self, rollout: &[State]) -> Result<bool, PlannerError> {
        let Some(p) = self.nonreactive.as_deref_mut() else {
            return Ok(true);
        };
        let counted = self.safety.count_overlap;
        self.safety.count_overlap = true;
        let e = self.safety.eval_nonreactive(p, rollout);
        self.safety.count_overlap = counted;
        let e = e?;
        Ok(e.min_b.is_none_or(f64::is_finite) && e.overlap <= EXCESS_TOLERANCE)
    }
}

/// `nominal + θ·(u − nominal)`, made feasible for `bounds`.
fn towards(u: &[f64], nominal: &[f64], theta: f64, bounds: RateBox) -> Vec<f64> {
    let mut out: Vec<f64> = u
        .iter()
        .zip(nominal)
        .map(|(u, n)| n + theta * (u - n))
        .collect();
    repair_box_rate(&mut out, bounds);
    out
}

/// The acceleration profiles `[T]` (m/s²) of the fallback, in order, each within the box and
/// jerk bounds ([`repair_box_rate`]): the constants 0, a_min/2, a_min, a_max/2; then, with
/// `fallback_full_accel`, the constant a_max; then, with `fallback_brake_hold`, "brake, then
/// hold": a_min for the first k steps and 0 after, for k = ⌈T/3⌉ and ⌈2T/3⌉ (those below T,
/// once each), which shed part of the speed and keep the rest; then, with
/// `fallback_match_speed` and without `match_admissible_only`, [`match_speed_accels`] to each of
/// [`LinearisedProblem::lead_speeds`] (with it, those are [`match_inputs`], apart).
pub(crate) fn fallback_accels(s: &PlannerSettings, lp: &LinearisedProblem) -> Vec<Vec<f64>> {
    let t = lp.horizon;
    let mut profiles: Vec<Vec<f64>> = [0.0, 0.5 * s.a_min, s.a_min, 0.5 * s.a_max]
        .into_iter()
        .map(|a_cmd| vec![a_cmd; t])
        .collect();
    if s.fallback_full_accel {
        profiles.push(vec![s.a_max; t]);
    }
    if s.fallback_brake_hold {
        let mut brake_steps = vec![t.div_ceil(3), (2 * t).div_ceil(3)];
        brake_steps.dedup();
        for k in brake_steps.into_iter().filter(|&k| k > 0 && k < t) {
            profiles.push((0..t).map(|i| if i < k { s.a_min } else { 0.0 }).collect());
        }
    }
    if !s.match_admissible_only {
        for &v_goal in &lp.lead_speeds {
            profiles.push(match_speed_accels(s, lp, v_goal));
        }
    }
    for a in &mut profiles {
        repair_box_rate(a, lp.accel_box);
    }
    profiles
}

/// Accelerations `[T]` (m/s²) that brake the ego from its start speed to `v_goal` (m/s, ≥ 0)
/// and then hold it (`PlannerSettings::fallback_match_speed`): each step takes the hardest
/// braking within the box and jerk bounds after which the speed, less what it still loses
/// while the brake unwinds to 0 at the jerk bound ([`unwind_loss`]), stays at or above
/// `v_goal`; with none such, the least braking the bounds allow (never more than 0 unless the
/// jerk bound keeps it positive). The speed advances by a·dt, floored at 0.
pub(crate) fn match_speed_accels(
    s: &PlannerSettings,
    lp: &LinearisedProblem,
    v_goal: f64,
) -> Vec<f64> {
    const BISECTIONS: usize = 50;
    let b = lp.accel_box;
    let (mut v, mut prev) = (lp.start[3].max(0.0), b.prev);
    let mut out = Vec::with_capacity(lp.horizon);
    for _ in 0..lp.horizon {
        let lo = b.lo.max(prev - b.rate);
        let hi = b.hi.min(prev + b.rate);
        let keeps = |a: f64| v + a * s.dt - unwind_loss(a, b.rate, s.dt) >= v_goal;
        let least = hi.min(0.0).max(lo);
        let a = if !keeps(least) {
            least
        } else if keeps(lo) {
            lo
        } else {
            // keeps(a) is monotone on [lo, least]: false at lo, true at least.
            let (mut bad, mut good) = (lo, least);
            for _ in 0..BISECTIONS {
                let mid = 0.5 * (bad + good);
                if keeps(mid) {
                    good = mid;
                } else {
                    bad = mid;
                }
            }
            good
        };
        v = (v + a * s.dt).max(0.0);
        prev = a;
        out.push(a);
    }
    out
}

/// The speed (m/s) still lost after a step at acceleration `a` (m/s², braking when
/// negative) while the brake unwinds to 0 at `rate` (m/s² per step), a step of `dt` (s) at
/// each: dt · Σ_{j ≥ 1} max(|a| − j·rate, 0); 0 when `a` ≥ 0.
pub(crate) fn unwind_loss(a: f64, rate: f64, dt: f64) -> f64 {
    if a >= 0.0 || rate <= 0.0 {
        return 0.0;
    }
    let mut rest = -a - rate;
    let mut loss = 0.0;
    while rest > 0.0 {
        loss += rest;
        rest -= rate;
    }
    loss * dt
}

/// Steps each choice of the fallback's input lattice is held ([`lattice_inputs`]).
pub(crate) const LATTICE_HOLD: usize = 2;

/// The choices of one block of an input lattice ([`lattice_inputs`]; the log-replay oracle of
/// `nudge-research` searches the same choices): the change per step of the steering and of the
/// acceleration, in units of their rate bounds; holding the inputs first, then braking, then
/// the rest.
pub(crate) const LATTICE_RATES: [(f64, f64); 9] = [
    (0.0, 0.0),
    (0.0, -1.0),
    (-1.0, -1.0),
    (1.0, -1.0),
    (-1.0, 0.0),
    (1.0, 0.0),
    (0.0, 1.0),
    (-1.0, 1.0),
    (1.0, 1.0),
];

/// Blocks of [`LATTICE_HOLD`] steps over which the fallback's input lattice branches
/// ([`lattice_inputs`]): the shipped 6-step horizon exactly, and at most 9³ = 729 sequences
/// whatever the horizon.
pub(crate) const LATTICE_BLOCKS: usize = 3;

/// The input lattice of the fallback (`PlannerSettings::fallback_lattice`): from the inputs
/// applied last, every sequence `[T]` that in each of its first [`LATTICE_BLOCKS`] blocks of
/// [`LATTICE_HOLD`] steps changes the steering by −, 0 or + its rate bound per step and the
/// acceleration likewise, each clipped to its box (so within the box and rate bounds by
/// construction), and holds its last inputs after them (horizons beyond
/// `LATTICE_BLOCKS` × `LATTICE_HOLD` steps); sequences equal after clipping appear once, in
/// the order of the choices (holding first, then braking, then the rest). At most
/// 9^min(⌈T/`LATTICE_HOLD`⌉, `LATTICE_BLOCKS`).
pub(crate) fn lattice_inputs(lp: &LinearisedProblem) -> Vec<(Vec<f64>, Vec<f64>)> {
    let (db, ab) = (lp.delta_box, lp.accel_box);
    let mut out: Vec<(Vec<f64>, Vec<f64>)> = vec![(Vec::new(), Vec::new())];
    for start in (0..lp.horizon).step_by(LATTICE_HOLD).take(LATTICE_BLOCKS) {
        let steps = LATTICE_HOLD.min(lp.horizon - start);
        let mut next = Vec::with_capacity(out.len() * LATTICE_RATES.len());
        for (d, a) in &out {
            let prev = (
                d.last().copied().unwrap_or(db.prev.clamp(db.lo, db.hi)),
                a.last().copied().unwrap_or(ab.prev.clamp(ab.lo, ab.hi)),
            );
            let mut firsts: Vec<(f64, f64)> = Vec::with_capacity(LATTICE_RATES.len());
            for (rd, ra) in LATTICE_RATES {
                let step = |p: (f64, f64)| {
                    (
                        (p.0 + rd * db.rate).clamp(db.lo, db.hi),
                        (p.1 + ra * ab.rate).clamp(ab.lo, ab.hi),
                    )
                };
                // Choices that clip to the same first inputs give the same block.
                let first = step(prev);
                if firsts.contains(&first) {
                    continue;
                }
                firsts.push(first);
                let (mut d, mut a, mut p) = (d.clone(), a.clone(), prev);
                for _ in 0..steps {
                    p = step(p);
                    d.push(p.0);
                    a.push(p.1);
                }
                next.push((d, a));
            }
        }
        out = next;
    }
    for (d, a) in &mut out {
        if let (Some(&last_d), Some(&last_a)) = (d.last(), a.last()) {
            d.resize(lp.horizon, last_d);
            a.resize(lp.horizon, last_a);
        }
    }
    out
}

/// The simple input sequences of the fallback besides the nominal, in order: the
/// [`keep_or_steer`] sequences of the profiles of [`fallback_accels`]; then, when the ego's
/// lane really ends ahead, the [`stop_inputs`]; then, with `PlannerSettings::fallback_shy`,
/// the [`shy_inputs`].
pub(crate) fn simple_inputs(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let mut inputs = keep_or_steer(model, lp, fallback_accels(s, lp));
    inputs.extend(stop_inputs(s, model, lp));
    inputs.extend(shy_inputs(s, model, lp));
    inputs
}

/// Clearance (m) the shy sequences' goals keep between the ego's box and its own lane's lines
/// (`PlannerSettings::fallback_shy`): its box stays off the line it moves towards.
pub const SHY_CLEARANCE: f64 = 0.1;

/// The smallest move across the road (m) that makes a shy goal: a goal nearer the ego's
/// start than this is no sequence of its own (the keep-lane one already holds it).
pub const SHY_MIN_SHIFT: f64 = 0.05;

/// The lateral goals (m, the call's frame) of the shy sequences (`PlannerSettings::fallback_shy`),
/// right first: in the lane holding the ego's centre at the start, the positions where its
/// box (at heading 0) keeps [`SHY_CLEARANCE`] from the lane's right and from its left line,
/// each clamped into the call's lateral bounds at the last step; only those at least
/// [`SHY_MIN_SHIFT`] from the start. Empty without a lane layout, with the centre off the
/// lanes, or with a lane too narrow for the box and its clearance.
pub(crate) fn shy_goals(lp: &LinearisedProblem) -> Vec<f64> {
    let Some(lanes) = &lp.lanes else {
        return Vec::new();
    };
    let lanes = lanes.view();
    let y0 = lp.origin[1];
    let Some(j) = lanes.lane_at(y0) else {
        return Vec::new();
    };
    let half = 0.5 * lp.ego_size[1] + SHY_CLEARANCE;
    let (right, left) = (lanes.bounds[j] + half - y0, lanes.bounds[j + 1] - half - y0);
    if right > left {
        return Vec::new();
    }
    let (Some(lower), Some(upper)) = (lp.lower.last(), lp.upper.last()) else {
        return Vec::new();
    };
    [right, left]
        .into_iter()
        .map(|y| y.max(lower[1]).min(upper[1]))
        .filter(|y| y.abs() >= SHY_MIN_SHIFT)
        .collect()
}

/// The shy sequences of the fallback (none unless `PlannerSettings::fallback_shy`): for each
/// goal of [`shy_goals`], each profile of [`fallback_accels`] with [`steer_towards`] it.
pub(crate) fn shy_inputs(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    if !s.fallback_shy {
        return Vec::new();
    }
    let max_heading = lp.upper.iter().map(|u| u[2]).fold(f64::INFINITY, f64::min);
    let profiles = fallback_accels(s, lp);
    let mut inputs = Vec::new();
    for y_goal in shy_goals(lp) {
        for a in &profiles {
            let d = steer_towards(model, &lp.start, a, y_goal, max_heading, lp.delta_box);
            inputs.push((d, a.clone()));
        }
    }
    inputs
}

/// The match-speed sequences of the fallback checked apart from the others
/// (`PlannerSettings::match_admissible_only`): the [`keep_or_steer`] sequences of the
/// [`match_speed_accels`] to each of [`LinearisedProblem::lead_speeds`] (none unless
/// `PlannerSettings::fallback_match_speed`).
pub(crate) fn match_inputs(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let profiles = lp
        .lead_speeds
        .iter()
        .map(|&v_goal| match_speed_accels(s, lp, v_goal))
        .collect();
    keep_or_steer(model, lp, profiles)
}

/// For each acceleration profile `[T]` (m/s²) of `profiles`, in order, the steering of
/// [`align_with_road`], then that of [`steer_towards`] the lateral goal, each paired with it.
fn keep_or_steer(
    model: &Bicycle,
    lp: &LinearisedProblem,
    profiles: Vec<Vec<f64>>,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let max_heading = lp.upper.iter().map(|u| u[2]).fold(f64::INFINITY, f64::min);
    let mut inputs = Vec::with_capacity(2 * profiles.len() + 3);
    for a in profiles {
        inputs.push((
            align_with_road(model, &lp.start, &a, lp.delta_box),
            a.clone(),
        ));
        let d = steer_towards(
            model,
            &lp.start,
            &a,
            lp.reference[1],
            max_heading,
            lp.delta_box,
        );
        inputs.push((d, a));
    }
    inputs
}

/// The stopping sequences of the fallback (none unless the ego's lane really ends ahead of
/// its start, [`super::linearised::StopLine`]): the accelerations of [`stop_accels`] with
/// [`align_with_road`], with [`steer_towards`] the own lane's centre and with
/// [`steer_towards`] the lateral goal (waiting at the line for a gap).
pub(crate) fn stop_inputs(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let Some(line) = lp.stop_line else {
        return Vec::new();
    };
    let a = stop_accels(s, lp, line.x);
    let max_heading = lp.upper.iter().map(|u| u[2]).fold(f64::INFINITY, f64::min);
    let steer = |y| steer_towards(model, &lp.start, &a, y, max_heading, lp.delta_box);
    vec![
        (
            align_with_road(model, &lp.start, &a, lp.delta_box),
            a.clone(),
        ),
        (steer(line.y_own), a.clone()),
        (steer(lp.reference[1]), a.clone()),
    ]
}

/// Accelerations `[T]` (m/s²) that stop the ego at `line` (m along the road from its start,
/// call frame): each step brakes at v² / (2 · (line − x)), the constant deceleration that
/// stops exactly at the line (`a_min` once at or past it, 0 once stopped), within the box and
/// jerk bounds; x and v advance along the road.
pub(crate) fn stop_accels(s: &PlannerSettings, lp: &LinearisedProblem, line: f64) -> Vec<f64> {
    let b = lp.accel_box;
    let (mut x, mut v, mut prev) = (lp.start[0], lp.start[3].max(0.0), b.prev);
    let mut out = Vec::with_capacity(lp.horizon);
    for _ in 0..lp.horizon {
        let gap = line - x;
        let wanted = if v <= 0.0 {
            0.0
        } else if gap <= 0.0 {
            s.a_min
        } else {
            -v * v / (2.0 * gap)
        };
        let a = wanted.clamp(b.lo.max(prev - b.rate), b.hi.min(prev + b.rate));
        let v_next = (v + a * s.dt).max(0.0);
        x += 0.5 * (v + v_next) * s.dt;
        v = v_next;
        prev = a;
        out.push(a);
    }
    out
}

/// The retreat sequences of the fallback (none when the problem has no retreat lane): for
/// each profile of [`fallback_accels`], [`steer_towards`] the retreat lane's centre.
pub(crate) fn retreat_inputs(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let Some(retreat) = &lp.retreat else {
        return Vec::new();
    };
    let max_heading = retreat
        .upper
        .iter()
        .map(|u| u[2])
        .fold(f64::INFINITY, f64::min);
    fallback_accels(s, lp)
        .into_iter()
        .map(|a| {
            let d = steer_towards(model, &lp.start, &a, retreat.y, max_heading, lp.delta_box);
            (d, a)
        })
        .collect()
}

/// The violation of a candidate's safety: −∞ (a NaN prediction) counts as infinitely
/// violating, otherwise the evaluator's total violation, at least `safety_min − min_b` when
/// that is positive.
fn safety_violation(min_b: Option<f64>, violation: f64, safety_min: f64) -> f64 {
    min_b.map_or(0.0, |b| violation.max(safety_min - b).max(0.0))
}

/// Steering that turns the vehicle parallel to the road (heading → 0) while it follows
/// `accel` (m/s²), within the box and rate bounds: [`steer_to_heading`] with goal 0.
pub(crate) fn align_with_road(
    model: &Bicycle,
    start: &State,
    accel: &[f64],
    bounds: RateBox,
) -> Vec<f64> {
    steer_to_heading(model, start, accel, bounds, |_| 0.0)
}

/// Steering that turns the vehicle towards the lateral goal `y_goal` (m, same frame as
/// `start`) while it follows `accel` (m/s²): each step aims at the heading
/// ψ* = clamp(0.05·(y_goal − y), ±min(0.08, `max_heading`)) rad and steers to reach it in one
/// step, within the box and rate bounds.
pub(crate) fn steer_towards(
    model: &Bicycle,
    start: &State,
    accel: &[f64],
    y_goal: f64,
    max_heading: f64,
    bounds: RateBox,
) -> Vec<f64> {
    let cap = max_heading.min(0.08);
    steer_to_heading(model, start, accel, bounds, |z| {
        (0.05 * (y_goal - z[1])).clamp(-cap, cap)
    })
}

/// Steering towards the heading `goal(z)` (rad) of the current state while the vehicle
/// follows `accel` (m/s²), within the box and rate bounds: each step takes, among the
/// steering values the bounds allow, the one whose heading after this step plus the turn it
/// takes to unwind the steering back to zero at the rate bound lands closest to the goal (so
/// the heading does not overshoot because the steering cannot be undone at once).
fn steer_to_heading(
    model: &Bicycle,
    start: &State,
    accel: &[f64],
    bounds: RateBox,
    goal: impl Fn(&State) -> f64,
) -> Vec<f64> {
    const CHOICES: usize = 40;
    let mut z = *start;
    let mut prev = bounds.prev.clamp(bounds.lo, bounds.hi);
    let mut out = Vec::with_capacity(accel.len());
    for a in accel {
        let heading_goal = goal(&z);
        // ψ⁺ − ψ ≈ gain·δ with gain = dt·v·sin β / (l_r δ), β ≈ δ·l_r/(l_f + l_r).
        let gain = model.dt * z[3].max(1.0) / (model.l_f + model.l_r);
        let lo = bounds.lo.max(prev - bounds.rate);
        let hi = bounds.hi.min(prev + bounds.rate);
        let unwind = |d: f64| {
            let (mut rest, mut turn) = (d.abs(), 0.0);
            while rest > bounds.rate {
                rest -= bounds.rate;
                turn += rest;
            }
            gain * turn * d.signum()
        };
        let mut best = (f64::INFINITY, prev.clamp(lo, hi));
        for i in 0..=CHOICES {
            let d = lo + (hi - lo) * i as f64 / CHOICES as f64;
            let miss = (z[2] + gain * d + unwind(d) - heading_goal).abs();
            if miss < best.0 {
                best = (miss, d);
            }
        }
        let d = best.1;
        z = model.advance(&z, d, *a);
        out.push(d);
        prev = d;
    }
    out
}
