//! The executed ego trajectory of a closed-loop run as a CommonRoad solution file: a
//! kinematic single-track (KS) trajectory in the scenario's own coordinates.
//!
//! **Vehicle model.** CommonRoad's KS model drives the centre of the rear axle:
//! ẋ = v cos ψ, ẏ = v sin ψ, ψ̇ = v tan δ / L. nudge's ego is the kinematic bicycle at the
//! centre of gravity (speed v_cg, slip β = atan(l_r tan δ_n / (l_f + l_r))); its rear axle
//! moves exactly as KS with v = v_cg cos β and tan δ / L = tan δ_n / (l_f + l_r). CommonRoad's
//! solutions give the position of the vehicle's centre, which its checker takes to lie `b`
//! ahead of the rear axle (`b` of the vehicle type). The written state is therefore nudge's
//! rear axle moved b ahead along ψ (0.02 m ahead of nudge's centre of gravity for the default
//! l_r), ψ, v = v_cg cos β and the steering angle δ the KS vehicle needs to drive the same
//! path on its wheelbase L. The vehicle is CommonRoad's type 2
//! (BMW 320i, [`VEHICLE`]): of the three CommonRoad vehicles its wheelbase (2.58 m) and rear
//! overhang l_r (1.42 m) are closest to nudge's default l_f + l_r = 2.8 m, l_r = 1.4 m.
//!
//! **Time.** The closed loop applies each step's (δ, a) for 0.3 s; the solution integrates
//! the bicycle's continuous dynamics under these inputs (RK4, [`SUBSTEPS`] per file step) and
//! writes a state every file step (0.1 s for the US-101 scenes). The closed loop's own 0.3 s
//! Euler states differ from it by [`Solution::max_dev_m`].

use std::fmt::Write as _;
use std::path::Path;

use nudge_planner::Scenario;
use nudge_predictor::T_OBS;
use nudge_sim::RunRecord;

use super::error::CommonRoadError;
use super::goal::GoalState;
use super::scene::{CommonRoadScene, Ego};

/// A CommonRoad vehicle type's parameters (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleType {
    /// CommonRoad's vehicle type id (`KS<id>` in the benchmark id).
    pub id: u8,
    /// Length (m).
    pub length: f64,
    /// Width (m).
    pub width: f64,
    /// Centre of gravity to front axle a (m).
    pub a: f64,
    /// Centre of gravity to rear axle b (m).
    pub b: f64,
}

/// CommonRoad vehicle type 2 (BMW 320i; `vehiclemodels.parameters_vehicle2`).
pub const VEHICLE: VehicleType = VehicleType {
    id: 2,
    length: 4.508,
    width: 1.61,
    a: 1.156_195_706_4,
    b: 1.422_717_093_6,
};

/// The solution's cost function id (CommonRoad `SM1`; the checker needs one, nudge does not
/// optimise it).
pub const COST_FUNCTION: &str = "SM1";
/// RK4 sub-steps per file time step.
pub const SUBSTEPS: usize = 10;

/// One KS state in the file's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KsState {
    /// Time step index of the file.
    pub step: i64,
    /// Position (m) of the vehicle's centre as CommonRoad defines it: the rear axle plus
    /// [`VEHICLE`]`.b` along the orientation.
    pub pos: [f64; 2],
    /// Steering angle of the KS vehicle (rad).
    pub steering: f64,
    /// Rear-axle speed (m/s).
    pub velocity: f64,
    /// Orientation (rad).
    pub orientation: f64,
}

/// A solution: the benchmark id, the planning problem (or ego obstacle) id and the states.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// `KS2:SM1:<benchmarkID>:<version>`.
    pub benchmark_id: String,
    /// The planning problem's id, or the ego obstacle's.
    pub planning_problem: i64,
    /// The states, one per file time step from t0.
    pub states: Vec<KsState>,
    /// Largest distance (m) between the integrated trajectory and the closed loop's own ego
    /// states at the 0.3 s steps (0 when they were not given).
    pub max_dev_m: f64,
}

/// nudge's bicycle (centre of gravity): state (x, y, ψ, v), inputs (δ, a), axle distances.
#[derive(Debug, Clone, Copy)]
struct Bicycle {
    l_f: f64,
    l_r: f64,
}

impl Bicycle {
    fn beta(self, delta: f64) -> f64 {
        (self.l_r / (self.l_f + self.l_r) * delta.tan()).atan()
    }

    fn deriv(self, z: [f64; 4], delta: f64, accel: f64) -> [f64; 4] {
        let b = self.beta(delta);
        let v = z[3];
        let dv = if v <= 0.0 && accel < 0.0 { 0.0 } else { accel };
        [
            v * (z[2] + b).cos(),
            v * (z[2] + b).sin(),
            v * b.sin() / self.l_r,
            dv,
        ]
    }

    /// One RK4 step of `h` s; the speed is kept ≥ 0 (the vehicle stops, it does not reverse).
    fn rk4(self, z: [f64; 4], delta: f64, accel: f64, h: f64) -> [f64; 4] {
        let add = |z: [f64; 4], k: [f64; 4], s: f64| std::array::from_fn(|i| z[i] + s * k[i]);
        let k1 = self.deriv(z, delta, accel);
        let k2 = self.deriv(add(z, k1, h / 2.0), delta, accel);
        let k3 = self.deriv(add(z, k2, h / 2.0), delta, accel);
        let k4 = self.deriv(add(z, k3, h), delta, accel);
        let mut out: [f64; 4] =
            std::array::from_fn(|i| z[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]));
        out[3] = out[3].max(0.0);
        out
    }
}

impl Solution {
    /// The solution of `record` (a closed-loop run on `scenario`, built from `scene` for
    /// `ego` at `t0_s`) with the ego's axle distances `l_f`, `l_r` (m).
    ///
    /// # Errors
    /// [`CommonRoadError::Solution`] when the record has no steps or a state is non-finite.
    pub fn of_run(
        scene: &CommonRoadScene,
        (ego, t0_s): (Ego, f64),
        scenario: &Scenario,
        record: &RunRecord,
        axles: (f64, f64),
    ) -> Result<Self, CommonRoadError> {
        let inputs: Vec<[f64; 2]> = record.steps.iter().map(|s| [s.delta, s.accel]).collect();
        let executed: Vec<[f64; 2]> = record.steps.iter().map(|s| [s.ego[0], s.ego[1]]).collect();
        Self::of_inputs(
            scene,
            (ego, t0_s),
            scenario,
            (&inputs, Some(&executed)),
            axles,
        )
    }

    /// The solution of the inputs `[steps]` of (steering δ (rad), acceleration a (m/s²)), each
    /// held for 0.3 s from the ego's state in `scenario` (built from `scene` for `ego` at
    /// `t0_s`); `executed` `[steps]` (m, road frame), when given, are the closed loop's ego
    /// positions after each step ([`Solution::max_dev_m`] compares them; 0 without).
    ///
    /// # Errors
    /// [`CommonRoadError::Solution`] when there are no inputs, `executed` has another length,
    /// a state leaves the road frame's range ([`super::RoadFrame::road_range`]: the ego drove
    /// past the end of the lane map, where the file's coordinates are not defined; refused
    /// rather than extrapolated), or a state is non-finite.
    pub fn of_inputs(
        scene: &CommonRoadScene,
        (ego, t0_s): (Ego, f64),
        scenario: &Scenario,
        (inputs, executed): (&[[f64; 2]], Option<&[[f64; 2]]>),
        (l_f, l_r): (f64, f64),
    ) -> Result<Self, CommonRoadError> {
        Self::build(
            scene,
            (ego, t0_s),
            scenario,
            (inputs, executed),
            (l_f, l_r),
            None,
        )
        .map(|(sol, _)| sol)
    }

    /// [`Solution::of_run`] for a planning problem's `goals` (none: as `of_run`): the
    /// solution ends at its first state that reaches one of them ([`Solution::goal_index`]),
    /// so states past it need not lie in the road frame's range; with it, whether the goal was
    /// reached (the index of that state) or why not.
    ///
    /// # Errors
    /// As [`Solution::of_run`], for the states up to the goal.
    pub fn of_run_to_goal(
        scene: &CommonRoadScene,
        (ego, t0_s): (Ego, f64),
        scenario: &Scenario,
        record: &RunRecord,
        axles: (f64, f64),
        goals: Option<&[GoalState]>,
    ) -> Result<(Self, Option<Result<usize, String>>), CommonRoadError> {
        let inputs: Vec<[f64; 2]> = record.steps.iter().map(|s| [s.delta, s.accel]).collect();
        let executed: Vec<[f64; 2]> = record.steps.iter().map(|s| [s.ego[0], s.ego[1]]).collect();
        Self::build(
            scene,
            (ego, t0_s),
            scenario,
            (&inputs, Some(&executed)),
            axles,
            goals,
        )
    }

    fn build(
        scene: &CommonRoadScene,
        (ego, t0_s): (Ego, f64),
        scenario: &Scenario,
        (inputs, executed): (&[[f64; 2]], Option<&[[f64; 2]]>),
        (l_f, l_r): (f64, f64),
        goals: Option<&[GoalState]>,
    ) -> Result<(Self, Option<Result<usize, String>>), CommonRoadError> {
        let err = |reason: String| CommonRoadError::Solution {
            path: scene.raw.path.clone(),
            reason,
        };
        if inputs.is_empty() || executed.is_some_and(|e| e.len() != inputs.len()) {
            return Err(err(format!(
                "{} inputs and {} executed positions (at least one input, as many positions)",
                inputs.len(),
                executed.map_or(inputs.len(), <[_]>::len)
            )));
        }
        let bike = Bicycle { l_f, l_r };
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let per_step = (nudge_predictor::DT / scene.raw.dt).round() as usize;
        #[allow(clippy::cast_possible_truncation)]
        let step0 = (t0_s / scene.raw.dt).round() as i64;
        let last = &scenario.history[(T_OBS - 1) * 2..T_OBS * 2];
        let mut z = [last[0], last[1], scenario.heading[0], scenario.speed[0]];
        #[allow(clippy::cast_precision_loss)]
        let h = scene.raw.dt / SUBSTEPS as f64;
        let mut road = Vec::with_capacity(inputs.len() * per_step + 1);
        let mut max_dev: f64 = 0.0;
        for (k, &[delta, accel]) in inputs.iter().enumerate() {
            for _ in 0..per_step {
                road.push((z, delta));
                for _ in 0..SUBSTEPS {
                    z = bike.rk4(z, delta, accel, h);
                }
            }
            if let Some(e) = executed {
                max_dev = max_dev.max((z[0] - e[k][0]).hypot(z[1] - e[k][1]));
            }
        }
        road.push((z, inputs[inputs.len() - 1][0]));
        let (lo, hi) = scene.frame.road_range();
        let mut reached = None;
        for (k, (&(z, delta), step)) in road.iter().zip(step0..).enumerate() {
            let r = reference(bike, z);
            if let (Some(g), Some(_)) = (goals, scene.frame.try_to_file(r)) {
                let st = ks_state(scene, bike, z, delta, step);
                if g.iter()
                    .any(|g| g.reached_by(st.step, st.pos, st.velocity, st.orientation))
                {
                    reached = Some(k);
                    break;
                }
            }
            if scene.frame.try_to_file(r).is_none() {
                return Err(err(format!(
                    "the ego at time step {step} is at road x = {:.1} m, y = {:.1} m, outside the \
                     road frame's range [{lo:.1}, {hi:.1}] m (the lane map ends there; the file's \
                     coordinates are not defined beyond it, so no solution is written)",
                    r[0], r[1]
                )));
            }
        }
        if let Some(k) = reached {
            road.truncate(k + 1);
        }
        let states: Vec<KsState> = road
            .iter()
            .zip(step0..)
            .map(|(&(z, delta), step)| ks_state(scene, bike, z, delta, step))
            .collect();
        if let Some(bad) = states.iter().find(|s| {
            ![s.pos[0], s.pos[1], s.steering, s.velocity, s.orientation]
                .iter()
                .all(|v| v.is_finite())
        }) {
            return Err(err(format!("non-finite state at time step {}", bad.step)));
        }
        let (Ego::Obstacle(id) | Ego::PlanningProblem(id)) = ego;
        let sol = Self {
            benchmark_id: format!(
                "KS{}:{COST_FUNCTION}:{}:{}",
                VEHICLE.id, scene.raw.benchmark_id, scene.raw.version
            ),
            planning_problem: id,
            states,
            max_dev_m: max_dev,
        };
        let goal = goals.map(|g| sol.goal_index(g));
        Ok((sol, goal))
    }

    /// The index of the first state that reaches one of `goals` (as CommonRoad's checker
    /// decides, [`GoalState::reached_by`]).
    ///
    /// # Errors
    /// Why no state reaches them: for the goal state whose time window the trajectory
    /// covers, the state of that window nearest its position, how far it is and which of the
    /// goal's conditions it misses; or that the trajectory ends before the window.
    pub fn goal_index(&self, goals: &[GoalState]) -> Result<usize, String> {
        if let Some(i) = self.states.iter().position(|k| {
            goals
                .iter()
                .any(|g| g.reached_by(k.step, k.pos, k.velocity, k.orientation))
        }) {
            return Ok(i);
        }
        let mut why = Vec::new();
        for (n, g) in goals.iter().enumerate() {
            #[allow(clippy::cast_precision_loss)]
            let inside: Vec<&KsState> = self
                .states
                .iter()
                .filter(|k| g.time.contains(k.step as f64))
                .collect();
            let Some(last) = self.states.last() else {
                return Err("no states".into());
            };
            if inside.is_empty() {
                why.push(format!(
                    "goal state {}: the trajectory (time steps {}..{}) does not reach its time \
                     steps {}..{}",
                    n + 1,
                    self.states[0].step,
                    last.step,
                    g.time.lo,
                    g.time.hi
                ));
                continue;
            }
            let centre = g.shapes.first().map(|s| s.outline()[0]);
            let dist =
                |k: &KsState| centre.map_or(0.0, |c| (k.pos[0] - c[0]).hypot(k.pos[1] - c[1]));
            let near = inside
                .iter()
                .min_by(|a, b| dist(a).total_cmp(&dist(b)))
                .copied()
                .unwrap_or(inside[0]);
            let mut miss = Vec::new();
            if !(g.shapes.is_empty() || g.shapes.iter().any(|s| s.contains(near.pos))) {
                miss.push(format!(
                    "position {:.2} m from the goal's centre",
                    dist(near)
                ));
            }
            if let Some(v) = g.velocity.filter(|v| !v.contains(near.velocity)) {
                miss.push(format!(
                    "velocity {:.2} m/s outside {:.2}..{:.2}",
                    near.velocity, v.lo, v.hi
                ));
            }
            if let Some(o) = g
                .orientation
                .filter(|o| !o.contains_angle(near.orientation))
            {
                miss.push(format!(
                    "orientation {:.3} rad outside {:.3}..{:.3}",
                    near.orientation, o.lo, o.hi
                ));
            }
            why.push(format!(
                "goal state {}: nearest state of its time window (time step {}) misses: {}",
                n + 1,
                near.step,
                miss.join(", ")
            ));
        }
        Err(why.join("; "))
    }

    /// The solution as CommonRoad solution XML.
    #[must_use]
    pub fn to_xml(&self) -> String {
        let mut s = String::from("<?xml version=\"1.0\" encoding=\"utf-8\"?>\n");
        let _ = writeln!(
            s,
            "<CommonRoadSolution benchmark_id=\"{}\">",
            self.benchmark_id
        );
        let _ = writeln!(
            s,
            "  <ksTrajectory planningProblem=\"{}\">",
            self.planning_problem
        );
        for k in &self.states {
            let _ = writeln!(
                s,
                "    <ksState><x>{}</x><y>{}</y><steeringAngle>{}</steeringAngle>\
                 <velocity>{}</velocity><orientation>{}</orientation><time>{}</time></ksState>",
                k.pos[0], k.pos[1], k.steering, k.velocity, k.orientation, k.step
            );
        }
        s.push_str("  </ksTrajectory>\n</CommonRoadSolution>\n");
        s
    }

    /// Writes [`Solution::to_xml`] to `path` atomically ([`crate::files::write_file`]: a
    /// temporary file renamed into place; a symbolic link at `path` is replaced, not followed).
    ///
    /// # Errors
    /// [`CommonRoadError::Io`] naming `path`.
    pub fn write(&self, path: &Path) -> Result<(), CommonRoadError> {
        crate::files::write_file(path, self.to_xml().as_bytes()).map_err(|e| CommonRoadError::Io {
            path: path.to_path_buf(),
            source: match e {
                crate::files::FilesError::Io { source, .. } => source,
                other => std::io::Error::other(other.to_string()),
            },
        })
    }
}

/// The point (road frame, m) CommonRoad calls the vehicle's centre for the bicycle state `z`:
/// the rear axle moved [`VEHICLE`]`.b` ahead along ψ.
fn reference(bike: Bicycle, z: [f64; 4]) -> [f64; 2] {
    let (s, c) = z[2].sin_cos();
    let back = bike.l_r - VEHICLE.b;
    [z[0] - back * c, z[1] - back * s]
}

/// The KS state (file frame) of the bicycle state `z` (road frame) steering `delta`.
fn ks_state(scene: &CommonRoadScene, bike: Bicycle, z: [f64; 4], delta: f64, step: i64) -> KsState {
    let reference = reference(bike, z);
    let wheelbase = VEHICLE.a + VEHICLE.b;
    let v_rear = z[3] * bike.beta(delta).cos();
    let (steering, velocity) = match scene.frame.curvature_at(reference[0]) {
        // The curvilinear frame: the road frame's straight lines are the reference path's
        // offsets, so the file's rear axle moves at the road speed scaled by (1 − κ d) along
        // the path and turns at the road yaw rate plus κ times its progress along it.
        Some(kappa) => {
            let (sn, cs) = z[2].sin_cos();
            let along = 1.0 - kappa * reference[1];
            let v = v_rear * (along * cs).hypot(sn);
            let yaw_rate = z[3] * bike.beta(delta).sin() / bike.l_r + kappa * v_rear * cs;
            let steering = if v > 1e-9 {
                (wheelbase * yaw_rate / v).atan()
            } else {
                (wheelbase * delta.tan() / (bike.l_f + bike.l_r)).atan()
            };
            (steering, v)
        }
        None => (
            (wheelbase * delta.tan() / (bike.l_f + bike.l_r)).atan(),
            v_rear,
        ),
    };
    KsState {
        step,
        pos: scene.frame.to_file(reference),
        steering,
        velocity,
        orientation: scene.frame.heading_to_file(reference, z[2]),
    }
}
