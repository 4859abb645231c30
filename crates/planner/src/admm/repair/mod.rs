//! The execution check and its repairs. The vehicle follows the nonlinear roll-out of (Δ, α),
//! not Z, and a plan is *admissible* when that roll-out is safe (every checked b > safety_min
//! under the predictor's prediction of it) and within the state bounds (heading, lateral
//! corridor, road). Every candidate's steering is first governed to the heading bound
//! ([`super::heading::govern_heading`]). When the ADMM roll-out is not admissible:
//! 1. [`Repairer::refine`]: SQP steps on the nonlinear roll-out from the ADMM inputs
//!    ([`super::refine`]); the first admissible roll-out;
//! 2. else [`Repairer::backtrack`]: pull (Δ, α) towards the nominal (the shifted previous
//!    plan) by θ = 3/4, 1/2, 1/4 and take the first admissible roll-out;
//! 3. else [`Repairer::best_fallback`]: the best by [`Rank`] of the candidate families
//!    ([`families`]), generated as pure functions of the call and ranked by the fixed key
//!    list [`RANK_ORDER`].
//!
//! A failed QP skips the check: the ADMM iterates are dropped and the best fallback is the plan.
//! Every candidate returned records what chose it ([`Candidate::chosen`]), which reaches the
//! plan as [`super::DecidedBy`].

pub(crate) mod families;
mod rank;

use nudge_predictor::Predictor;

use crate::error::PlannerError;
use crate::extents::LaneViolationKind;
use crate::model::{Bicycle, State};
use crate::qp::{RateBox, repair_box_rate};
use crate::settings::PlannerSettings;

use super::constraint::{Evaluation, SafetyEval, SafetyRow};
use super::decision::{Family, RankKey};
use super::heading::govern_heading;
use super::linearised::LinearisedProblem;
use super::refine;

pub(crate) use families::{Inputs, lattice_inputs, retreat_inputs, simple_families};
#[cfg(test)]
pub(crate) use families::{align_with_road, fallback_accels, simple_inputs};
pub(crate) use rank::{EXCESS_TOLERANCE, EXCESS_WEIGHT, Rank, Violations};

/// An input sequence checked on its roll-out.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Candidate {
    /// Steering `[T]` (rad), as governed to the heading bound.
    pub delta: Vec<f64>,
    /// Acceleration `[T]` (m/s²).
    pub accel: Vec<f64>,
    /// Its roll-out z_1..z_T (call frame).
    pub rollout: Vec<State>,
    /// Minimum b of the roll-out (`None` when nothing is checked).
    pub min_b: Option<f64>,
    /// The predictor's verdict: the roll-out is safe at `safety_min` (state bounds aside).
    pub predicted_safe: bool,
    /// The heading governor changed the steering it was given.
    pub governed: bool,
    /// How it ranks among fallbacks.
    pub rank: Rank,
    /// The safety rows of the roll-out's evaluation (for the refinement).
    pub rows: Vec<SafetyRow>,
    /// For a candidate returned by [`Repairer::best_fallback`]: its family and the rank key by
    /// which it beat the best before it (`None` for the first one checked, the nominal, when
    /// nothing beat it).
    pub chosen: Option<(Family, Option<RankKey>)>,
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
    /// Settings of the call.
    pub s: &'a PlannerSettings,
    /// The vehicle model.
    pub model: &'a Bicycle,
    /// The call's linearised problem (bounds, nominal, reference).
    pub lp: &'a LinearisedProblem,
    /// The safety evaluator (counts predictor calls, holds the budget).
    pub safety: &'a mut SafetyEval<'c>,
    /// The planning predictor.
    pub predictor: &'a mut dyn Predictor,
    /// The constant-velocity predictor under which a lattice sequence must hit nobody;
    /// `None` when nothing is checked.
    pub nonreactive: Option<&'a mut dyn Predictor>,
}

/// The violation of a candidate's safety: −∞ (a NaN prediction) counts as infinitely
/// violating, otherwise the evaluator's total violation, at least `safety_min − min_b` when
/// that is positive.
fn safety_violation(min_b: Option<f64>, violation: f64, safety_min: f64) -> f64 {
    min_b.map_or(0.0, |b| violation.max(safety_min - b).max(0.0))
}

impl Repairer<'_, '_> {
    /// Governs `delta` to the heading bound, rolls (Δ, α) out from the measured state and
    /// checks it: predictor, state bounds, [`Rank`].
    pub(crate) fn check(
        &mut self,
        delta: Vec<f64>,
        accel: Vec<f64>,
    ) -> Result<Candidate, PlannerError> {
        self.check_within(delta, accel, Goal::Target)
    }

    /// [`Self::check`] within the state bounds of `goal`.
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
        let given = delta.clone();
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
        let governed = delta != given;
        let mut rollout = vec![State::zeros(); self.lp.horizon];
        self.model
            .rollout(&self.lp.start, &delta, &accel, &mut rollout);
        let e = self.safety.eval(self.predictor, &rollout)?;
        let excess = match (goal, &self.lp.retreat) {
            (Goal::Retreat, Some(r)) => self.lp.bound_excess_within(&r.lower, &r.upper, &rollout),
            _ => self.lp.bound_excess(&rollout),
        };
        let rows = self.safety.rows.clone();
        let predicted_safe = e.is_safe(self.s.safety.safety_min);
        let unbegun = self.lp.lanes.as_ref().is_some_and(|lanes| {
            let lanes = lanes.view();
            self.lp.to_world(&rollout).iter().any(|z| {
                matches!(
                    lanes.outside(z[0], z[1]),
                    Some((_, LaneViolationKind::NotBegun))
                )
            })
        });
        let rank = if predicted_safe && excess <= EXCESS_TOLERANCE {
            Rank::admissible(unbegun, self.lp.cost(self.s, &delta, &accel, &rollout))
        } else {
            Rank::inadmissible(self.s, &self.violations(&rollout, &e, excess, unbegun))
        };
        Ok(Candidate {
            delta,
            accel,
            rollout,
            min_b: e.min_b,
            predicted_safe,
            governed,
            rank,
            rows,
            chosen: None,
        })
    }

    /// What an inadmissible `rollout` (evaluation `e`, state-bound excess `excess`) ranks by.
    fn violations(
        &self,
        rollout: &[State],
        e: &Evaluation,
        excess: f64,
        unbegun: bool,
    ) -> Violations {
        let s = self.s;
        let floor = s.repair.fallback_speed_floor;
        let v_end = rollout.last().map_or(self.lp.start[3], |z| z[3]);
        let clear = floor > 0.0
            && excess <= s.repair.bounds_slack.max(EXCESS_TOLERANCE)
            && safety_violation(e.path_min_b, e.path_violation, s.safety.safety_min) == 0.0
            && v_end >= floor * self.lp.reference[3];
        let lead = self.lead_applies();
        Violations {
            unbegun,
            clear,
            value: safety_violation(e.min_b, e.violation, s.safety.safety_min)
                + EXCESS_WEIGHT * excess,
            bound_excess: excess,
            contact: e.overlap,
            edge: self.lp.edge_excess(rollout),
            ahead: if lead { e.ahead_violation } else { 0.0 },
            leaves_lane: lead && self.lp.spans_line(rollout),
        }
    }

    /// Whether the lead rule ([`RankKey::KeepsLane`], [`RankKey::Ahead`]) ranks this call's
    /// inadmissible candidates: the ego at least as fast as `lead_min_speed` at the start of
    /// the call and its box spanning no lane line there
    /// ([`LinearisedProblem::starts_in_one_lane`]).
    fn lead_applies(&self) -> bool {
        self.lp.start[3] >= self.s.repair.lead_min_speed && self.lp.starts_in_one_lane()
    }

    /// Up to `refine_iters` SQP steps ([`refine::step`]) from the inadmissible `from`; the
    /// first admissible roll-out, or `None`.
    pub(crate) fn refine(&mut self, from: &Candidate) -> Result<Option<Candidate>, PlannerError> {
        let (mut delta, mut accel, mut rows) =
            (from.delta.clone(), from.accel.clone(), from.rows.clone());
        for _ in 0..self.s.repair.refine_iters {
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
    /// admissible.
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

    /// The best by [`Rank`] (the first on ties) of the families, in order: the nominal, the
    /// keep-lane, steer-to-goal and stop sequences; when the best of these is unsafe by the
    /// prediction (not only outside the state bounds), the retreat sequences (checked within
    /// the retreat's bounds); when still nothing is admissible and the ego is at least as fast
    /// as `lattice_min_speed`, the lattice ([`Self::best_of_lattice`]). With nothing
    /// admissible this is the minimum-risk choice between holding, finishing and cancelling a
    /// lane change.
    pub(crate) fn best_fallback(&mut self) -> Result<Candidate, PlannerError> {
        let nominal = (self.lp.nominal_delta.clone(), self.lp.nominal_accel.clone());
        let mut best = self.check(nominal.0, nominal.1)?;
        best.chosen = Some((Family::Nominal, None));
        for (family, (d, a)) in simple_families(self.s, self.model, self.lp) {
            let c = self.check(d, a)?;
            best = keep_better(best, c, family);
        }
        if best.predicted_safe {
            return Ok(best);
        }
        for (d, a) in retreat_inputs(self.s, self.model, self.lp) {
            let c = self.check_within(d, a, Goal::Retreat)?;
            best = keep_better(best, c, Family::Retreat);
        }
        if !best.rank.safe && self.lp.start[3] >= self.s.repair.lattice_min_speed {
            best = self.best_of_lattice(best, lattice_inputs(self.lp))?;
        }
        Ok(best)
    }

    /// The best by [`Rank`] of `best` and the `lattice` sequences (the first on ties), a
    /// lattice sequence replacing the best only when it hits nobody without reaction
    /// ([`Self::clear_without_reaction`]); stops at the first admissible one or when the
    /// budget is spent.
    fn best_of_lattice(
        &mut self,
        mut best: Candidate,
        lattice: Vec<Inputs>,
    ) -> Result<Candidate, PlannerError> {
        for (d, a) in lattice {
            let mut c = self.check(d, a)?;
            let (key, wins) = c.rank.decide(&best.rank);
            if wins && self.clear_without_reaction(&c.rollout)? {
                c.chosen = Some((Family::Lattice, Some(key)));
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

/// `candidate` (of `family`) when it beats `best`, recording the deciding key; else `best`.
fn keep_better(best: Candidate, mut candidate: Candidate, family: Family) -> Candidate {
    let (key, wins) = candidate.rank.decide(&best.rank);
    if wins {
        candidate.chosen = Some((family, Some(key)));
        candidate
    } else {
        best
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
