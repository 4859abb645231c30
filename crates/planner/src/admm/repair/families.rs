//! The candidate families of the fallback: pure generators of input sequences (steering and
//! acceleration, `[T]` each) from the call's linearised problem. None of them calls the
//! predictor; [`super::Repairer::best_fallback`] checks and ranks what they generate.

use crate::model::{Bicycle, State};
use crate::qp::{RateBox, repair_box_rate};
use crate::settings::PlannerSettings;

use super::super::decision::Family;
use super::super::linearised::LinearisedProblem;

/// An input sequence: steering `[T]` (rad) and acceleration `[T]` (m/s²).
pub(crate) type Inputs = (Vec<f64>, Vec<f64>);

/// The fallbacks' constant acceleration profiles (m/s², `[T]` each): 0, a_min/2, a_min and
/// a_max/2, each made feasible for the box and jerk bounds from the previous acceleration.
pub(crate) fn fallback_accels(s: &PlannerSettings, lp: &LinearisedProblem) -> Vec<Vec<f64>> {
    let t = lp.horizon;
    let mut profiles: Vec<Vec<f64>> = [
        0.0,
        0.5 * s.bounds.a_min,
        s.bounds.a_min,
        0.5 * s.bounds.a_max,
    ]
    .into_iter()
    .map(|a_cmd| vec![a_cmd; t])
    .collect();
    for a in &mut profiles {
        repair_box_rate(a, lp.accel_box);
    }
    profiles
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
/// The [`Family::KeepLane`] and [`Family::SteerToGoal`] sequences of every
/// [`fallback_accels`] profile (in that order, profile by profile), then the [`Family::Stop`]
/// sequences ([`stop_inputs`]), each with its family.
pub(crate) fn simple_families(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
) -> Vec<(Family, Inputs)> {
    let max_heading = lp.upper.iter().map(|u| u[2]).fold(f64::INFINITY, f64::min);
    let profiles = fallback_accels(s, lp);
    let mut out = Vec::with_capacity(2 * profiles.len() + 3);
    for a in profiles {
        let keep = align_with_road(model, &lp.start, &a, lp.delta_box);
        out.push((Family::KeepLane, (keep, a.clone())));
        let d = steer_towards(
            model,
            &lp.start,
            &a,
            lp.reference[1],
            max_heading,
            lp.delta_box,
        );
        out.push((Family::SteerToGoal, (d, a)));
    }
    out.extend(
        stop_inputs(s, model, lp)
            .into_iter()
            .map(|i| (Family::Stop, i)),
    );
    out
}

/// [`simple_families`] without the families.
#[cfg(test)]
pub(crate) fn simple_inputs(
    s: &PlannerSettings,
    model: &Bicycle,
    lp: &LinearisedProblem,
) -> Vec<Inputs> {
    simple_families(s, model, lp)
        .into_iter()
        .map(|(_, i)| i)
        .collect()
}

/// The stopping sequences of the fallback (none unless the ego's lane really ends ahead of
/// its start, [`super::super::linearised::StopLine`]): the accelerations of [`stop_accels`] with
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
            s.bounds.a_min
        } else {
            -v * v / (2.0 * gap)
        };
        let a = wanted.clamp(b.lo.max(prev - b.rate), b.hi.min(prev + b.rate));
        let v_next = (v + a * s.model.dt).max(0.0);
        x += 0.5 * (v + v_next) * s.model.dt;
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
