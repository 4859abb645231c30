//! Could a log-replay collision have been avoided at all, and from when? An oracle that knows
//! the whole logged future searches the ego's inputs for a continuation without contact.
//!
//! In a [`World::LogReplay`](nudge_sim::World::LogReplay) run the other vehicles follow the
//! log whatever the ego does ([`logged_position`]), so their boxes at every step are known in
//! advance ([`LoggedTraffic`]). From the ego's state before closed-loop step `k` (and the inputs
//! it applied at step `k − 1`), [`avoid`] searches sequences of inputs (δ, a) for steps
//! `k..=until` for one along which the ego's box overlaps no other vehicle's at any step
//! (the separating-axis test of the collision metric, [`contacts`]), no corner
//! leaves the road by more than the run's off-road tolerance, the heading stays within the
//! planner's bound and the speed within `[0, v_max]`. The inputs keep the planner's own bounds
//! ([`OracleLimits::of`]): box bounds on δ and a, and their per-step rates.
//!
//! The search is exhaustive over a lattice: each block of [`OracleLimits::hold`] steps changes
//! δ by −ddelta_max, 0 or +ddelta_max per step and a by −da_max, 0 or +da_max per step (each
//! clipped to its box), 9 choices per block, depth first, pruning a branch at its first
//! contact or violation. [`Avoidance::Avoidable`] is therefore a proof (the inputs are
//! returned and can be replayed, [`replay`]); [`Avoidance::Unavoidable`] means no sequence of
//! the lattice avoids it, a strong indication rather than a proof for the continuum of inputs
//! between; [`Avoidance::Undecided`] means the search hit [`OracleLimits::max_nodes`].

use nudge_planner::{Bicycle, PlannerSettings, Scenario, State, motion_heading};
use nudge_predictor::{DT, T_OBS};
use nudge_sim::metrics::{Vehicle, contacts, ego_box, others_from_history, road_excess};
use nudge_sim::world::logged_position;

/// The other vehicles of a log-replay run of one scene at every closed-loop step, as the
/// simulator sees them: `steps[k]` holds agents 1..n after step `k` (agent i at index i − 1),
/// each at its logged position with the heading and speed of its last displacement
/// ([`others_from_history`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LoggedTraffic {
    /// The others after each step, `[steps][n − 1]`.
    pub steps: Vec<Vec<Vehicle>>,
}

impl LoggedTraffic {
    /// The others of `sc` after steps `0..steps`, moved by the log exactly as the simulator's
    /// log-replay world with [`nudge_sim::SimConfig::replay_lateral_decay`] =
    /// `lateral_decay` moves them.
    #[must_use]
    pub fn new(sc: &Scenario, steps: usize, lateral_decay: f64) -> Self {
        let mut observed: Vec<Vec<[f64; 2]>> = (0..sc.n_agents)
            .map(|i| (0..T_OBS).map(|t| sc.position(i, t)).collect())
            .collect();
        let mut out = Vec::with_capacity(steps);
        for step in 0..steps {
            let moved: Vec<[f64; 2]> = observed
                .iter()
                .enumerate()
                .map(|(i, h)| {
                    if i == 0 {
                        h[T_OBS - 1]
                    } else {
                        logged_position(sc, i, h, step, lateral_decay)
                    }
                })
                .collect();
            for (h, p) in observed.iter_mut().zip(moved) {
                h.remove(0);
                h.push(p);
            }
            out.push(others_from_history(sc, &observed));
        }
        Self { steps: out }
    }

    /// What the ego could know before step `k`: the same traffic up to step `k − 1`, and from
    /// step `k` on every other vehicle extrapolated at the constant velocity of its last
    /// observed displacement (after steps `k − 2`, `k − 1`, or the scene's last observations
    /// of `sc` for `k` < 2), heading and speed held.
    #[must_use]
    pub fn extrapolated(&self, sc: &Scenario, k: usize) -> Self {
        let n = self.steps.len();
        let k = k.min(n);
        let at = |j: isize, i: usize| -> [f64; 2] {
            if j >= 0 {
                let b = &self.steps[j as usize][i].bbox;
                [b.x, b.y]
            } else {
                sc.position(i + 1, (T_OBS as isize + j) as usize)
            }
        };
        let mut steps = self.steps[..k].to_vec();
        let last = k as isize - 1;
        let template = self
            .steps
            .get(k.saturating_sub(1))
            .cloned()
            .unwrap_or_default();
        for s in k..n {
            let ahead = (s - k + 1) as f64;
            let row = template
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    let (a, b) = (at(last - 1, i), at(last, i));
                    let mut moved = *v;
                    moved.bbox.x = b[0] + ahead * (b[0] - a[0]);
                    moved.bbox.y = b[1] + ahead * (b[1] - a[1]);
                    if k == 0 {
                        moved.bbox.heading = motion_heading(a, b, sc.heading[i + 1]);
                        moved.vx = (b[0] - a[0]) / DT;
                    }
                    moved
                })
                .collect();
            steps.push(row);
        }
        Self { steps }
    }
}

/// The bounds of the oracle's inputs and states, and the size of its search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OracleLimits {
    /// Steering bound |δ| ≤ delta_max (rad).
    pub delta_max: f64,
    /// Steering rate per step |δ_k − δ_{k−1}| ≤ ddelta_max (rad); also the lattice's step.
    pub ddelta_max: f64,
    /// Acceleration bounds `[a_min, a_max]` (m/s²).
    pub accel: [f64; 2],
    /// Jerk bound per step |a_k − a_{k−1}| ≤ da_max (m/s²); also the lattice's step.
    pub da_max: f64,
    /// Upper speed bound (m/s).
    pub v_max: f64,
    /// Heading bound relative to the road (rad); ≥ π/2 leaves it unbounded.
    pub heading_max: f64,
    /// Rate (rad per step) at which the bound of an ego starting beyond `heading_max` returns
    /// to it.
    pub heading_recovery: f64,
    /// Steps each lattice choice is held (≥ 1).
    pub hold: usize,
    /// Lattice blocks the search may expand before it gives up ([`Avoidance::Undecided`]).
    pub max_nodes: usize,
}

impl OracleLimits {
    /// Blocks of two steps (0.6 s at the default `dt`), as the planner's lattice fallback.
    pub const DEFAULT_HOLD: usize = 2;
    /// At most two million blocks per search (a few seconds).
    pub const DEFAULT_MAX_NODES: usize = 2_000_000;

    /// The planner's own bounds from `settings`, with [`Self::DEFAULT_HOLD`] and
    /// [`Self::DEFAULT_MAX_NODES`].
    #[must_use]
    pub fn of(settings: &PlannerSettings) -> Self {
        Self {
            delta_max: settings.bounds.delta_max,
            ddelta_max: settings.bounds.ddelta_max,
            accel: [settings.bounds.a_min, settings.bounds.a_max],
            da_max: settings.bounds.da_max,
            v_max: settings.bounds.v_max,
            heading_max: settings.bounds.heading_max,
            heading_recovery: settings.bounds.heading_recovery,
            hold: Self::DEFAULT_HOLD,
            max_nodes: Self::DEFAULT_MAX_NODES,
        }
    }

    /// The heading bound (rad) of the state `j` steps after a start at heading `psi0`.
    fn heading_bound(&self, psi0: f64, j: usize) -> f64 {
        self.heading_max
            .max(psi0.abs() - self.heading_recovery * j as f64)
    }
}

/// Where the oracle starts: the ego before closed-loop step `step`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OracleStart {
    /// The first step whose input the oracle chooses.
    pub step: usize,
    /// The ego's state before that step (x, y, ψ, v) (m, m, rad, m/s).
    pub ego: [f64; 4],
    /// The inputs (δ, a) applied at the step before (rad, m/s²); (0, 0) before step 0, as
    /// the simulator starts.
    pub inputs: (f64, f64),
}

/// What the oracle found.
#[derive(Debug, Clone, PartialEq)]
pub enum Avoidance {
    /// A sequence of inputs (δ, a) (rad, m/s²), one per step `start.step..=until`, without
    /// contact or violation.
    Avoidable(Vec<(f64, f64)>),
    /// No sequence of the lattice avoids it; `nodes` blocks were expanded.
    Unavoidable {
        /// Blocks expanded.
        nodes: usize,
    },
    /// The search stopped at [`OracleLimits::max_nodes`] blocks without an answer.
    Undecided {
        /// Blocks expanded.
        nodes: usize,
    },
}

/// The scene and the run that a search or a replay is about.
#[derive(Debug, Clone, Copy)]
pub struct OracleWorld<'a> {
    /// The ego's vehicle model (the planner's, [`Planner::model`](nudge_planner::Planner::model)).
    pub bicycle: Bicycle,
    /// The ego's (length, width) (m).
    pub size: [f64; 2],
    /// The road's lane bounds `[L + 1]` (y, m).
    pub bounds: &'a [f64],
    /// How far a corner may lie beyond the road's edges (m): the run's off-road tolerance
    /// ([`nudge_sim::metrics::RunObserver::off_road_tolerance`]).
    pub road_tolerance: f64,
    /// The others at every step.
    pub traffic: &'a LoggedTraffic,
}

/// What went wrong first along a replayed sequence of inputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Violation {
    /// The ego's box overlaps agent `agent`'s after step `step`.
    Contact {
        /// Closed-loop step.
        step: usize,
        /// Agent index (1..n).
        agent: usize,
    },
    /// A corner of the ego's box lies beyond the road's edge by more than the tolerance.
    OffRoad {
        /// Closed-loop step.
        step: usize,
    },
    /// The heading left its bound, or the speed exceeded `v_max`.
    Bounds {
        /// Closed-loop step.
        step: usize,
    },
    /// The traffic does not cover the step.
    BeyondLog {
        /// Closed-loop step.
        step: usize,
    },
}

impl OracleWorld<'_> {
    /// The first violation of the ego in state `z` after closed-loop step `step`, the state
    /// being the `j`-th after a start at heading `psi0`.
    fn violation(
        &self,
        limits: &OracleLimits,
        psi0: f64,
        j: usize,
        step: usize,
        z: &State,
    ) -> Option<Violation> {
        let Some(others) = self.traffic.steps.get(step) else {
            return Some(Violation::BeyondLog { step });
        };
        if z[2].abs() > limits.heading_bound(psi0, j) + 1e-12 || z[3] > limits.v_max {
            return Some(Violation::Bounds { step });
        }
        let b = ego_box([z[0], z[1], z[2], z[3]], self.size);
        if road_excess(&b, self.bounds) > self.road_tolerance {
            return Some(Violation::OffRoad { step });
        }
        contacts(&b, others)
            .first()
            .map(|&agent| Violation::Contact { step, agent })
    }
}

/// Replays `inputs` (δ, a) (rad, m/s²) from `start` in `world`: the states after each step
/// `[inputs.len()]` and the first violation, if any (the states stop there). Checks the
/// states only; the inputs' own bounds are the caller's (the simulator's executed inputs keep
/// them by construction).
#[must_use]
pub fn replay(
    world: &OracleWorld<'_>,
    limits: &OracleLimits,
    start: &OracleStart,
    inputs: &[(f64, f64)],
) -> (Vec<[f64; 4]>, Option<Violation>) {
    let e = start.ego;
    let mut z = State::new(e[0], e[1], e[2], e[3]);
    let mut states = Vec::with_capacity(inputs.len());
    for (j, &(d, a)) in inputs.iter().enumerate() {
        z = world.bicycle.advance(&z, d, a);
        states.push([z[0], z[1], z[2], z[3]]);
        if let Some(v) = world.violation(limits, e[2], j + 1, start.step + j, &z) {
            return (states, Some(v));
        }
    }
    (states, None)
}

/// Searches inputs for steps `start.step..=until` along which the ego meets no other vehicle
/// and keeps the road and its bounds (see the module).
#[must_use]
pub fn avoid(
    world: &OracleWorld<'_>,
    limits: &OracleLimits,
    start: &OracleStart,
    until: usize,
) -> Avoidance {
    let mut search = Search {
        world,
        limits,
        psi0: start.ego[2],
        first: start.step,
        until,
        nodes: 0,
        inputs: Vec::new(),
    };
    if until < start.step {
        return Avoidance::Avoidable(Vec::new());
    }
    let e = start.ego;
    let z = State::new(e[0], e[1], e[2], e[3]);
    match search.dfs(start.step, z, start.inputs) {
        Some(true) => Avoidance::Avoidable(search.inputs),
        Some(false) => Avoidance::Unavoidable {
            nodes: search.nodes,
        },
        None => Avoidance::Undecided {
            nodes: search.nodes,
        },
    }
}

/// The depth-first search of [`avoid`].
struct Search<'w, 'a> {
    world: &'w OracleWorld<'a>,
    limits: &'w OracleLimits,
    psi0: f64,
    first: usize,
    until: usize,
    nodes: usize,
    /// The inputs of the current branch, steps `first..`.
    inputs: Vec<(f64, f64)>,
}

impl Search<'_, '_> {
    /// From state `z` before step `step` with previous inputs `prev`: `Some(true)` when a
    /// branch reaches past `until` (its inputs left in `self.inputs`), `Some(false)` when none
    /// does, `None` at the node limit.
    fn dfs(&mut self, step: usize, z: State, prev: (f64, f64)) -> Option<bool> {
        if step > self.until {
            return Some(true);
        }
        if self.nodes >= self.limits.max_nodes {
            return None;
        }
        self.nodes += 1;
        let l = self.limits;
        let steps = l.hold.max(1).min(self.until + 1 - step);
        let mut tried: Vec<(f64, f64)> = Vec::with_capacity(9);
        for (rd, ra) in lattice_rates() {
            let next = |p: (f64, f64)| {
                (
                    (p.0 + rd * l.ddelta_max).clamp(-l.delta_max, l.delta_max),
                    (p.1 + ra * l.da_max).clamp(l.accel[0], l.accel[1]),
                )
            };
            // Choices that clip to the same first input are the same block.
            let first_input = next(prev);
            if tried.contains(&first_input) {
                continue;
            }
            tried.push(first_input);
            let mark = self.inputs.len();
            let (mut zz, mut p, mut ok) = (z, prev, true);
            for s in step..step + steps {
                p = next(p);
                zz = self.world.bicycle.advance(&zz, p.0, p.1);
                self.inputs.push(p);
                let j = s + 1 - self.first;
                if self.world.violation(l, self.psi0, j, s, &zz).is_some() {
                    ok = false;
                    break;
                }
            }
            if ok {
                match self.dfs(step + steps, zz, p) {
                    Some(true) => return Some(true),
                    None => return None,
                    Some(false) => {}
                }
            }
            self.inputs.truncate(mark);
        }
        Some(false)
    }
}

/// The 9 choices of one lattice block: the change per step of the steering and of the
/// acceleration, in units of their rate bounds (−1, 0 or +1 each). Holding the inputs comes
/// first, then braking (straight, then steering either way), steering alone, and accelerating;
/// the order of the planner's own input-lattice fallback, so that a search tries first what the
/// planner's fallback would.
fn lattice_rates() -> impl Iterator<Item = (f64, f64)> {
    let steer = [0.0, -1.0, 1.0];
    std::iter::once((0.0, 0.0)).chain(
        [-1.0, 0.0, 1.0]
            .into_iter()
            .flat_map(move |accel| steer.into_iter().map(move |d| (d, accel)))
            .filter(|&c| c != (0.0, 0.0)),
    )
}

#[cfg(test)]
mod tests {
    use super::lattice_rates;

    #[test]
    fn the_lattice_holds_first_then_brakes_then_steers_then_accelerates() {
        let rates: Vec<(f64, f64)> = lattice_rates().collect();
        assert_eq!(
            rates,
            [
                (0.0, 0.0),
                (0.0, -1.0),
                (-1.0, -1.0),
                (1.0, -1.0),
                (-1.0, 0.0),
                (1.0, 0.0),
                (0.0, 1.0),
                (-1.0, 1.0),
                (1.0, 1.0),
            ]
        );
    }
}
