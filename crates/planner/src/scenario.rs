//! Reader of "nudge.scenario/1" and "nudge.scenario/2" scenario files (one real scene per
//! `.safetensors` file). Version 2 adds where each lane begins and ends along x
//! ([`Scenario::lane_extents`]); version 1 files have none (their lanes run through the scene).
//!
//! Besides the format (schema, tensors, dtypes, shapes, finite values), the reader checks that
//! a scene is physically plausible for a highway, naming the agent and field that is not. The
//! ranges, with the distribution over every scene nudge has (7,590: the train, val and test
//! splits of `data/processed/scenes` and `assets/scenes`):
//!
//! | quantity | real scenes (min / median / max) | accepted |
//! |---|---|---|
//! | lateral position vs the road edges, every agent and observed step | 2.7 m inside / 1.2 m inside / 0.91 m outside | at most [`ROAD_TOLERANCE`] = 2 m outside |
//! | ego's y vs its `ego_lane` boundaries | always inside | at most [`EGO_LANE_TOLERANCE`] = 0.5 m outside |
//! | \|heading\| | 0.0015 / 0.055 / 0.39 rad | ≤ [`MAX_HEADING`] = π/4 |
//! | speed | 10.6 / 18.4 / 29.1 m/s | 0 ..= [`MAX_SPEED`] = 60 m/s |
//! | history displacement per 0.3 s step | max 8.9 m | ≤ [`MAX_SPEED`] × 0.3 s = 18 m |
//! | lane width | 3.19 / 3.80 / 3.86 m | [`LANE_WIDTH`] = 2.5 ..= 6 m |
//! | lanes | 5 / 6 / 6 | 1 ..= [`MAX_LANES`] = 12 |
//! | vehicle length, width | 2.7–19.8 m, 1.19–2.59 m | [`VEHICLE_LENGTH`] = 1 ..= 30 m, [`VEHICLE_WIDTH`] = 0.5 ..= 4 m |
//! | coordinates (history, valid future, lanes) | \|x\| ≤ 262 m, \|y\| ≤ 19.3 m | ≤ [`MAX_ABS_POSITION`] = 1e6 m |
//! | distance between agents, last observed step | max 120 m | ≤ [`MAX_AGENT_OFFSET`] = 1,000 m |
//!
//! The last two are the predictor's accepted input ranges ([`nudge_predictor::limits`]).
//! Logged futures are checked for finite, in-range coordinates only (the log-replay world
//! replays them). Files are read only when regular and at most [`MAX_SCENARIO_BYTES`].

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nudge_predictor::limits::{MAX_ABS_POSITION, MAX_AGENT_OFFSET};
use nudge_predictor::{MAX_AGENTS, PredictorError, T_OBS};
use safetensors::{Dtype, SafeTensors};

use crate::error::ScenarioError;
use crate::safety::OrientedBox;

/// The schema string of scenario files without lane extents (lanes run through the scene).
pub const SCHEMA: &str = "nudge.scenario/1";
/// The schema string of scenario files with lane extents (`lane_extent`, `lane_extent_real`).
pub const SCHEMA_EXTENTS: &str = "nudge.scenario/2";
/// How far (m) along x the ego's centre may lie outside the extent of its `ego_lane`.
pub const EGO_EXTENT_TOLERANCE: f64 = 0.5;

pub use crate::extents::LaneExtent;

/// Largest scenario file accepted (bytes): 16 MiB; real scenes are 3–10 kB.
pub const MAX_SCENARIO_BYTES: u64 = 16 << 20;
/// How far (m) a vehicle centre may lie outside the road edges (shoulders, edge lines).
pub const ROAD_TOLERANCE: f64 = 2.0;
/// How far (m) the ego's centre may lie outside the boundaries of its `ego_lane`.
pub const EGO_LANE_TOLERANCE: f64 = 0.5;
/// Largest |heading| (rad) relative to the road's direction of travel: π/4.
pub const MAX_HEADING: f64 = std::f64::consts::FRAC_PI_4;
/// Largest speed (m/s), 216 km/h; also bounds the history displacement per step.
pub const MAX_SPEED: f64 = 60.0;
/// Plausible lane widths (m).
pub const LANE_WIDTH: [f64; 2] = [2.5, 6.0];
/// Most lanes one road may have.
pub const MAX_LANES: usize = 12;
/// Plausible vehicle lengths (m).
pub const VEHICLE_LENGTH: [f64; 2] = [1.0, 30.0];
/// Plausible vehicle widths (m).
pub const VEHICLE_WIDTH: [f64; 2] = [0.5, 4.0];

/// One real scene: the ego (agent 0) and its neighbours, their 8-step history, sizes, logged
/// futures and the lane layout, in the road frame (x along travel, y lateral positive left,
/// metres; one step = 0.3 s).
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// Short name (file stem).
    pub name: String,
    /// Number of agents n (ego included, 1..=47).
    pub n_agents: usize,
    /// Observed positions `[n, 8, 2]` (m), oldest first.
    pub history: Vec<f64>,
    /// Heading at the last observed step `[n]` (rad).
    pub heading: Vec<f64>,
    /// Speed at the last observed step `[n]` (m/s).
    pub speed: Vec<f64>,
    /// (length, width) `[n]` (m).
    pub size: Vec<[f64; 2]>,
    /// Logged future steps F (≥ 6).
    pub n_future: usize,
    /// Logged future positions `[n, F, 2]` (m), steps 1..=F.
    pub future: Vec<f64>,
    /// Whether each future position is real data `[n, F]`.
    pub future_valid: Vec<bool>,
    /// Lane-centre y, ascending `[L]` (m).
    pub lane_centres: Vec<f64>,
    /// Lane-boundary y, ascending `[L + 1]` (m); first and last are the road edges.
    pub lane_bounds: Vec<f64>,
    /// Index of the ego's lane in `lane_centres`.
    pub ego_lane: usize,
    /// Source vehicle ids `[n]`.
    pub agent_ids: Vec<i64>,
    /// Extent of each lane `[L]`, in `lane_centres` order ("nudge.scenario/2"); `None` for
    /// "nudge.scenario/1" files, whose lanes run through the whole scene.
    pub lane_extents: Option<Vec<LaneExtent>>,
    /// String metadata (source, scene, split, t0_s, dt, provenance, ...).
    pub metadata: HashMap<String, String>,
}

struct Reader<'a> {
    path: &'a Path,
    st: SafeTensors<'a>,
}

impl Reader<'_> {
    fn view(
        &self,
        tensor: &'static str,
        dtype: Dtype,
        expected: &[Option<usize>],
    ) -> Result<(Vec<usize>, &[u8]), ScenarioError> {
        let v = self
            .st
            .tensor(tensor)
            .map_err(|_| ScenarioError::MissingTensor {
                path: self.path.to_path_buf(),
                tensor,
            })?;
        if v.dtype() != dtype {
            return Err(ScenarioError::WrongDtype {
                path: self.path.to_path_buf(),
                tensor,
                expected: if dtype == Dtype::F64 {
                    "F64"
                } else if dtype == Dtype::U8 {
                    "U8"
                } else {
                    "I64"
                },
                got: format!("{:?}", v.dtype()),
            });
        }
        let shape = v.shape().to_vec();
        let ok = shape.len() == expected.len()
            && shape
                .iter()
                .zip(expected)
                .all(|(s, e)| e.is_none_or(|e| *s == e));
        if !ok {
            let exp: Vec<String> = expected
                .iter()
                .map(|e| e.map_or_else(|| "?".to_string(), |e| e.to_string()))
                .collect();
            return Err(ScenarioError::WrongShape {
                path: self.path.to_path_buf(),
                tensor,
                expected: format!("[{}]", exp.join(", ")),
                got: shape,
            });
        }
        Ok((shape, v.data()))
    }

    fn f64s(
        &self,
        tensor: &'static str,
        expected: &[Option<usize>],
    ) -> Result<(Vec<usize>, Vec<f64>), ScenarioError> {
        let (shape, data) = self.view(tensor, Dtype::F64, expected)?;
        let vals: Vec<f64> = data
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
            .collect();
        if let Some((index, &value)) = vals.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(ScenarioError::NonFinite {
                path: self.path.to_path_buf(),
                tensor,
                index,
                value,
            });
        }
        Ok((shape, vals))
    }

    fn i64s(
        &self,
        tensor: &'static str,
        expected: &[Option<usize>],
    ) -> Result<Vec<i64>, ScenarioError> {
        let (_, data) = self.view(tensor, Dtype::I64, expected)?;
        Ok(data
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
            .collect())
    }

    fn bad(&self, tensor: &'static str, reason: String) -> ScenarioError {
        ScenarioError::BadValue {
            path: self.path.to_path_buf(),
            tensor,
            reason,
        }
    }
}

fn ascending(v: &[f64]) -> bool {
    v.windows(2).all(|w| w[0] < w[1])
}

/// The agents' tensors of a scenario file (n agents).
struct Agents {
    /// Number of agents n (1..=[`MAX_AGENTS`]).
    n: usize,
    /// Observed positions `[n, 8, 2]` (m).
    history: Vec<f64>,
    /// Heading `[n]` (rad).
    heading: Vec<f64>,
    /// Speed `[n]` (m/s), ≥ 0.
    speed: Vec<f64>,
    /// (length, width) `[n]` (m), > 0.
    size: Vec<[f64; 2]>,
}

/// The logged futures of a scenario file.
struct LoggedFuture {
    /// Logged future steps F (≥ 6).
    n_future: usize,
    /// Positions `[n, F, 2]` (m).
    future: Vec<f64>,
    /// Whether each position is real data `[n, F]`.
    future_valid: Vec<bool>,
}

/// The lane layout of a scenario file (L lanes).
struct Lanes {
    /// Lane-centre y, strictly ascending `[L]` (m).
    centres: Vec<f64>,
    /// Lane-boundary y, strictly ascending, around the centres `[L + 1]` (m).
    bounds: Vec<f64>,
    /// Index of the ego's lane in `centres`.
    ego_lane: usize,
}

impl Reader<'_> {
    /// `history` `[n, 8, 2]` (1 ≤ n ≤ [`MAX_AGENTS`]), `heading` `[n]`, `speed` `[n]` (≥ 0)
    /// and `size` `[n, 2]` (> 0), in this order.
    fn agents(&self) -> Result<Agents, ScenarioError> {
        let (hshape, history) = self.f64s("history", &[None, Some(T_OBS), Some(2)])?;
        let n = hshape[0];
        if n == 0 || n > MAX_AGENTS {
            return Err(self.bad("history", format!("{n} agents; supported 1..={MAX_AGENTS}")));
        }
        let (_, heading) = self.f64s("heading", &[Some(n)])?;
        let (_, speed) = self.f64s("speed", &[Some(n)])?;
        if let Some(i) = speed.iter().position(|&v| v < 0.0) {
            return Err(self.bad(
                "speed",
                format!("agent {i} has negative speed {}", speed[i]),
            ));
        }
        let (_, size_flat) = self.f64s("size", &[Some(n), Some(2)])?;
        if let Some(i) = size_flat.iter().position(|&v| v <= 0.0) {
            return Err(self.bad(
                "size",
                format!(
                    "agent {} has a non-positive dimension {}",
                    i / 2,
                    size_flat[i]
                ),
            ));
        }
        let size: Vec<[f64; 2]> = size_flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        Ok(Agents {
            n,
            history,
            heading,
            speed,
            size,
        })
    }

    /// `future` `[n, F, 2]` (F ≥ 6) and `future_valid` `[n, F]`.
    fn future(&self, n: usize) -> Result<LoggedFuture, ScenarioError> {
        let (fshape, future) = self.f64s("future", &[Some(n), None, Some(2)])?;
        let nf = fshape[1];
        if nf < 6 {
            return Err(self.bad("future", format!("{nf} future steps; at least 6 required")));
        }
        let (_, fv) = self.view("future_valid", Dtype::U8, &[Some(n), Some(nf)])?;
        let future_valid: Vec<bool> = fv.iter().map(|&b| b != 0).collect();
        Ok(LoggedFuture {
            n_future: nf,
            future,
            future_valid,
        })
    }

    /// `lane_centres` `[L]` and `lane_bounds` `[L + 1]`, both strictly ascending with every
    /// centre inside its bounds, and `ego_lane` `[1]` in 0..L.
    fn lanes(&self) -> Result<Lanes, ScenarioError> {
        let (lshape, lane_centres) = self.f64s("lane_centres", &[None])?;
        let nl = lshape[0];
        if nl == 0 || !ascending(&lane_centres) {
            return Err(self.bad(
                "lane_centres",
                format!("{lane_centres:?} is empty or not strictly ascending"),
            ));
        }
        let (_, lane_bounds) = self.f64s("lane_bounds", &[Some(nl + 1)])?;
        if !ascending(&lane_bounds) {
            return Err(self.bad(
                "lane_bounds",
                format!("{lane_bounds:?} is not strictly ascending"),
            ));
        }
        for (i, c) in lane_centres.iter().enumerate() {
            if !(lane_bounds[i] < *c && *c < lane_bounds[i + 1]) {
                return Err(self.bad(
                    "lane_centres",
                    format!("centre {i} ({c}) lies outside its bounds"),
                ));
            }
        }
        let ego_lane = self.i64s("ego_lane", &[Some(1)])?[0];
        if ego_lane < 0 || ego_lane as usize >= nl {
            return Err(self.bad(
                "ego_lane",
                format!("{ego_lane} is not a lane index in 0..{nl}"),
            ));
        }
        Ok(Lanes {
            centres: lane_centres,
            bounds: lane_bounds,
            ego_lane: ego_lane as usize,
        })
    }

    /// `lane_extent` `[L, 2]` (begin < end, m) and `lane_extent_real` `[L, 2]` (0 or 1).
    fn lane_extents(&self, nl: usize) -> Result<Vec<LaneExtent>, ScenarioError> {
        let (_, ext) = self.f64s("lane_extent", &[Some(nl), Some(2)])?;
        let (_, real) = self.view("lane_extent_real", Dtype::U8, &[Some(nl), Some(2)])?;
        if let Some(i) = real.iter().position(|&b| b > 1) {
            return Err(self.bad(
                "lane_extent_real",
                format!("lane {} has flag {} (0 or 1 expected)", i / 2, real[i]),
            ));
        }
        let mut out = Vec::with_capacity(nl);
        for k in 0..nl {
            let (begin, end) = (ext[2 * k], ext[2 * k + 1]);
            if begin.abs().max(end.abs()) > MAX_ABS_POSITION {
                return Err(self.bad(
                    "lane_extent",
                    format!("lane {k} extent [{begin}, {end}] m is beyond ±{MAX_ABS_POSITION} m"),
                ));
            }
            if begin >= end {
                return Err(self.bad(
                    "lane_extent",
                    format!("lane {k} begins at {begin} m, not before its end {end} m"),
                ));
            }
            out.push(LaneExtent {
                begin,
                end,
                begins: real[2 * k] == 1,
                ends: real[2 * k + 1] == 1,
            });
        }
        Ok(out)
    }
}

/// Parses the safetensors image `bytes` and checks its string metadata: `schema` is
/// [`SCHEMA`] or [`SCHEMA_EXTENTS`] and `dt`, when present, is 0.3 (s).
///
/// # Errors
/// [`ScenarioError::NotSafetensors`], [`ScenarioError::WrongSchema`],
/// [`ScenarioError::BadMetadata`].
fn read_header<'a>(
    bytes: &'a [u8],
    path: &Path,
) -> Result<(SafeTensors<'a>, HashMap<String, String>), ScenarioError> {
    let p = || path.to_path_buf();
    let st = SafeTensors::deserialize(bytes).map_err(|e| ScenarioError::NotSafetensors {
        path: p(),
        reason: e.to_string(),
    })?;
    let (_, meta) =
        SafeTensors::read_metadata(bytes).map_err(|e| ScenarioError::NotSafetensors {
            path: p(),
            reason: e.to_string(),
        })?;
    let metadata: HashMap<String, String> = meta.metadata().clone().unwrap_or_default();
    let schema = metadata.get("schema").cloned();
    if !matches!(schema.as_deref(), Some(SCHEMA | SCHEMA_EXTENTS)) {
        return Err(ScenarioError::WrongSchema {
            path: p(),
            found: schema,
        });
    }
    if let Some(dt) = metadata.get("dt") {
        let ok = dt
            .trim()
            .parse::<f64>()
            .is_ok_and(|d| (d - 0.3).abs() < 1e-9);
        if !ok {
            return Err(ScenarioError::BadMetadata {
                path: p(),
                key: "dt",
                reason: format!("{dt:?} is not 0.3"),
            });
        }
    }
    Ok((st, metadata))
}

/// [`ScenarioError::BadValue`] naming the file and `tensor`.
fn bad_value(path: &Path, tensor: &'static str, reason: String) -> ScenarioError {
    ScenarioError::BadValue {
        path: path.to_path_buf(),
        tensor,
        reason,
    }
}

impl Scenario {
    /// The scenario file image of this scene: "nudge.scenario/2" when it has lane extents,
    /// else "nudge.scenario/1", with its metadata (`schema` and `dt` = 0.3 set) and every
    /// tensor [`Scenario::from_bytes`] reads. Nothing is validated here: reading the image back
    /// ([`Scenario::from_bytes`]) applies the file reader's checks, so a scene built in memory
    /// (Python's `Scenario.from_arrays`) passes exactly the checks of a file.
    ///
    /// # Errors
    /// [`ScenarioError::BadValue`] naming the tensor whose length does not match its shape
    /// (`history` not `n_agents` × 8 × 2 values, ...).
    pub fn to_bytes(&self) -> Result<Vec<u8>, ScenarioError> {
        use safetensors::tensor::TensorView;
        let here = Path::new(&self.name);
        let n = self.n_agents;
        let nl = self.lane_centres.len();
        let f64s = |v: &[f64]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let size: Vec<f64> = self.size.iter().flatten().copied().collect();
        let mut tensors: Vec<(&'static str, Dtype, Vec<usize>, Vec<u8>)> = vec![
            (
                "history",
                Dtype::F64,
                vec![n, T_OBS, 2],
                f64s(&self.history),
            ),
            ("heading", Dtype::F64, vec![n], f64s(&self.heading)),
            ("speed", Dtype::F64, vec![n], f64s(&self.speed)),
            ("size", Dtype::F64, vec![n, 2], f64s(&size)),
            (
                "future",
                Dtype::F64,
                vec![n, self.n_future, 2],
                f64s(&self.future),
            ),
            (
                "future_valid",
                Dtype::U8,
                vec![n, self.n_future],
                self.future_valid.iter().map(|&b| u8::from(b)).collect(),
            ),
            (
                "lane_centres",
                Dtype::F64,
                vec![nl],
                f64s(&self.lane_centres),
            ),
            (
                "lane_bounds",
                Dtype::F64,
                vec![self.lane_bounds.len()],
                f64s(&self.lane_bounds),
            ),
            (
                "ego_lane",
                Dtype::I64,
                vec![1],
                i64::try_from(self.ego_lane)
                    .unwrap_or(i64::MAX)
                    .to_le_bytes()
                    .to_vec(),
            ),
            (
                "agent_ids",
                Dtype::I64,
                vec![self.agent_ids.len()],
                self.agent_ids
                    .iter()
                    .flat_map(|x| x.to_le_bytes())
                    .collect(),
            ),
        ];
        let mut metadata = self.metadata.clone();
        metadata.insert("dt".into(), "0.3".into());
        match &self.lane_extents {
            Some(ext) => {
                let flat: Vec<f64> = ext.iter().flat_map(|e| [e.begin, e.end]).collect();
                let real: Vec<u8> = ext
                    .iter()
                    .flat_map(|e| [u8::from(e.begins), u8::from(e.ends)])
                    .collect();
                tensors.push(("lane_extent", Dtype::F64, vec![ext.len(), 2], f64s(&flat)));
                tensors.push(("lane_extent_real", Dtype::U8, vec![ext.len(), 2], real));
                metadata.insert("schema".into(), SCHEMA_EXTENTS.into());
            }
            None => {
                metadata.insert("schema".into(), SCHEMA.into());
            }
        }
        let mut views = Vec::with_capacity(tensors.len());
        for (name, dtype, shape, data) in &tensors {
            let view = TensorView::new(*dtype, shape.clone(), data).map_err(|e| {
                bad_value(here, name, format!("does not fit its shape {shape:?}: {e}"))
            })?;
            views.push((*name, view));
        }
        safetensors::serialize(views, Some(metadata)).map_err(|e| ScenarioError::NotSafetensors {
            path: here.to_path_buf(),
            reason: e.to_string(),
        })
    }

    /// Reads and validates a scenario file.
    ///
    /// # Errors
    /// [`ScenarioError::Io`] when the file cannot be read,
    /// [`ScenarioError::NotRegularFile`] / [`ScenarioError::FileTooLarge`] (checked before
    /// reading, so a FIFO or `/dev/zero` is never read), otherwise as
    /// [`Scenario::from_bytes`].
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, ScenarioError> {
        let path = path.as_ref();
        let bytes =
            nudge_predictor::file::read_bounded(path, MAX_SCENARIO_BYTES).map_err(|e| match e {
                PredictorError::NotRegularFile { path, kind } => {
                    ScenarioError::NotRegularFile { path, kind }
                }
                PredictorError::FileTooLarge { path, size, max } => {
                    ScenarioError::FileTooLarge { path, size, max }
                }
                PredictorError::Io { path, source } => ScenarioError::Io { path, source },
                other => ScenarioError::Io {
                    path: path.to_path_buf(),
                    source: std::io::Error::other(other.to_string()),
                },
            })?;
        Self::from_bytes(&bytes, path)
    }

    /// Parses and validates the bytes of a scenario file; `path` names it in errors and gives
    /// [`Scenario::name`] (its stem).
    ///
    /// # Errors
    /// [`ScenarioError::NotSafetensors`], [`ScenarioError::WrongSchema`],
    /// [`ScenarioError::BadMetadata`], [`ScenarioError::MissingTensor`],
    /// [`ScenarioError::WrongDtype`], [`ScenarioError::WrongShape`],
    /// [`ScenarioError::NonFinite`], [`ScenarioError::BadValue`] (sizes ≤ 0, negative speed,
    /// unordered lanes, ego lane out of range, fewer than 6 future steps, lane count or width
    /// out of range, coordinates beyond ±1e6 m), [`ScenarioError::Implausible`] (an agent
    /// off the road, with an absurd heading, speed, size or history motion, or too far from
    /// another agent; see the module documentation for every range),
    /// [`ScenarioError::EgoLane`] (`ego_lane` is not the ego's lane),
    /// [`ScenarioError::EgoOverlap`] (the ego's box overlaps another vehicle's now).
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, ScenarioError> {
        let (st, metadata) = read_header(bytes, path)?;
        let r = Reader { path, st };
        let agents = r.agents()?;
        let n = agents.n;
        let future = r.future(n)?;
        let lanes = r.lanes()?;
        let lane_extents = if metadata.get("schema").map(String::as_str) == Some(SCHEMA_EXTENTS) {
            Some(r.lane_extents(lanes.centres.len())?)
        } else {
            None
        };
        let agent_ids = r.i64s("agent_ids", &[Some(n)])?;
        let name = path.file_stem().map_or_else(
            || "<memory>".to_string(),
            |s| s.to_string_lossy().into_owned(),
        );
        let sc = Self {
            name,
            n_agents: n,
            history: agents.history,
            heading: agents.heading,
            speed: agents.speed,
            size: agents.size,
            n_future: future.n_future,
            future: future.future,
            future_valid: future.future_valid,
            lane_centres: lanes.centres,
            lane_bounds: lanes.bounds,
            ego_lane: lanes.ego_lane,
            agent_ids,
            lane_extents,
            metadata,
        };
        sc.check_plausible(path)?;
        sc.check_ego_clear(path)?;
        Ok(sc)
    }

    /// The physical plausibility checks of [`Scenario::from_bytes`] (format already checked):
    /// the road, then every agent, then the distances between agents, then the ego's lane.
    fn check_plausible(&self, path: &Path) -> Result<(), ScenarioError> {
        self.check_road(path)?;
        for a in 0..self.n_agents {
            self.check_history(path, a)?;
            self.check_state(path, a)?;
            self.check_future(path, a)?;
        }
        self.check_agent_spacing(path)?;
        self.check_ego_lane(path)
    }

    /// [`ScenarioError::Implausible`] naming `agent` (index and source id) and `field`.
    fn implausible(
        &self,
        path: &Path,
        agent: usize,
        field: &'static str,
        detail: String,
    ) -> ScenarioError {
        ScenarioError::Implausible {
            path: path.to_path_buf(),
            agent,
            id: self.agent_ids[agent],
            field,
            detail,
        }
    }

    /// The road: at most [`MAX_LANES`] lanes, boundaries within ±[`MAX_ABS_POSITION`] m,
    /// every lane [`LANE_WIDTH`] wide.
    fn check_road(&self, path: &Path) -> Result<(), ScenarioError> {
        let nl = self.lane_centres.len();
        if nl > MAX_LANES {
            return Err(bad_value(
                path,
                "lane_centres",
                format!("{nl} lanes; plausible roads have 1..={MAX_LANES}"),
            ));
        }
        if let Some(v) = self.lane_bounds.iter().find(|v| v.abs() > MAX_ABS_POSITION) {
            return Err(bad_value(
                path,
                "lane_bounds",
                format!("y = {v} m is beyond the accepted ±{MAX_ABS_POSITION} m"),
            ));
        }
        for (i, w) in self.lane_bounds.windows(2).enumerate() {
            let width = w[1] - w[0];
            if !(LANE_WIDTH[0]..=LANE_WIDTH[1]).contains(&width) {
                return Err(bad_value(
                    path,
                    "lane_bounds",
                    format!(
                        "lane {i} has width {width:e} m, outside the plausible {}..={} m",
                        LANE_WIDTH[0], LANE_WIDTH[1]
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The observed positions of `agent`, oldest first: within ±[`MAX_ABS_POSITION`] m, at
    /// most [`ROAD_TOLERANCE`] outside the road, and at most [`MAX_SPEED`] × 0.3 s from the
    /// previous one.
    fn check_history(&self, path: &Path, a: usize) -> Result<(), ScenarioError> {
        let [right, left] = self.road();
        let max_step = MAX_SPEED * nudge_predictor::DT;
        for t in 0..T_OBS {
            let [x, y] = self.position(a, t);
            if x.abs().max(y.abs()) > MAX_ABS_POSITION {
                return Err(self.implausible(
                    path,
                    a,
                    "history",
                    format!(
                        "({x}, {y}) m at observed step {t} is beyond the accepted \
                         ±{MAX_ABS_POSITION} m"
                    ),
                ));
            }
            let outside = (right - y).max(y - left);
            if outside > ROAD_TOLERANCE {
                return Err(self.implausible(
                    path,
                    a,
                    "history",
                    format!(
                        "y = {y} m at observed step {t} is {outside:.2} m outside the road \
                         [{right}, {left}] m (tolerance {ROAD_TOLERANCE} m)"
                    ),
                ));
            }
            if t > 0 {
                let p = self.position(a, t - 1);
                let d = (x - p[0]).hypot(y - p[1]);
                if d > max_step {
                    return Err(self.implausible(
                        path,
                        a,
                        "history",
                        format!(
                            "moves {d:.2} m between observed steps {} and {t}, more than \
                             {max_step} m ({MAX_SPEED} m/s for 0.3 s)",
                            t - 1
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The last observed state of `agent`: |heading| ≤ [`MAX_HEADING`], speed ≤
    /// [`MAX_SPEED`], length in [`VEHICLE_LENGTH`], width in [`VEHICLE_WIDTH`].
    fn check_state(&self, path: &Path, a: usize) -> Result<(), ScenarioError> {
        let psi = self.heading[a];
        if psi.abs() > MAX_HEADING {
            return Err(self.implausible(
                path,
                a,
                "heading",
                format!(
                    "{psi} rad is outside the plausible |heading| <= {MAX_HEADING:.4} rad \
                     (pi/4) relative to the road"
                ),
            ));
        }
        let v = self.speed[a];
        if v > MAX_SPEED {
            return Err(self.implausible(
                path,
                a,
                "speed",
                format!("{v} m/s is outside the plausible 0..={MAX_SPEED} m/s"),
            ));
        }
        let [length, width] = self.size[a];
        if !(VEHICLE_LENGTH[0]..=VEHICLE_LENGTH[1]).contains(&length) {
            return Err(self.implausible(
                path,
                a,
                "size",
                format!(
                    "length {length} m is outside the plausible {}..={} m",
                    VEHICLE_LENGTH[0], VEHICLE_LENGTH[1]
                ),
            ));
        }
        if !(VEHICLE_WIDTH[0]..=VEHICLE_WIDTH[1]).contains(&width) {
            return Err(self.implausible(
                path,
                a,
                "size",
                format!(
                    "width {width} m is outside the plausible {}..={} m",
                    VEHICLE_WIDTH[0], VEHICLE_WIDTH[1]
                ),
            ));
        }
        Ok(())
    }

    /// The valid logged future positions of `agent`: within ±[`MAX_ABS_POSITION`] m.
    fn check_future(&self, path: &Path, a: usize) -> Result<(), ScenarioError> {
        for k in 1..=self.n_future {
            if let Some([x, y]) = self.future_at(a, k)
                && x.abs().max(y.abs()) > MAX_ABS_POSITION
            {
                return Err(self.implausible(
                    path,
                    a,
                    "future",
                    format!("({x}, {y}) m at future step {k} is beyond ±{MAX_ABS_POSITION} m"),
                ));
            }
        }
        Ok(())
    }

    /// Every pair of agents at most [`MAX_AGENT_OFFSET`] m apart at the last observed step
    /// (the later agent of the first pair too far apart is named).
    fn check_agent_spacing(&self, path: &Path) -> Result<(), ScenarioError> {
        for i in 0..self.n_agents {
            for j in i + 1..self.n_agents {
                let (p, q) = (self.position(i, T_OBS - 1), self.position(j, T_OBS - 1));
                let d = (p[0] - q[0]).hypot(p[1] - q[1]);
                if d > MAX_AGENT_OFFSET {
                    return Err(self.implausible(
                        path,
                        j,
                        "history",
                        format!(
                            "is {d:.1} m from agent {i} at the last observed step, more than \
                             {MAX_AGENT_OFFSET} m"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The ego's y at the last observed step lies within its `ego_lane` boundaries, up to
    /// [`EGO_LANE_TOLERANCE`].
    fn check_ego_lane(&self, path: &Path) -> Result<(), ScenarioError> {
        let y = self.position(0, T_OBS - 1)[1];
        let (lo, hi) = (
            self.lane_bounds[self.ego_lane],
            self.lane_bounds[self.ego_lane + 1],
        );
        if y < lo - EGO_LANE_TOLERANCE || y > hi + EGO_LANE_TOLERANCE {
            return Err(ScenarioError::EgoLane {
                path: path.to_path_buf(),
                ego_lane: self.ego_lane,
                y,
                lo,
                hi,
                tolerance: EGO_LANE_TOLERANCE,
            });
        }
        if let Some(ext) = &self.lane_extents {
            let x = self.position(0, T_OBS - 1)[0];
            let e = ext[self.ego_lane];
            if x < e.begin - EGO_EXTENT_TOLERANCE || x > e.end + EGO_EXTENT_TOLERANCE {
                return Err(self.implausible(
                    path,
                    0,
                    "lane_extent",
                    format!(
                        "the ego at x = {x} m is outside its lane's extent [{}, {}] m \
                         (tolerance {EGO_EXTENT_TOLERANCE} m)",
                        e.begin, e.end
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The ego's box overlaps no other vehicle's box at the last observed step.
    fn check_ego_clear(&self, path: &Path) -> Result<(), ScenarioError> {
        let ego = self.vehicle_box(0);
        for i in 1..self.n_agents {
            if ego.overlaps(&self.vehicle_box(i)) {
                return Err(ScenarioError::EgoOverlap {
                    path: path.to_path_buf(),
                    agent: i,
                    id: self.agent_ids[i],
                });
            }
        }
        Ok(())
    }

    /// Position `[x, y]` (m) of `agent` at observed step `t` (0 = oldest, 7 = now).
    #[must_use]
    pub fn position(&self, agent: usize, t: usize) -> [f64; 2] {
        let k = (agent * T_OBS + t) * 2;
        [self.history[k], self.history[k + 1]]
    }

    /// The bounding box of `agent` at the last observed step.
    #[must_use]
    pub fn vehicle_box(&self, agent: usize) -> OrientedBox {
        let p = self.position(agent, T_OBS - 1);
        OrientedBox {
            x: p[0],
            y: p[1],
            heading: self.heading[agent],
            length: self.size[agent][0],
            width: self.size[agent][1],
        }
    }

    /// The lane layout with extents for a [`crate::PlanningProblem`] (`None` for a
    /// "nudge.scenario/1" scene).
    #[must_use]
    pub fn lanes(&self) -> Option<crate::extents::Lanes<'_>> {
        self.lane_extents
            .as_deref()
            .map(|extents| crate::extents::Lanes {
                bounds: &self.lane_bounds,
                extents,
            })
    }

    /// Road edges (right, left) y (m).
    #[must_use]
    pub fn road(&self) -> [f64; 2] {
        [
            self.lane_bounds[0],
            self.lane_bounds[self.lane_bounds.len() - 1],
        ]
    }

    /// Logged future position of `agent` at future step `k` (1-based), if real data.
    #[must_use]
    pub fn future_at(&self, agent: usize, k: usize) -> Option<[f64; 2]> {
        if k == 0 || k > self.n_future || !self.future_valid[agent * self.n_future + k - 1] {
            return None;
        }
        let i = (agent * self.n_future + k - 1) * 2;
        Some([self.future[i], self.future[i + 1]])
    }

    /// A copy keeping the ego and its `keep` nearest neighbours at the last observed step
    /// (nearest first). Used to build scenes of a chosen size for benchmarks.
    #[must_use]
    pub fn nearest(&self, keep: usize) -> Self {
        let e = self.position(0, T_OBS - 1);
        let mut order: Vec<usize> = (1..self.n_agents).collect();
        order.sort_by(|&a, &b| {
            let da = dist2(self.position(a, T_OBS - 1), e);
            let db = dist2(self.position(b, T_OBS - 1), e);
            da.total_cmp(&db).then(a.cmp(&b))
        });
        order.truncate(keep);
        let mut idx = vec![0];
        idx.extend(order);
        let nf = self.n_future;
        let pick = |v: &[f64], per: usize| -> Vec<f64> {
            idx.iter()
                .flat_map(|&i| v[i * per..(i + 1) * per].iter().copied())
                .collect()
        };
        Self {
            name: format!("{}-n{}", self.name, idx.len()),
            n_agents: idx.len(),
            history: pick(&self.history, T_OBS * 2),
            heading: pick(&self.heading, 1),
            speed: pick(&self.speed, 1),
            size: idx.iter().map(|&i| self.size[i]).collect(),
            n_future: nf,
            future: pick(&self.future, nf * 2),
            future_valid: idx
                .iter()
                .flat_map(|&i| self.future_valid[i * nf..(i + 1) * nf].iter().copied())
                .collect(),
            lane_centres: self.lane_centres.clone(),
            lane_bounds: self.lane_bounds.clone(),
            ego_lane: self.ego_lane,
            agent_ids: idx.iter().map(|&i| self.agent_ids[i]).collect(),
            lane_extents: self.lane_extents.clone(),
            metadata: self.metadata.clone(),
        }
    }

    /// The paths of every `.safetensors` file in `dir`, sorted by name (the order the CLI runs
    /// them in).
    ///
    /// # Errors
    /// [`ScenarioError::Io`] when the directory or one of its entries cannot be read.
    pub fn paths_in(dir: impl AsRef<Path>) -> Result<Vec<PathBuf>, ScenarioError> {
        let dir = dir.as_ref();
        let io = |source| ScenarioError::Io {
            path: dir.to_path_buf(),
            source,
        };
        let mut paths = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(io)? {
            let p = entry.map_err(io)?.path();
            if p.extension().is_some_and(|x| x == "safetensors") {
                paths.push(p);
            }
        }
        paths.sort();
        Ok(paths)
    }

    /// Every `.safetensors` file in `dir`, sorted by name, read and validated; files that fail
    /// are returned with their error.
    ///
    /// # Errors
    /// [`ScenarioError::Io`] when the directory cannot be listed.
    #[allow(clippy::type_complexity)]
    pub fn load_dir(
        dir: impl AsRef<Path>,
    ) -> Result<(Vec<Self>, Vec<(PathBuf, ScenarioError)>), ScenarioError> {
        let mut ok = Vec::new();
        let mut bad = Vec::new();
        for p in Self::paths_in(dir)? {
            match Self::from_file(&p) {
                Ok(s) => ok.push(s),
                Err(e) => bad.push((p, e)),
            }
        }
        Ok((ok, bad))
    }
}

fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}
