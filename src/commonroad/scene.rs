//! A CommonRoad scene in the road frame, and the nudge scenario of one ego at one time, built
//! as the data pipeline builds its scenarios (`nudge_train.data.scenarios.scenario_at`): the
//! ego's and its neighbours' 8-step histories on the 0.3 s grid, their logged futures, and
//! the lanes at the ego's x.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nudge_planner::Scenario;
use nudge_planner::scenario::ROAD_TOLERANCE;
use nudge_predictor::{DT, MAX_AGENTS, T_OBS};
use safetensors::{Dtype, tensor::TensorView};

use super::error::CommonRoadError;
use super::frame::RoadFrame;
use super::lanes::{LaneMap, RoadLanelet, on_carriageway, sorted_by_x};
use super::xml::{RawScenario, RawState};

/// Most logged future steps (0.3 s each) a scenario keeps.
pub const MAX_FUTURE: usize = 30;
/// Most future steps (0.3 s each) a planning problem's scenario keeps: its goal's time
/// window may end later than [`MAX_FUTURE`] steps after its start, and the closed loop runs
/// until it ends (the others as logged).
pub const MAX_PLAN_FUTURE: usize = 100;
/// Fewest logged future steps of the ego (the scenario format's minimum).
pub const MIN_FUTURE: usize = 6;
/// Neighbours are the vehicles within this distance (m) of the ego at the last observed step.
pub const NEIGHBOUR_RANGE: f64 = 60.0;
/// Lanes near the ego must be straight within this (m) ...
pub const STRAIGHT_TOL: f64 = 0.6;
/// ... over the ego's x ± this (m).
pub const STRAIGHT_HALF_RANGE: f64 = 100.0;
/// Largest |curvature · offset| of a point in the curvilinear frame (the projection onto the
/// reference path stops being unique at 1), as the data pipeline's `max_offset_curvature`.
pub const MAX_OFFSET_CURVATURE: f64 = 0.5;
/// How the refusal of lanes that are not straight near the ego begins (its reason).
pub const ROAD_SHAPE: &str = "road shape: ";
/// The `split` metadata of a scenario built from a CommonRoad file.
pub const SPLIT: &str = "commonroad";

/// One vehicle's states in the road frame (step, x (m), y (m), heading (rad), speed (m/s)).
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// Obstacle id.
    pub id: i64,
    /// (length, width) (m).
    pub size: [f64; 2],
    /// States, steps strictly increasing.
    pub states: Vec<RoadState>,
}

/// One state in the road frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoadState {
    /// Time step index of the file.
    pub step: i64,
    /// Centre (x, y) (m).
    pub pos: [f64; 2],
    /// Heading relative to the road (rad).
    pub heading: f64,
    /// Speed (m/s).
    pub speed: f64,
}

impl Track {
    /// The state at `step`, if logged.
    #[must_use]
    pub fn at(&self, step: i64) -> Option<&RoadState> {
        self.states
            .binary_search_by_key(&step, |s| s.step)
            .ok()
            .map(|i| &self.states[i])
    }
}

/// Who drives the ego.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ego {
    /// A dynamic obstacle of the scene (removed from the others).
    Obstacle(i64),
    /// A planning problem: its initial state; histories before the scene's first logged step
    /// are extrapolated (see [`CommonRoadScene::scenario`]).
    PlanningProblem(i64),
}

impl std::fmt::Display for Ego {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Obstacle(id) => write!(f, "obstacle {id}"),
            Self::PlanningProblem(id) => write!(f, "planning problem {id}"),
        }
    }
}

/// The vehicle-type size (length, width) (m) of a planning problem's ego, which has none in
/// the file: CommonRoad vehicle type 3 (see [`super::solution::VEHICLE`]).
fn planning_ego_size() -> [f64; 2] {
    [
        super::solution::VEHICLE.length,
        super::solution::VEHICLE.width,
    ]
}

/// A CommonRoad scene read into the road frame.
#[derive(Debug, Clone)]
pub struct CommonRoadScene {
    /// What was read from the file (file frame).
    pub raw: RawScenario,
    /// The road frame.
    pub frame: RoadFrame,
    /// The lanes (road frame).
    pub lanes: LaneMap,
    /// Every dynamic obstacle, sorted by id (road frame).
    pub tracks: Vec<Track>,
}

impl CommonRoadScene {
    /// Reads `path` and maps it into the road frame.
    ///
    /// # Errors
    /// As [`RawScenario::read`] and [`LaneMap::build`].
    pub fn read(path: impl AsRef<Path>) -> Result<Self, CommonRoadError> {
        Self::from_raw(RawScenario::read(path)?)
    }

    /// Maps an already read scene into the road frame.
    ///
    /// # Errors
    /// As [`LaneMap::build`].
    pub fn from_raw(raw: RawScenario) -> Result<Self, CommonRoadError> {
        let frame = RoadFrame::fit(&raw.lanelets);
        Self::in_frame(raw, frame)
    }

    /// The same scene in the curvilinear (Frenet) road frame ([`RoadFrame::curvilinear`]):
    /// x = arc length along a reference path fitted to the lanelet bounds, y = the signed
    /// offset from it, so that lanes that curve are lines y = const.
    ///
    /// # Errors
    /// [`CommonRoadError::Unsupported`] naming what the frame cannot represent: a reference
    /// path turning by more than [`super::frenet::MAX_TURN_RAD`], a lanelet point or vehicle
    /// state whose foot lies beyond the path or whose offset is not small against the path's
    /// radius of curvature (|κ d| > [`MAX_OFFSET_CURVATURE`]); as [`LaneMap::build`].
    pub fn curvilinear(&self) -> Result<Self, CommonRoadError> {
        let unsupported = |reason: String| CommonRoadError::Unsupported {
            path: self.raw.path.clone(),
            reason: format!("curvilinear road frame: {reason}"),
        };
        let frame = RoadFrame::curvilinear(&self.raw.lanelets).map_err(unsupported)?;
        let points = self
            .raw
            .lanelets
            .iter()
            .flat_map(|ll| ll.left.iter().chain(&ll.right).copied())
            .chain(
                self.raw
                    .obstacles
                    .iter()
                    .flat_map(|o| o.states.iter().map(|st| [st.x, st.y])),
            )
            .chain(
                self.raw
                    .planning_problems
                    .iter()
                    .map(|pp| [pp.initial.x, pp.initial.y]),
            );
        for p in points {
            match frame.project(p) {
                None => {
                    return Err(unsupported(format!(
                        "point ({:.2}, {:.2}) m lies beyond the ends of the reference path or its \
                         projection does not converge",
                        p[0], p[1]
                    )));
                }
                Some((r, kd)) if kd > MAX_OFFSET_CURVATURE => {
                    return Err(unsupported(format!(
                        "point ({:.2}, {:.2}) m is {:.1} m off the reference path, {kd:.2} of its \
                         radius of curvature (at most {MAX_OFFSET_CURVATURE}): its projection is \
                         not unique",
                        p[0], p[1], r[1]
                    )));
                }
                Some(_) => {}
            }
        }
        Self::in_frame(self.raw.clone(), frame)
    }

    /// The scene of `ego` made ready to plan: read from `path`, t0 (`t0_s`, or
    /// [`CommonRoadScene::default_t0`]) and the scenario with its file bytes
    /// ([`CommonRoadScene::scenario_in_range`], neighbours within `range_m` m). In the
    /// straightened road frame when the lanes near the ego are straight there (every shipped
    /// scene), else in the curvilinear frame ([`CommonRoadScene::curvilinear`]); the scene
    /// returned is the one the scenario was built in (the solution writer maps back through
    /// its frame).
    ///
    /// # Errors
    /// As [`CommonRoadScene::read`], [`CommonRoadScene::default_t0`] and
    /// [`CommonRoadScene::scenario_in_range`] (in the curvilinear frame when the straightened
    /// one is refused for its road shape), [`CommonRoadScene::curvilinear`].
    pub fn prepare(
        path: impl AsRef<Path>,
        ego: Ego,
        t0_s: Option<f64>,
        range_m: f64,
    ) -> Result<(Self, f64, Scenario, Vec<u8>), CommonRoadError> {
        let scene = Self::read(path)?;
        let t0 = match t0_s {
            Some(t) => t,
            None => scene.default_t0(ego)?,
        };
        match scene.scenario_in_range(ego, t0, range_m) {
            Ok((sc, bytes)) => Ok((scene, t0, sc, bytes)),
            Err(CommonRoadError::Unsupported { reason, .. }) if reason.starts_with(ROAD_SHAPE) => {
                let curved = scene.curvilinear()?;
                let (sc, bytes) = curved.scenario_in_range(ego, t0, range_m)?;
                Ok((curved, t0, sc, bytes))
            }
            Err(e) => Err(e),
        }
    }

    fn in_frame(raw: RawScenario, frame: RoadFrame) -> Result<Self, CommonRoadError> {
        let road = |b: &[[f64; 2]]| sorted_by_x(b.iter().map(|&p| frame.to_road(p)).collect());
        let lanelets: Vec<RoadLanelet> = raw
            .lanelets
            .iter()
            .map(|ll| RoadLanelet {
                id: ll.id.clone(),
                line: ll.line,
                left: road(&ll.left),
                right: road(&ll.right),
            })
            .collect();
        let lanes = if frame.is_curvilinear() {
            LaneMap::build(&on_carriageway(&lanelets), &raw.path)?
        } else {
            LaneMap::build(&lanelets, &raw.path)?
        };
        let mut tracks: Vec<Track> = raw
            .obstacles
            .iter()
            .map(|o| Track {
                id: o.id,
                size: [o.length, o.width],
                states: o.states.iter().map(|s| road_state(&frame, s)).collect(),
            })
            .collect();
        tracks.sort_by_key(|t| t.id);
        Ok(Self {
            raw,
            frame,
            lanes,
            tracks,
        })
    }

    fn ego_err(&self, ego: Ego, reason: String) -> CommonRoadError {
        CommonRoadError::Ego {
            path: self.raw.path.clone(),
            ego: ego.to_string(),
            reason,
        }
    }

    /// File steps per 0.3 s scenario step.
    fn stride(&self) -> Result<i64, CommonRoadError> {
        let r = DT / self.raw.dt;
        if (r - r.round()).abs() > 1e-6 || r.round() < 1.0 {
            return Err(CommonRoadError::Unsupported {
                path: self.raw.path.clone(),
                reason: format!(
                    "timeStepSize {} s does not divide nudge's {DT} s step",
                    self.raw.dt
                ),
            });
        }
        #[allow(clippy::cast_possible_truncation)]
        Ok(r.round() as i64)
    }

    /// The first and last logged step of the scene.
    fn step_range(&self) -> (i64, i64) {
        let steps = self
            .tracks
            .iter()
            .flat_map(|t| t.states.iter().map(|s| s.step));
        steps.fold((i64::MAX, i64::MIN), |(l, h), s| (l.min(s), h.max(s)))
    }

    /// The ego's track: a logged obstacle, or the planning problem's initial state alone.
    fn ego_track(&self, ego: Ego) -> Result<Track, CommonRoadError> {
        match ego {
            Ego::Obstacle(id) => self
                .tracks
                .iter()
                .find(|t| t.id == id)
                .cloned()
                .ok_or_else(|| self.ego_err(ego, "no dynamic obstacle with this id".into())),
            Ego::PlanningProblem(id) => {
                let pp = self
                    .raw
                    .planning_problems
                    .iter()
                    .find(|p| p.id == id)
                    .ok_or_else(|| self.ego_err(ego, "no planning problem with this id".into()))?;
                Ok(Track {
                    id,
                    size: planning_ego_size(),
                    states: vec![road_state(&self.frame, &pp.initial)],
                })
            }
        }
    }

    /// The default last observed step for `ego`: the planning problem's initial step, or the
    /// obstacle's first step with a full 8-step history on the scene's 0.3 s grid.
    ///
    /// # Errors
    /// [`CommonRoadError::Ego`] for an unknown ego; [`CommonRoadError::Unsupported`] for a
    /// time step that does not divide 0.3 s.
    pub fn default_t0(&self, ego: Ego) -> Result<f64, CommonRoadError> {
        let track = self.ego_track(ego)?;
        let first = track.states[0].step;
        #[allow(clippy::cast_precision_loss)]
        if let Ego::PlanningProblem(_) = ego {
            return Ok(first as f64 * self.raw.dt);
        }
        let stride = self.stride()?;
        let f0 = self.step_range().0;
        let want = first + stride * (T_OBS as i64 - 1) - f0;
        let step = f0 + (want + stride - 1).div_euclid(stride) * stride;
        #[allow(clippy::cast_precision_loss)]
        Ok(step as f64 * self.raw.dt)
    }

    /// The nudge scenario of `ego` with its last observed step at `t0_s` (s of the file's
    /// clock), as the data pipeline builds one: the ego's 8 states at t0 − 2.1 s ..= t0 every
    /// 0.3 s, the vehicles within [`NEIGHBOUR_RANGE`] of it at t0 with full histories (nearest
    /// first, ties by id, at most 46), their logged futures (up to [`MAX_FUTURE`] steps, the
    /// ego's at least [`MIN_FUTURE`]) and the lanes at the ego's x. In the curvilinear frame
    /// ([`CommonRoadScene::curvilinear`]) the lanes are every lane of the road with its extent
    /// ("nudge.scenario/2") and vehicles off the carriageway are left out.
    ///
    /// For a planning problem, whose ego is not logged, every history step before a vehicle's
    /// first logged state is extrapolated back from it at constant speed and heading (the
    /// scene has no earlier data: CommonRoad tracks start at the scene's first step); the ego
    /// has no logged future, and the others' logged futures run up to [`MAX_PLAN_FUTURE`]
    /// steps (a goal's window may end later than [`MAX_FUTURE`]).
    ///
    /// # Errors
    /// [`CommonRoadError::Ego`] (unknown id, t0 not on a logged step, no full history, too
    /// short a logged future); [`CommonRoadError::Unsupported`] (lanes near the ego not
    /// straight within [`STRAIGHT_TOL`] over ±[`STRAIGHT_HALF_RANGE`], a time step that does
    /// not divide 0.3 s); [`CommonRoadError::Scenario`] when the result does not validate.
    pub fn scenario(&self, ego: Ego, t0_s: f64) -> Result<Scenario, CommonRoadError> {
        self.scenario_in_range(ego, t0_s, NEIGHBOUR_RANGE)
            .map(|(sc, _)| sc)
    }

    /// [`CommonRoadScene::scenario`] with neighbours within `range_m` (m) instead of
    /// [`NEIGHBOUR_RANGE`], and the bytes of its "nudge.scenario/1" file.
    ///
    /// # Errors
    /// As [`CommonRoadScene::scenario`].
    pub fn scenario_in_range(
        &self,
        ego: Ego,
        t0_s: f64,
        range_m: f64,
    ) -> Result<(Scenario, Vec<u8>), CommonRoadError> {
        let stride = self.stride()?;
        let ego_track = self.ego_track(ego)?;
        let plan = matches!(ego, Ego::PlanningProblem(_));
        let step = (t0_s / self.raw.dt).round();
        let (first, last) = self.step_range();
        #[allow(clippy::cast_precision_loss)]
        let inside = step >= first as f64 && step <= last as f64;
        if !inside || (step * self.raw.dt - t0_s).abs() > 1e-6 {
            return Err(self.ego_err(ego, format!("t0 {t0_s} s is not a time step of the scene")));
        }
        if !(range_m.is_finite() && range_m >= 0.0) {
            let why = format!("neighbour range {range_m} m is not a finite distance ≥ 0");
            return Err(self.ego_err(ego, why));
        }
        #[allow(clippy::cast_possible_truncation)]
        let step = step as i64;
        let hist: Vec<i64> = (0..T_OBS as i64).rev().map(|k| step - stride * k).collect();
        let ego_hist = history(&ego_track, &hist, plan, self.raw.dt).ok_or_else(|| {
            self.ego_err(
                ego,
                format!("no full {T_OBS}-step history ending at t0 {t0_s} s"),
            )
        })?;
        let max_future = if plan { MAX_PLAN_FUTURE } else { MAX_FUTURE };
        let fut: Vec<i64> = (1..=max_future as i64)
            .map(|k| step + stride * k)
            .take_while(|&s| s <= last)
            .collect();
        let n_fut = if plan {
            fut.len()
        } else {
            fut.iter()
                .take_while(|&&s| ego_track.at(s).is_some())
                .count()
        };
        if n_fut < MIN_FUTURE {
            let why = format!(
                "{n_fut} logged future steps after t0 {t0_s} s (at least {MIN_FUTURE} needed)"
            );
            return Err(self.ego_err(ego, why));
        }
        let ego_xy = ego_hist[T_OBS - 1].pos;
        let dev = self.lanes.local_deviation(ego_xy[0], STRAIGHT_HALF_RANGE);
        if dev > STRAIGHT_TOL {
            return Err(CommonRoadError::Unsupported {
                path: self.raw.path.clone(),
                reason: format!(
                    "{ROAD_SHAPE}the lanes near {ego} (road x {:.1} m) deviate {dev:.2} m from \
                     straight lines over ±{STRAIGHT_HALF_RANGE} m in the {} road frame (nudge \
                     plans on lanes y = const: at most {STRAIGHT_TOL} m)",
                    ego_xy[0],
                    if self.frame.is_curvilinear() {
                        "curvilinear"
                    } else {
                        "straightened"
                    }
                ),
            });
        }
        let mut agents = vec![(ego_track, ego_hist)];
        agents.extend(self.neighbours(ego, &hist, (ego_xy, range_m), plan));
        let tensors = self.tensors(&agents, &fut[..n_fut], plan);
        let bytes = serialize(&tensors, self.metadata(ego, (t0_s, range_m), dev));
        let name = format!(
            "{}-t{t0_s:04.1}-{}.safetensors",
            self.raw.benchmark_id,
            ego_tag(ego)
        );
        let sc = Scenario::from_bytes(&bytes, Path::new(&name)).map_err(|source| {
            CommonRoadError::Scenario {
                path: self.raw.path.clone(),
                source,
            }
        })?;
        Ok((sc, bytes))
    }

    /// The other vehicles with full histories within `range_m` (m) of the ego at t0,
    /// nearest first (ties by id), at most `MAX_AGENTS − 1`; in the curvilinear frame only
    /// those whose history stays within the scenario's road tolerance of the lanes at the
    /// ego's x (not on a ramp before it joins).
    fn neighbours(
        &self,
        ego: Ego,
        hist: &[i64],
        (ego_xy, range_m): ([f64; 2], f64),
        plan: bool,
    ) -> Vec<(Track, Vec<RoadState>)> {
        let mut cand: Vec<(f64, &Track, Vec<RoadState>)> = self
            .tracks
            .iter()
            .filter(|t| ego != Ego::Obstacle(t.id))
            .filter_map(|t| {
                let h = history(t, hist, plan, self.raw.dt)?;
                let p = h[T_OBS - 1].pos;
                let d = (p[0] - ego_xy[0]).hypot(p[1] - ego_xy[1]);
                (d <= range_m).then_some((d, t, h))
            })
            .collect();
        if self.frame.is_curvilinear() {
            // Vehicles off the carriageway at the ego's x (on a ramp before it joins) are not
            // part of the scene's road.
            let b = self.lanes.bounds_at(ego_xy[0]);
            let (lo, hi) = (b[0] - ROAD_TOLERANCE, b[b.len() - 1] + ROAD_TOLERANCE);
            cand.retain(|(_, _, h)| h.iter().all(|s| (lo..=hi).contains(&s.pos[1])));
        }
        cand.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.id.cmp(&b.1.id)));
        cand.into_iter()
            .take(MAX_AGENTS - 1)
            .map(|(_, t, h)| (t.clone(), h))
            .collect()
    }

    fn metadata(&self, ego: Ego, (t0_s, range_m): (f64, f64), dev: f64) -> HashMap<String, String> {
        let source = self
            .raw
            .path
            .file_name()
            .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
        let provenance = format!(
            "CommonRoad {} scenario {source}; road frame straightened along the fitted lane \
             geometry (nudge::commonroad, as nudge_train.data); ego {ego}, neighbours within \
             {range_m} m with full {T_OBS}-step history; lanes straight within {dev:.2} m \
             over +-{STRAIGHT_HALF_RANGE} m",
            self.raw.version
        );
        [
            (
                "schema",
                if self.frame.is_curvilinear() {
                    nudge_planner::SCHEMA_EXTENTS
                } else {
                    nudge_planner::SCHEMA
                }
                .to_string(),
            ),
            ("source", source),
            ("scene", self.raw.benchmark_id.clone()),
            ("split", SPLIT.to_string()),
            ("t0_s", format!("{t0_s:.1}")),
            ("dt", DT.to_string()),
            ("provenance", provenance),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }

    /// The scenario's tensors (name, dtype, shape, little-endian bytes).
    fn tensors(&self, agents: &[(Track, Vec<RoadState>)], fut: &[i64], plan: bool) -> Vec<Tensor> {
        let n = agents.len();
        let f = fut.len();
        let mut history = Vec::with_capacity(n * T_OBS * 2);
        let mut future = vec![0.0; n * f * 2];
        let mut valid = vec![0u8; n * f];
        for (a, (track, h)) in agents.iter().enumerate() {
            history.extend(h.iter().flat_map(|s| s.pos));
            let logged = !(plan && a == 0);
            for (k, &s) in fut.iter().enumerate() {
                if let Some(st) = track.at(s).filter(|_| logged) {
                    future[(a * f + k) * 2..(a * f + k) * 2 + 2].copy_from_slice(&st.pos);
                    valid[a * f + k] = 1;
                }
            }
        }
        let ego_xy = agents[0].1[T_OBS - 1].pos;
        let spans = self
            .frame
            .is_curvilinear()
            .then(|| self.lanes.lanes_with_extents(ego_xy[0]));
        let bounds = match &spans {
            // Lanes y = const: every lane the road has ahead and behind, each with its
            // extent; neighbours share the midpoint of their bounds.
            Some(sp) => {
                let mut b = vec![sp[0].right];
                b.extend(sp.windows(2).map(|w| 0.5 * (w[0].left + w[1].right)));
                b.push(sp[sp.len() - 1].left);
                b
            }
            None => self.lanes.bounds_at(ego_xy[0]).to_vec(),
        };
        let centres: Vec<f64> = bounds.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
        let lane = bounds
            .partition_point(|&b| b <= ego_xy[1])
            .saturating_sub(1)
            .min(centres.len() - 1);
        let now = |g: fn(&RoadState) -> f64| {
            agents
                .iter()
                .map(|(_, h)| g(&h[T_OBS - 1]))
                .collect::<Vec<_>>()
        };
        let mut out = vec![
            Tensor::f64s("history", vec![n, T_OBS, 2], &history),
            Tensor::f64s("heading", vec![n], &now(|s| s.heading)),
            Tensor::f64s("speed", vec![n], &now(|s| s.speed)),
            Tensor::f64s(
                "size",
                vec![n, 2],
                &agents.iter().flat_map(|(t, _)| t.size).collect::<Vec<_>>(),
            ),
            Tensor::f64s("future", vec![n, f, 2], &future),
            Tensor::bytes("future_valid", Dtype::U8, vec![n, f], valid),
            Tensor::f64s("lane_centres", vec![centres.len()], &centres),
            Tensor::f64s("lane_bounds", vec![bounds.len()], &bounds),
            Tensor::i64s("ego_lane", vec![1], &[i64::try_from(lane).unwrap_or(0)]),
            Tensor::i64s(
                "agent_ids",
                vec![n],
                &agents.iter().map(|(t, _)| t.id).collect::<Vec<_>>(),
            ),
        ];
        if let Some(sp) = spans {
            let ext: Vec<f64> = sp.iter().flat_map(|l| [l.begin, l.end]).collect();
            let real: Vec<u8> = sp
                .iter()
                .flat_map(|l| [u8::from(l.begins), u8::from(l.ends)])
                .collect();
            out.push(Tensor::f64s("lane_extent", vec![sp.len(), 2], &ext));
            out.push(Tensor::bytes(
                "lane_extent_real",
                Dtype::U8,
                vec![sp.len(), 2],
                real,
            ));
        }
        out
    }
}

/// `ego<id>` or `pp<id>`, for scenario names.
fn ego_tag(ego: Ego) -> String {
    match ego {
        Ego::Obstacle(id) => format!("ego{id}"),
        Ego::PlanningProblem(id) => format!("pp{id}"),
    }
}

/// A file state mapped into the road frame.
fn road_state(frame: &RoadFrame, s: &RawState) -> RoadState {
    let p = [s.x, s.y];
    RoadState {
        step: s.step,
        pos: frame.to_road(p),
        heading: frame.heading_to_road(p, s.orientation),
        speed: s.velocity,
    }
}

/// The states of `track` at the `steps` (ascending), or `None` when one is missing; with
/// `extrapolate`, steps before the first logged state are extrapolated back from it at
/// constant speed and heading (`dt` s per file step).
fn history(track: &Track, steps: &[i64], extrapolate: bool, dt: f64) -> Option<Vec<RoadState>> {
    let first = track.states[0];
    steps
        .iter()
        .map(|&s| match track.at(s) {
            Some(st) => Some(*st),
            None if extrapolate && s < first.step => {
                #[allow(clippy::cast_precision_loss)]
                let back = (first.step - s) as f64 * dt * first.speed;
                let (sn, cs) = first.heading.sin_cos();
                Some(RoadState {
                    step: s,
                    pos: [first.pos[0] - back * cs, first.pos[1] - back * sn],
                    ..first
                })
            }
            None => None,
        })
        .collect()
}

/// One tensor to serialise: name, dtype, shape, little-endian bytes.
struct Tensor {
    name: &'static str,
    dtype: Dtype,
    shape: Vec<usize>,
    data: Vec<u8>,
}

impl Tensor {
    fn f64s(name: &'static str, shape: Vec<usize>, v: &[f64]) -> Self {
        Self::bytes(
            name,
            Dtype::F64,
            shape,
            v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        )
    }

    fn i64s(name: &'static str, shape: Vec<usize>, v: &[i64]) -> Self {
        Self::bytes(
            name,
            Dtype::I64,
            shape,
            v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        )
    }

    fn bytes(name: &'static str, dtype: Dtype, shape: Vec<usize>, data: Vec<u8>) -> Self {
        Self {
            name,
            dtype,
            shape,
            data,
        }
    }
}

/// The safetensors image of `tensors` with `metadata` (shapes and byte lengths agree by
/// construction).
fn serialize(tensors: &[Tensor], metadata: HashMap<String, String>) -> Vec<u8> {
    let views = tensors.iter().filter_map(|t| {
        TensorView::new(t.dtype, t.shape.clone(), &t.data)
            .ok()
            .map(|v| (t.name, v))
    });
    safetensors::serialize(views, Some(metadata)).unwrap_or_default()
}

/// The scenario file of `sc` would be written at `dir/<name>.safetensors`.
#[must_use]
pub fn scenario_path(dir: &Path, sc: &Scenario) -> PathBuf {
    dir.join(format!("{}.safetensors", sc.name))
}
