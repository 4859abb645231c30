"""Type stubs of the Rust extension ``nudge._native`` (crates/pybind). Keep in sync: tests check
that every public name of the module appears here with the module's parameters and defaults
(``...`` where the default is a Rust constant: see ``DEFAULTS`` and ``SimConfig.default()``)."""

from collections.abc import Callable, Sequence
from os import PathLike
from pathlib import Path
from typing import Any, Literal, Protocol, TypedDict

import numpy as np
import numpy.typing as npt

__version__: str
# The git commit this extension was built from ("unknown" outside a git checkout).
GIT_SHA: str
T_OBS: int
MAX_AGENTS: int
DT: float
# Fraction of the surrounding traffic's speed below which the ego is slow (closed-loop metrics).
SLOW_FRACTION: float

class _Defaults(TypedDict):
    predictor: str  # "student"
    world_predictor: str  # "teacher"
    seed: int  # 0
    runs: int  # 1 per scene

DEFAULTS: _Defaults
"""The front ends' defaults, from Rust (``nudge_sim::defaults``)."""

class _FieldDoc(TypedDict):
    field: str  # name, as a keyword and in JSON
    unit: str  # "" when it has none
    default: int | float | bool | str
    range: str  # the values validation accepts: "[a, b]", "(a, b]", "true or false", names
    doc: str  # meaning: the Rust doc comment

class NudgeError(Exception):
    """Base class of every nudge error."""

class WeightsError(NudgeError):
    """A weights file is missing, malformed or inconsistent with its config."""

class InputError(NudgeError):
    """An input array has the wrong shape or dtype, or holds NaN/inf."""

class SettingsError(NudgeError):
    """Planner or closed-loop settings are invalid (unknown key, impossible value)."""

class ScenarioError(NudgeError):
    """A scenario file is missing or malformed."""

class SolverError(NudgeError):
    """An optimisation step failed."""

class WorldFileError(NudgeError):
    """A world file (the idm world's driver population, "nudge.idm/1") is missing or malformed."""

class ReentrancyError(NudgeError):
    """A planner was called again from inside its own planning call (its predictor called back
    into it): refused instead of waiting for itself."""

class PredictorError(NudgeError):
    """A predictor given from Python failed (its exception is the cause), lacks a method, or
    returned a prediction of the wrong type or shape, non-finite or implausible."""

_F64 = npt.NDArray[np.float64]
_F32 = npt.NDArray[np.float32]
_I64 = npt.NDArray[np.int64]
_Bool = npt.NDArray[np.bool_]
_Path = str | PathLike[str]
# Coordinates: a float64/float32 array (other dtypes are refused, not converted) or a nested
# list/tuple of real numbers.
_Coords = _F64 | _F32 | Sequence[Any]

class Predictor:
    """Teacher, student (from a .safetensors file) or constant-velocity baseline."""

    @staticmethod
    def load(path: _Path, horizon: int | None = None) -> Predictor: ...
    @staticmethod
    def constant_velocity(horizon: int = 6) -> Predictor: ...
    @property
    def name(self) -> Literal["teacher", "student", "constant_velocity"]: ...
    @property
    def horizon(self) -> int: ...
    def predict(self, history: _Coords, candidates: _Coords) -> _F64:
        """history [agents, 8, 2], candidates [batch, horizon, 2] (m; float64/float32 arrays
        or nested lists of numbers; masked arrays are refused; at most 16384 candidates)
        -> [batch, agents - 1, horizon, 2] float64."""

class _PythonPredictor(Protocol):
    """Your own predictor (docs/python_predictor.md): metres in the road frame (x along travel,
    y lateral positive left), 0.3 s steps, agent 0 = the ego. Optional: ``set_scene(history)``,
    called once per planning step before its ``predict`` calls, and an int attribute
    ``horizon`` (default ``settings.model["horizon"]``)."""

    def predict(self, history: _F64, candidates: _F64) -> Any:
        """history [n, 8, 2] float64 (the last 8 observed positions of every agent, oldest
        first; read-only, one array per planning step), candidates [batch, horizon, 2] float64
        (the ego's positions at steps 1..horizon; read-only) -> [batch, n - 1, horizon, 2]
        float64/float32 (or anything ``numpy.asarray`` converts, e.g. a CPU torch tensor):
        agents 1..n-1 under each candidate."""

class _PythonPlanner(Protocol):
    """Your own planner (docs/python_planner.md), driving the ego of ``simulate(...,
    planner=obj)``. Optional: ``reset()``, called before each run's first step."""

    def plan(self, observation: dict[str, Any]) -> Any:
        """observation: ``scenario``, ``seed``, ``step``, ``dt``, ``horizon`` (T), ``ego`` [4]
        (x, y, psi, v), ``last_inputs`` [2] (delta, accel), ``history`` [n, 8, 2], ``sizes``
        [n, 2], ``lane_centres`` [L], ``lane_bounds`` [L + 1], ``road`` [2], ``y_target``,
        ``y_retreat`` (float or None), ``v_ref``, ``bounds`` (``delta_max``, ``a_min``,
        ``a_max``); arrays read-only float64, metres / radians / m/s in the road frame ->
        ``{"delta": [T], "accel": [T]}`` (rad, m/s²; finite, within ``bounds``)."""

class PlannerSettings:
    """Planner settings in groups that follow the MPC call's phases (``model``, ``cost``,
    ``bounds``, ``safety``, ``admm``, ``repair``, ``budget``, ``lane_ends``): a group reads as a
    dict (``s.cost["w_y"]``), a field also by its dotted name (``getattr(s, "cost.w_y")``).
    Overrides are group dicts (``PlannerSettings(cost={"w_y": 20})``, merged into the group) or
    dotted keys (``PlannerSettings(**{"cost.w_y": 20})``); a flat key of earlier versions raises
    ``SettingsError`` naming where it moved or why it was removed. The docstring lists every
    field with its unit, default, valid values and meaning, as does ``describe()``."""

    def __init__(self, **overrides: int | float | bool | dict[str, int | float | bool]) -> None: ...
    @staticmethod
    def default() -> PlannerSettings: ...
    @staticmethod
    def from_dict(d: dict[str, dict[str, int | float | bool]]) -> PlannerSettings: ...
    def to_dict(self) -> dict[str, dict[str, int | float | bool]]: ...
    @staticmethod
    def from_json(text: str) -> PlannerSettings: ...
    def to_json(self) -> str: ...
    def replace(self, **overrides: int | float | bool | dict[str, int | float | bool]) -> PlannerSettings: ...
    @staticmethod
    def describe() -> list[_FieldDoc]: ...
    def __getattr__(self, name: str) -> int | float | bool | dict[str, int | float | bool]: ...
    def __eq__(self, other: object) -> bool: ...

class SimConfig:
    """Closed-loop settings; fields are readable as attributes (``c.max_steps``). The docstring
    lists every field with its unit, default, valid values and meaning, as does
    ``describe()``."""

    def __init__(self, **overrides: int | float | str) -> None: ...
    @staticmethod
    def default() -> SimConfig: ...
    @staticmethod
    def from_dict(d: dict[str, int | float | str]) -> SimConfig: ...
    def to_dict(self) -> dict[str, int | float | str]: ...
    @staticmethod
    def from_json(text: str) -> SimConfig: ...
    def to_json(self) -> str: ...
    def replace(self, **overrides: int | float | str) -> SimConfig: ...
    @staticmethod
    def describe() -> list[_FieldDoc]: ...
    def __getattr__(self, name: str) -> int | float | str: ...
    def __eq__(self, other: object) -> bool: ...

class Scenario:
    """A "nudge.scenario/1" or "nudge.scenario/2" scene (agent 0 = ego), road frame, metres."""

    @staticmethod
    def load(path: _Path) -> Scenario: ...
    @staticmethod
    def from_arrays(
        history: npt.ArrayLike,
        size: npt.ArrayLike,
        lane_bounds: npt.ArrayLike,
        ego_lane: int,
        *,
        heading: npt.ArrayLike | None = None,
        speed: npt.ArrayLike | None = None,
        future: npt.ArrayLike | None = None,
        future_valid: npt.ArrayLike | None = None,
        lane_centres: npt.ArrayLike | None = None,
        agent_ids: npt.ArrayLike | None = None,
        lane_extents: npt.ArrayLike | None = None,
        lane_extent_real: npt.ArrayLike | None = None,
        name: str = "scene",
        metadata: dict[str, str] | None = None,
    ) -> Scenario:
        """A scene from your own data, validated exactly as a scenario file (written to a file
        image in memory and read back by the file reader). history [n, 8, 2], size [n, 2],
        lane_bounds [L + 1] (ascending; first and last the road edges), ego_lane; optional
        heading, speed [n] (default from the last two observed positions), future [n, F, 2] with
        future_valid [n, F] bool (default: 6 constant-velocity steps, none valid), lane_centres
        [L] (default midway), agent_ids [n] int (default 0..n), lane_extents [L, 2] with
        lane_extent_real [L, 2] bool ("nudge.scenario/2"). InputError for a wrong type or shape,
        ScenarioError for what the reader refuses."""
    def save(self, path: _Path) -> None:
        """Writes the scene as a scenario file (``Scenario.load`` reads it back equal)."""
    @property
    def name(self) -> str: ...
    @property
    def path(self) -> Path: ...
    @property
    def n_agents(self) -> int: ...
    @property
    def history(self) -> _F64:
        """[n, 8, 2] m."""
    @property
    def heading(self) -> _F64:
        """[n] rad."""
    @property
    def speed(self) -> _F64:
        """[n] m/s."""
    @property
    def size(self) -> _F64:
        """[n, 2] (length, width) m."""
    @property
    def future(self) -> _F64:
        """[n, F, 2] m."""
    @property
    def future_valid(self) -> _Bool:
        """[n, F]."""
    @property
    def lane_centres(self) -> _F64: ...
    @property
    def lane_bounds(self) -> _F64: ...
    @property
    def lane_extents(self) -> _F64 | None:
        """[L, 2] (begin, end) m; None for "nudge.scenario/1"."""
    @property
    def lane_extent_real(self) -> _Bool | None:
        """[L, 2] (begins, ends); None for "nudge.scenario/1"."""
    @property
    def ego_lane(self) -> int: ...
    @property
    def agent_ids(self) -> _I64: ...
    @property
    def metadata(self) -> dict[str, str]: ...
    @property
    def road(self) -> tuple[float, float]: ...
    def target_lane(self, seed: int, settings: PlannerSettings | None = None, config: SimConfig | None = None) -> int: ...
    def nearest(self, keep: int) -> Scenario: ...

class Timings(TypedDict):
    delta_s: float
    alpha_s: float
    z_s: float
    total_s: float
    z_updates_s: _F64

class LaneViolation(TypedDict):
    step: int  # plan step, 1-based
    lane: int
    kind: Literal["Ended", "NotBegun"]
    x: float  # m

class PlanResult(TypedDict, total=False):
    delta: _F64  # [T] rad
    accel: _F64  # [T] m/s^2
    states: _F64  # [T, 4] (x, y, psi, v): the nonlinear roll-out of delta, accel
    admm_states: _F64  # [T, 4] ADMM's own Z at the end of its loop ([0, 4] after a QP failure)
    cost: float
    iterations: int
    predictor_calls: int
    refused_candidates: int  # candidates outside the predictors' range, judged unsafe unpredicted
    qp_solves: int
    primal_residual: float
    change_residual: float
    min_safety: float | None
    rollout_min_safety: float | None
    checked: int
    status: Literal["Converged", "MaxIterations", "Refined", "Unsafe", "BudgetExhausted", "Backtracked", "Fallback", "SolverFailed"]
    solver_failure: tuple[str, str] | None  # (qp "delta" | "alpha", Clarabel status) for SolverFailed
    decided_by: str  # what decided the applied inputs (DecidedBy label)
    budget_reached: Literal["Calls", "Seconds"] | None  # the budget limit the call reached, if any
    timings: Timings
    lane_violation: LaneViolation | None  # first planned state in a lane outside its extent
    target_lane: int  # plan_scenario only
    y_target: float  # plan_scenario only

class Session:
    """nudge's closed loop one step at a time (the Rust ``nudge_sim::Session``), the core of
    ``nudge.env`` (docs/env.md). Built and checked like a ``simulate`` batch over
    ``scene_paths``; ``reset(scene, seed)`` starts the run ``simulate`` makes of that scene with
    that seed. Planning and stepping release the GIL."""

    def __init__(
        self,
        scene_paths: Sequence[str],
        predictor: str = ...,
        *,
        world_predictor: str | None = None,
        idm: str | None = None,
        settings: PlannerSettings | None = None,
        config: SimConfig | None = None,
        assets: str | None = None,
        **config_overrides: int | float | str,
    ) -> None: ...
    @property
    def scene_names(self) -> list[str]: ...
    @property
    def lane_counts(self) -> list[int]: ...
    @property
    def settings(self) -> PlannerSettings: ...
    @property
    def config(self) -> SimConfig: ...
    @property
    def predictor(self) -> str: ...
    def reset(self, scene: int, seed: int) -> dict[str, Any]:
        """Starts a run; returns its first observation (the dict a Python planner gets)."""
    def observation(self) -> dict[str, Any]:
        """The current step's observation."""
    def target(self) -> tuple[int, float]:
        """The run's target lane and its centre y (m)."""
    def nudge_plan(self) -> dict[str, npt.NDArray[np.float64]]:
        """nudge's plan for the current step, kept pending: ``{"delta": [T], "accel": [T]}``."""
    def step(
        self, delta: Sequence[float], accel: Sequence[float]
    ) -> tuple[dict[str, Any], str | None, dict[str, Any] | None, dict[str, Any] | None]:
        """Applies the inputs (T each; nudge's pending plan when equal to it, bit for bit);
        returns the step's ``steps.csv`` row, the end reason or None, and once ended the run's
        ``runs.csv`` row and its collisions. Out-of-bounds or non-finite inputs raise
        InputError (never clamped)."""

class Planner:
    """The ADMM MPC planner bound to one predictor (keeps a warm start; see reset)."""

    def __init__(self, settings: PlannerSettings | None, predictor: Predictor | _PythonPredictor) -> None:
        """``predictor``: a Predictor, or your own object with ``predict(history, candidates)``
        (``_PythonPredictor``; called with the GIL held only inside its calls; failures raise
        PredictorError naming the item, an exception it raises as the cause). Raises
        SettingsError when the settings do not fit the predictor (horizon; dt = 0.3 s for a
        teacher or student), PredictorError for an object without ``predict``."""
    @property
    def settings(self) -> PlannerSettings: ...
    @property
    def predictor(self) -> Predictor | _PythonPredictor: ...
    def reset(self) -> None: ...
    def plan(
        self,
        history: _Coords,
        sizes: _Coords,
        ego: _Coords,
        y_target: float,
        v_ref: float,
        road: tuple[float, float],
        last_delta: float = 0.0,
        last_accel: float = 0.0,
        y_retreat: float | None = None,
        lane_bounds: _Coords | None = None,
        lane_extents: _Coords | None = None,
        lane_extent_real: _Coords | None = None,
    ) -> PlanResult:
        """One MPC call on raw arrays. Lanes that begin and end (as ``Scenario.lane_bounds``,
        ``lane_extents``, ``lane_extent_real`` give them): ``lane_bounds`` ``[L + 1]`` (m),
        ``lane_extents`` ``[L, 2]`` (begin, end x, m), ``lane_extent_real`` ``[L, 2]`` (bool or
        0/1, default all true); both of the first two or neither. A planned state in a lane that
        has not begun or has ended is inadmissible (``lane_violation``); a bad layout raises
        InputError naming the lane and field."""
    def plan_scenario(
        self, scenario: Scenario, target_lane: int | None = None, seed: int = 0, config: SimConfig | None = None
    ) -> PlanResult: ...

def model_path(assets: _Path, name: Literal["teacher", "student"]) -> Path:
    """The shipped weights of ``name`` under ``assets`` (the Rust resolver's path)."""

def assets_dir(shipped: _Path) -> Path:
    """``$NUDGE_ASSETS`` when set and not empty, else ``shipped`` (the one assets rule)."""

def scenes_dir(assets: _Path) -> Path:
    """The shipped scenes under ``assets``: ``<assets>/scenes``."""

def cli_main(argv: list[str], assets: _Path) -> int:
    """Runs the Rust ``nudge`` command line on ``argv`` (program name first) with the shipped
    assets at ``assets``; returns its exit status (0, 1, 2 or 3)."""

def commonroad_scenario(
    path: _Path,
    *,
    ego: int | None = None,
    planning_problem: int | None = None,
    t0: float | None = None,
    neighbour_range: float | None = None,
) -> Scenario:
    """The nudge scenario of ``ego`` (a dynamic obstacle id) or ``planning_problem`` (an id) in
    the CommonRoad 2020a/2018b file ``path`` (.xml or .xml.gz), in the data pipeline's road
    frame, last observed at ``t0`` s (default: the first time with a full 2.1 s history; a
    planning problem's initial time), neighbours within ``neighbour_range`` m (default 60).
    Raises ``ScenarioError`` naming the file and reason (e.g. lanes not straight near the ego)."""

def commonroad_solution(
    path: _Path,
    out: _Path,
    delta: npt.NDArray[np.float64],
    accel: npt.NDArray[np.float64],
    *,
    ego: int | None = None,
    planning_problem: int | None = None,
    t0: float | None = None,
    neighbour_range: float | None = None,
    settings: PlannerSettings | None = None,
) -> dict[str, Any]:
    """Writes to ``out`` the CommonRoad KS solution (vehicle type 2, the file's coordinates) of
    the inputs ``delta`` [steps] (rad) and ``accel`` [steps] (m/s^2), each held 0.3 s from the
    ego of ``commonroad_scenario`` with the same arguments. Returns benchmark_id,
    planning_problem, n_states."""

def commonroad_tracks(path: _Path, *, curvilinear: bool = False) -> dict[str, Any]:
    """The CommonRoad file ``path`` in the road frame: vehicle, step (int64 [N]), x, y (m),
    heading (rad), speed (m/s) (float64 [N]) and pieces: [(x0 m, x1 m, lane bounds [L + 1] m)].
    With ``curvilinear``, in the curvilinear (Frenet) frame used on curved roads."""

class _Trace(TypedDict):
    """One traced run (S steps, n agents, horizon T, L lanes; road frame, m, rad, m/s, s)."""

    title: str
    """Caption title: scenario, seed, predictors, outcome."""
    lane_bounds: _F64
    """[L + 1] lane-boundary y, ascending; the road edges first and last."""
    sizes: _F64
    """[n, 2] (length, width) per agent."""
    agents: _F64
    """[S + 1, n, 3] (x, y, heading) per state (before step 0, after each step), agent 0 the ego."""
    speed: _F64
    """[S + 1] ego speed per state."""
    collision: _Bool
    """[S + 1] the ego's box overlaps another in that state."""
    status: list[str]
    """[S] each step's plan status."""
    mpc_s: _F64
    """[S] planning time per step."""
    plan: _F64
    """[S, T + 1, 4] the plan z_0..z_T (x, y, psi, v) from the measured state."""
    predicted: _F64
    """[S, n - 1, T, 2] the planning predictor's positions of agents 1..n given the plan."""
    binding: _I64
    """[S] the agent the plan's safety binds on (smallest b), -1 when none is checked."""
    binding_step: _I64
    """[S] the plan step of its smallest b, -1 when none."""
    binding_b: _F64
    """[S] its smallest b, NaN when none."""
    semi_axes: _F64
    """[S, T, 2] (a_x, a_y) of its safety ellipse at each plan step, NaN when none."""

class _Written(TypedDict):
    gif: Path
    mp4: Path | None
    frames: int
    width: int
    height: int

def animate(
    trace: _Trace,
    gif: _Path,
    *,
    mp4: _Path | None = None,
    ffmpeg: _Path | None = None,
    **settings: float,
) -> _Written:
    """Draws the traced run ``trace`` into the GIF ``gif`` (one frame per state, the camera
    following the ego: lanes, every vehicle as its rotated box, the executed path, the plan,
    the predicted reaction, the binding vehicle's safety ellipses, a caption) and, when
    ``mp4`` is given, into that MP4 through ``ffmpeg`` (default: the one on ``PATH``), with the
    renderer of ``nudge simulate --animate``. ``settings``: ``px_per_m`` (default 6),
    ``behind_m`` (30), ``ahead_m`` (90), ``margin_m`` (2), ``frame_s`` (0.3 s, real time).

    Raises ``InputError`` for a malformed trace (naming the key), ``SettingsError`` for a bad
    setting, ``NudgeError`` when writing fails or an MP4 is asked for without ffmpeg."""

def find_ffmpeg() -> Path | None:
    """The ``ffmpeg`` program on ``PATH`` (the one ``nudge simulate --animate`` uses), or None."""

def simulate(
    scene_paths: list[_Path],
    predictor: _Path | _PythonPredictor = ...,
    *,
    world_predictor: _Path | None = None,
    idm: _Path | None = None,
    seed: int = ...,
    scene_seeds: list[int] | None = None,
    runs: int = ...,
    threads: int | None = None,
    settings: PlannerSettings | None = None,
    config: SimConfig | None = None,
    record: bool = False,
    trace: bool = False,
    on_error: Literal["raise", "skip"] = "raise",
    assets: _Path | None = None,
    progress: Callable[[int, int], object] | None = None,
    planner: _PythonPlanner | None = None,
    out: _Path | None = None,
    command: list[str] | None = None,
    **config_overrides: int | float | str,
) -> dict[str, Any]:
    """Closed-loop runs over scenario files (in the given order) on ``threads`` rayon threads;
    run ``r`` of scene ``i`` draws its target lane from seed ``scene_seeds[i] + r`` when given,
    else ``seed + i * runs + r``.

    Every argument is checked before any run starts, by the validation the CLI uses
    (``nudge_sim::BatchRequest::prepare``): at least one scene, at most 1,000,000 runs,
    1..=256 threads, settings that fit the predictors (same horizon, ``dt`` = 0.3 s), loadable
    models and scenes. Ctrl-C stops the batch and raises ``KeyboardInterrupt`` within about a
    second.

    ``predictor`` (default ``DEFAULTS["predictor"]``) and ``world_predictor`` (the world model
    of a ``"teacher"`` world, default the shipped teacher; must be a teacher): ``"teacher"``,
    ``"student"``, ``"constant_velocity"`` (named models under ``assets``) or a weights path;
    ``predictor`` may also be your own object with ``predict(history, candidates)``
    (``_PythonPredictor``; its runs go one after another on one thread, ``threads`` > 1 raises
    InputError; the ``predictor`` column reads ``"python"``).
    ``idm``: the driver population of an ``"idm"`` world (default ``<assets>/worlds/idm.json``).
    ``config`` (default ``SimConfig.default()``) with ``config_overrides`` (``SimConfig`` fields:
    ``world``, ``max_steps``, ``settle_y``, ``settle_psi``, ``settle_steps``, ``abort_after``,
    ``abort_hold``, ``stall_progress``, ``start_abort_after``, ``gap_speed``, ``gap_window``,
    ``crawl_fraction``, ``fault_brake_limit``, ``replay_lateral_decay``) sets
    the closed loop. Lane-change
    aborts: after ``abort_after`` consecutive steps without a safe plan (status ``Fallback``,
    ``Unsafe`` or ``SolverFailed``) while the ego is not yet wholly inside the target lane, the ego
    aims at its own lane's centre for ``abort_hold`` steps, then retries (``abort_after = 0``
    disables aborts); with ``stall_progress`` > 0 a step that moved the ego less than that
    (m) towards the target lane while its box straddles the line, before the crossing, counts
    too; with ``start_abort_after`` > 0 an ego whose box starts across a line of its own lane
    aborts after that many steps without a safe plan, before its first safe plan. Gap seeking: while a target-lane vehicle alongside (bumper gap below ``gap_window``, m)
    blocks the change, the planner's reference speed moves ``gap_speed`` (m/s) past that
    vehicle's speed, ahead of it or behind it (off by default: ``gap_speed = 0``).
    Crawl reference: once the ego's starting speed is below ``crawl_fraction`` times the
    median speed of the goal lane's vehicles within 50 m along the road (the last such median
    seen when none is in range), its reference speed is at least that median for the rest of
    the run (``crawl_fraction = 0``: off).
    Log replay past a vehicle's log: it keeps its last displacement along the road and
    repeats ``replay_lateral_decay`` (in [0, 1]; 0.75, fitted to real tracks) of its last
    sideways one per step (1: constant velocity; 0: its lateral position held).
    The metrics and their rules: ``nudge_sim::metrics`` (docs/results/closed_loop.md).

    ``trace``: keep every step's plan and the planning predictor's predicted reaction to it
    (one more predictor call per step; off by default, the other outputs are the same either
    way): the result then holds ``"traces"``, a list with one trace dict per run (``_Trace``) (``None``
    for a run that could not run), which :func:`animate` draws.

    ``planner``: your own planner (``_PythonPlanner``: ``plan(observation) -> {"delta": [T],
    "accel": [T]}``, optionally ``reset()``) drives the ego instead of nudge's planner; its runs
    go one after another on one thread (``threads`` > 1 raises InputError); each step's
    ``status`` is ``Converged`` when nudge's safety check under ``predictor`` passes on the
    plan's roll-out, else ``Unsafe`` (docs/python_planner.md). An exception it raises stops the
    run with ``NudgeError`` (the exception as its cause); an unusable plan with ``InputError``,
    both naming the scene, seed and step.

    ``progress``: a callable called as ``progress(done, total)`` (runs finished, runs in all)
    about every 50 ms while the count grows and once at the end, from the calling thread; an
    exception it raises stops the batch and is raised. Not callable: InputError.

    ``out``: also write the record set into this folder as ``nudge simulate --out`` does
    (``steps.csv``, ``runs.csv``, ``collisions.csv``, ``records.json``, ``provenance.json``, one
    atomic set with its manifest ``outputs.sha256``; docs/records.md), by the CLI's writer; the
    folder is made before any run (NudgeError when it cannot be). ``command``: provenance's
    ``command`` (default empty).

    Returns ``{"runs": ..., "steps": ..., "collisions": ...}`` (+ ``"examples"`` when
    ``record``, ``"traces"`` when ``trace``), the columns of ``nudge_sim::columns`` (the CLI's CSV has the same names
    and values):

    - runs (one row per run): scenario list[str], scene_index i64, seed u64,
      predictor list[str], world list[str], n_agents i64, target_lane i64 (-1 on error),
      y_target f64 (NaN on error), success bool (settled without any collision),
      steps_to_target i64 (-1 = never), collision bool, aborts i64, n_steps i64,
      collisions_at_fault i64, collisions_not_at_fault i64, collisions_at_fault_nuplan i64
      (at fault under nuPlan's own rule, for comparison), start_overhang f64 (m),
      off_road_steps i64, straddle_steps i64, steps_to_lane i64 (-1 = never), slow_steps i64,
      slow_planned_steps i64, slow_planned_free_steps i64 (of those, with the road ahead free:
      nobody in the ego's path within 2 s of headway), min_ttc f64 (s, inf = nobody closed in), progress f64 (m),
      progress_ratio f64 (NaN = no log), max_abs_jerk, rms_jerk f64 (m/s^3),
      max_abs_lat_accel, rms_lat_accel f64 (m/s^2), max_abs_yaw_rate, rms_yaw_rate f64
      (rad/s), max_abs_yaw_accel f64 (rad/s^2), min_accel, max_accel f64 (m/s^2),
      comfortable bool, max_abs_heading f64 (rad), max_overshoot f64 (m, beyond the target lane's
      centre), free_gap f64 (m), score f64, outcome list[str] ("Success", "Collision",
      "LaneEnded", "LaneNotBegun", "Waiting", "Unfinished"; "" on error), error list[str | None] (metric
      columns of a failed run: -1 / NaN / False);
    - steps (one row per closed-loop step): run i64 (row of runs), step i64, mpc_s f64,
      z_updates i64, z_s f64 (sum of the Z-update times), z_median_s f64, iterations i64,
      predictor_calls i64, cost f64, primal_residual f64, min_b f64 (the planner's constraint
      at the executed step; NaN = none checked), collision bool, status list[str] (a
      ``PlanStatus`` name), delta f64, accel f64, x, y, psi, v f64 (the ego after the step),
      y_goal f64 (the lateral position aimed at: the target lane's centre, or the ego's own
      lane's during an abort), v_planned f64 (speed at the end of the applied plan),
      lane_violation i64 (plan step 1..T of the applied plan's first state in a lane that has
      not begun or has ended; -1 = none),
      road_excess f64 (m), off_road bool, straddle bool, in_target_lane bool, traffic_v f64
      (NaN = no traffic), slow bool, slow_planned bool, lead_gap f64 (m, bumper gap to the
      nearest vehicle ahead in the ego's path; inf = none), slow_planned_free bool
      (slow_planned with the road ahead free), ttc f64 (inf = none), progress f64,
      jerk f64 (NaN at the first step), yaw_rate f64, lat_accel f64, yaw_accel f64;
      plus ego f64 [S, 4] = (x, y, psi, v);
    - collisions (one row per collision event): run i64, step i64, other i64 (agent index),
      other_id i64 (source vehicle id), at_fault bool, other_behind bool, rear_hit bool,
      ego_in_lane bool, ego_accel f64, dx, dy f64 (other minus ego, m), ego_heading,
      other_heading f64 (rad), ego_v, other_v f64 (m/s), nuplan_type list[str] (nuPlan's
      collision type: "STOPPED_EGO_COLLISION", "STOPPED_TRACK_COLLISION", "ACTIVE_REAR_COLLISION",
      "ACTIVE_FRONT_COLLISION", "ACTIVE_LATERAL_COLLISION"), nuplan_at_fault bool (nuPlan's rule),
      free_gap f64 (m);
    - examples (every distinct candidate the planning predictor evaluated, float32 m):
      history [H, 8, 2], context_offsets i64 [C + 1], context_run i64 [C],
      example_context i64 [E], candidate [E, T, 2], prediction [P, T, 2],
      prediction_offsets i64 [E + 1], duplicates int.
    """
