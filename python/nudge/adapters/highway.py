"""nudge as the controller of the ego vehicle in highway-env (docs/highway_env.md).

Needs the ``highway`` extra (``pip install "nudge-planner[highway]"``: highway-env, which brings
gymnasium). Driven: the straight roads of ``highway-v0`` and ``highway-fast-v0``. Lanes that
begin and end (merge-v0's merge lane) are passed to nudge with their extents, but highway-env's
merge envs cannot take a continuous action (their reward raises on one)::

    from nudge.adapters.highway import NudgeHighwayController, make_env

    env = make_env("highway-v0")                  # ContinuousAction at nudge's bounds, 0.3 s steps
    ctrl = NudgeHighwayController(env)            # the student predictor, the lane rule below
    env.reset(seed=0)
    ctrl.reset()
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(ctrl.act())
        done = terminated or truncated

**State.** Exact states are read from the simulator (``env.unwrapped.road.vehicles`` and the
ego ``env.unwrapped.vehicle``), not from an observation: position of the box centre (m),
heading (rad), speed (m/s), length and width (m) of every vehicle.

**Frames.** highway-env draws y downwards: its lane 0 is the leftmost lane in the direction of
travel and a positive heading or steering turns right. nudge's road frame has x along travel and
y positive to the left. The map is a mirror, its own inverse: ``(x, y, ψ) -> (x, -y, -ψ)``,
steering ``δ -> -δ`` (:func:`to_nudge`, :func:`to_highway`). nudge's lanes are ordered right to
left (ascending y), so highway-env lane ``i`` of ``L`` straight lanes is nudge lane ``L - 1 - i``
(:class:`LaneLayout`).

**Model.** highway-env moves a vehicle with a kinematic bicycle whose slip is
``atan(tan(δ)/2)`` and heading rate ``v sin β / (length/2)``: nudge's bicycle with
``l_f = l_r = length/2`` (2.5 m for its 5 m cars; :func:`planner_settings`). A controller whose
settings use another bicycle is refused.

**Time.** One ``env.step`` is one nudge step of 0.3 s (``nudge.DT``): ``simulation_frequency``
is ``substeps / 0.3`` Hz (default 3 sub-steps, 10 Hz, the action held over them) and
``policy_frequency`` the largest float whose floor division gives ``substeps`` frames
(``10 // (10/3)`` is 2 in floating point) (:func:`env_config`).

**History.** nudge's predictors take every agent's last ``nudge.T_OBS`` (8) positions, 0.3 s
apart, oldest first. :class:`HistoryBuffer` records every vehicle at each call of
:meth:`NudgeHighwayController.act`; a vehicle seen fewer than 8 times is padded backwards at
constant velocity along its heading (all vehicles at ``reset``), and the count of padded
entries is reported.

**Actions.** ``ContinuousAction`` with ``acceleration_range = [a_min, a_max]`` and
``steering_range = [-delta_max, delta_max]`` of the planner settings' bounds and ``clip`` off:
nudge's first planned input is mapped linearly onto ``[-1, 1]`` (``[acceleration, steering]``)
and sent as it is. A value outside ``[-1, 1]`` is never clamped: it is recorded
(:attr:`EpisodeStats.out_of_range`) and the env applies it unclamped.

**Target lane** (:class:`LaneRule`, or a fixed highway-env lane id ``target_lane``): a lane's
speed is that of its nearest vehicle ahead within ``look_ahead`` m (``v_ref`` when there is
none); the ego moves to an adjacent lane whose speed beats its own lane's by ``advantage`` m/s
when that lane has ``gap_ahead`` m clear in front and ``gap_behind + time_gap * closing speed``
m clear behind (bumper to bumper), the right one first on a tie. Once chosen, the target holds
until the ego's centre is within ``arrive_tolerance`` m of its centre line or ``max_change_steps``
steps have passed; the lane it came from is the planner's retreat (``y_retreat``); then the ego
keeps its lane for ``settle_steps`` steps before the rule looks again. An ego whose centre is
beyond a road edge counts in the lane at that edge (the steps are counted:
:attr:`EpisodeStats.off_road`).
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import nudge

try:
    import gymnasium as gym
    import highway_env  # noqa: F401  (registers highway-v0, merge-v0, ...)
    from highway_env.envs.common.action import ContinuousAction
    from highway_env.road.lane import StraightLane
except ImportError as e:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        'nudge.adapters.highway needs highway-env: pip install "nudge-planner[highway]"'
    ) from e

__all__ = [
    "DEFAULT_SUBSTEPS",
    "EpisodeResult",
    "EpisodeStats",
    "HighwayAdapterError",
    "HistoryBuffer",
    "LaneLayout",
    "LaneRule",
    "NudgeHighwayController",
    "action_from_inputs",
    "env_config",
    "inputs_from_action",
    "make_env",
    "planner_settings",
    "run_episode",
    "to_highway",
    "to_nudge",
]

DEFAULT_SUBSTEPS = 3
"""Simulator sub-steps per 0.3 s step (10 Hz)."""

_TOL = 1e-6  # m: lanes meeting, lines parallel


class HighwayAdapterError(nudge.NudgeError):
    """The env cannot be driven by nudge as configured (the message names the field), or the
    controller was used out of order."""


# ---- frames -----------------------------------------------------------------------------------


def to_nudge(x: Any, y: Any, heading: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """highway-env (x, y down, heading clockwise) -> nudge road frame (x, y left, ψ) (m, m, rad);
    any broadcastable shapes."""
    return np.asarray(x, dtype=np.float64), -np.asarray(y, dtype=np.float64), -np.asarray(heading, dtype=np.float64)


def to_highway(x: Any, y: Any, psi: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """nudge road frame -> highway-env: the same mirror (it is its own inverse)."""
    return to_nudge(x, y, psi)


# ---- settings and env config ------------------------------------------------------------------


def planner_settings(vehicle_length: float = 5.0, **overrides: Any) -> nudge.PlannerSettings:
    """nudge's default planner settings with the bicycle of highway-env's cars of length
    ``vehicle_length`` (m): ``l_f = l_r = length / 2``; ``overrides`` as for
    ``nudge.PlannerSettings`` (group dicts or dotted keys)."""
    half = vehicle_length / 2.0
    return nudge.PlannerSettings(model={"l_f": half, "l_r": half}).replace(**overrides)


def _frequencies(substeps: int) -> tuple[float, float]:
    if not isinstance(substeps, int) or substeps < 1:
        raise HighwayAdapterError(f"substeps: {substeps!r} is not a positive integer")
    sim = substeps / nudge.DT
    policy = sim / substeps
    # highway-env runs int(sim // policy) frames per step; 10 // (10/3) is 2.0 in floating point.
    while int(sim // policy) < substeps:
        policy = math.nextafter(policy, 0.0)
    return sim, policy


def env_config(settings: nudge.PlannerSettings | None = None, substeps: int = DEFAULT_SUBSTEPS) -> dict[str, Any]:
    """The highway-env config keys the adapter needs: ``action`` (ContinuousAction at the
    settings' bounds, no clipping), ``simulation_frequency`` (``substeps / 0.3`` Hz) and
    ``policy_frequency`` (one step = 0.3 s)."""
    s = settings if settings is not None else planner_settings()
    b = s.bounds
    sim, policy = _frequencies(substeps)
    return {
        "action": {
            "type": "ContinuousAction",
            "acceleration_range": [float(b["a_min"]), float(b["a_max"])],
            "steering_range": [-float(b["delta_max"]), float(b["delta_max"])],
            "longitudinal": True,
            "lateral": True,
            "dynamical": False,
            "clip": False,
        },
        "simulation_frequency": sim,
        "policy_frequency": policy,
    }


def make_env(
    env_id: str = "highway-v0",
    config: Mapping[str, Any] | None = None,
    settings: nudge.PlannerSettings | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    **make_kwargs: Any,
) -> gym.Env:
    """``gymnasium.make(env_id, config=...)`` with :func:`env_config` over ``config`` (the
    highway-env config you want besides; a key of :func:`env_config` given there with another
    value raises HighwayAdapterError naming it)."""
    cfg = dict(config or {})
    ours = env_config(settings, substeps)
    for key, value in ours.items():
        if key in cfg and cfg[key] != value:
            raise HighwayAdapterError(f"config[{key!r}] = {cfg[key]!r}: the adapter needs {value!r}")
        cfg[key] = value
    return gym.make(env_id, config=cfg, **make_kwargs)


# ---- actions ----------------------------------------------------------------------------------


def action_from_inputs(delta: float, accel: float, bounds: Mapping[str, float]) -> np.ndarray:
    """nudge inputs (steering δ rad, acceleration m/s², nudge frame) -> highway-env's
    ContinuousAction ``[acceleration, steering]`` in ``[-1, 1]`` for the ranges of
    :func:`env_config` (the inverse of highway-env's ``lmap``). Not clamped: a value outside
    ``[-1, 1]`` means an input outside the bounds."""
    a_min, a_max, d_max = float(bounds["a_min"]), float(bounds["a_max"]), float(bounds["delta_max"])
    a = -1.0 + (accel - a_min) * 2.0 / (a_max - a_min)
    s = -1.0 + (-delta + d_max) * 2.0 / (2.0 * d_max)
    return np.array([a, s], dtype=np.float64)


def inputs_from_action(action: Any, bounds: Mapping[str, float]) -> tuple[float, float]:
    """highway-env's ContinuousAction ``[acceleration, steering]`` -> (δ rad, a m/s²) in the
    nudge frame, as highway-env maps it (its ``lmap``)."""
    a_min, a_max, d_max = float(bounds["a_min"]), float(bounds["a_max"]), float(bounds["delta_max"])
    a_n, s_n = float(action[0]), float(action[1])
    accel = a_min + (a_n + 1.0) * (a_max - a_min) / 2.0
    steer = -d_max + (s_n + 1.0) * (2.0 * d_max) / 2.0
    return -steer, accel


# ---- lanes ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LaneLayout:
    """The straight lanes parallel to x around the ego, in nudge's frame, right to left.

    ``centres`` [L] and ``bounds`` [L + 1] (y, m, ascending; the first and last bounds are the
    road's edges), ``extents`` [L, 2] (x where each lane begins and ends, m), ``extent_real``
    [L, 2] (bool: the lane begins / ends there, rather than the modelled road), ``speed_limits``
    [L] (m/s, NaN where highway-env gives none). highway-env's lanes of one y (one per road
    segment) are one nudge lane; the layout is the block of side-by-side lanes holding the ego's
    lane (merge-v0's ramp, apart from it, is left out: vehicles on it are still neighbours)."""

    centres: np.ndarray
    bounds: np.ndarray
    extents: np.ndarray
    extent_real: np.ndarray
    speed_limits: np.ndarray

    @staticmethod
    def from_road(road: Any, ego_y: float) -> LaneLayout:
        """Builds the layout from highway-env's ``road.network``; ``ego_y`` is the ego's
        highway-env y (m). HighwayAdapterError when the ego is on no straight lane parallel to x
        or lanes of one y have different widths or gaps between their pieces."""
        pieces: dict[float, list[tuple[float, float, float, float]]] = {}
        for lane in road.network.lanes_list():
            if not isinstance(lane, StraightLane):
                continue
            start, end = np.asarray(lane.start, float), np.asarray(lane.end, float)
            if abs(start[1] - end[1]) > _TOL or end[0] <= start[0]:
                continue
            y = round(float(start[1]), 6)
            limit = float(lane.speed_limit) if lane.speed_limit is not None else math.nan
            pieces.setdefault(y, []).append((float(start[0]), float(end[0]), float(lane.width), limit))
        if not pieces:
            raise HighwayAdapterError("road.network: no straight lane parallel to x")
        ys = sorted(pieces)  # highway-env y ascending = nudge y descending
        rows = []
        for y in ys:
            ps = sorted(pieces[y])
            widths = {p[2] for p in ps}
            if len(widths) != 1:
                raise HighwayAdapterError(f"road.network: lanes at y = {y} m have widths {sorted(widths)}")
            for a, b in zip(ps, ps[1:], strict=False):
                if b[0] > a[1] + _TOL:
                    raise HighwayAdapterError(f"road.network: lanes at y = {y} m have a gap at x = {a[1]}..{b[0]} m")
            limits = [p[3] for p in ps if not math.isnan(p[3])]
            rows.append((y, ps[0][0], max(p[1] for p in ps), widths.pop(), min(limits) if limits else math.nan))
        # The block of side-by-side lanes holding the ego.
        blocks: list[list[tuple[float, float, float, float, float]]] = [[rows[0]]]
        for r in rows[1:]:
            prev = blocks[-1][-1]
            if abs(r[0] - prev[0] - (r[3] + prev[3]) / 2.0) <= _TOL:
                blocks[-1].append(r)
            else:
                blocks.append([r])
        block = next((b for b in blocks if any(abs(ego_y - r[0]) <= r[3] / 2.0 for r in b)), None)
        if block is None:
            raise HighwayAdapterError(f"ego at y = {ego_y} m (highway-env) is on no straight lane parallel to x")
        block = block[::-1]  # nudge order: right to left
        centres = np.array([-r[0] for r in block])
        widths = np.array([r[3] for r in block])
        bounds = np.concatenate([[centres[0] - widths[0] / 2.0], centres + widths / 2.0])
        extents = np.array([[r[1], r[2]] for r in block])
        lo, hi = extents[:, 0].min(), extents[:, 1].max()
        real = np.stack([extents[:, 0] > lo + _TOL, extents[:, 1] < hi - _TOL], axis=1)
        return LaneLayout(centres, bounds, extents, real, np.array([r[4] for r in block]))

    @property
    def n_lanes(self) -> int:
        return len(self.centres)

    @property
    def road(self) -> tuple[float, float]:
        """(right edge, left edge) y (m)."""
        return float(self.bounds[0]), float(self.bounds[-1])

    def nearest_lane(self, y: float) -> int:
        """:meth:`lane_of`, or the lane at the nearer edge for a y beyond the road."""
        lane = self.lane_of(y)
        if lane is None:
            return 0 if y < self.bounds[0] else self.n_lanes - 1
        return lane

    def lane_of(self, y: float) -> int | None:
        """The nudge lane holding nudge y (m), None off the road (a point on a line belongs to
        the lane on its left)."""
        if not self.bounds[0] <= y <= self.bounds[-1]:
            return None
        return int(min(np.searchsorted(self.bounds, y, side="right") - 1, self.n_lanes - 1))

    def from_highway_lane(self, highway_lane_y: float) -> int:
        """nudge lane index of the highway-env lane whose centre line is at highway-env y."""
        j = np.flatnonzero(np.abs(self.centres + highway_lane_y) <= _TOL)
        if len(j) != 1:
            raise HighwayAdapterError(f"no lane of the layout has its centre at highway-env y = {highway_lane_y} m")
        return int(j[0])

    def exists(self, lane: int, x0: float, x1: float) -> bool:
        """Lane ``lane`` is there from x0 to x1 (m)."""
        return bool(self.extents[lane, 0] <= x0 and x1 <= self.extents[lane, 1])


# ---- history ----------------------------------------------------------------------------------


class HistoryBuffer:
    """The last ``length`` positions (nudge frame, m) of each vehicle, ``dt`` s apart.

    :meth:`record` takes every vehicle's state at one time; a vehicle seen for the first time
    (all of them after :meth:`reset`) is padded backwards at constant velocity along its heading
    to ``length`` positions, and a vehicle missing from a record is dropped."""

    def __init__(self, length: int = nudge.T_OBS, dt: float = nudge.DT) -> None:
        self.length = length
        self.dt = dt
        self._pos: dict[int, deque[tuple[float, float]]] = {}
        self._padded: dict[int, int] = {}
        self.time: float | None = None

    def reset(self) -> None:
        self._pos.clear()
        self._padded.clear()
        self.time = None

    def record(self, t: float, states: Mapping[int, np.ndarray]) -> int:
        """Records ``states`` (key -> nudge state [4]: x, y, ψ, v) at time ``t`` (s), which must be
        ``dt`` after the previous record. Returns the number of padded entries it added."""
        if self.time is not None and abs(t - self.time - self.dt) > 1e-6:
            raise HighwayAdapterError(
                f"history: a record at t = {t:.6f} s after one at {self.time:.6f} s; records must be "
                f"{self.dt} s apart (call act() exactly once per env.step)"
            )
        self.time = t
        added = 0
        for key in list(self._pos):
            if key not in states:
                del self._pos[key]
                del self._padded[key]
        for key, s in states.items():
            x, y, psi, v = (float(c) for c in s)
            buf = self._pos.get(key)
            if buf is None:
                buf = deque(maxlen=self.length)
                for k in range(self.length - 1, 0, -1):
                    buf.append((x - k * self.dt * v * math.cos(psi), y - k * self.dt * v * math.sin(psi)))
                self._pos[key] = buf
                self._padded[key] = self.length - 1
                added += self.length - 1
            elif self._padded[key] > 0:
                self._padded[key] -= 1
            buf.append((x, y))
        return added

    def history(self, key: int) -> np.ndarray:
        """[length, 2] positions (m), oldest first; the last is the latest record."""
        return np.array(self._pos[key], dtype=np.float64)

    def padded(self, key: int) -> int:
        """How many of ``history(key)``'s positions are padding, not records."""
        return self._padded[key]

    def __contains__(self, key: int) -> bool:
        return key in self._pos


# ---- the lane rule ----------------------------------------------------------------------------


@dataclass(frozen=True)
class LaneRule:
    """The target-lane rule (module docstring); distances in m, speeds in m/s."""

    look_ahead: float = 80.0
    """m: the nearest vehicle ahead within this sets a lane's speed; a free lane exists this far."""
    advantage: float = 2.0
    """m/s: how much faster an adjacent lane must be."""
    gap_ahead: float = 15.0
    """m: clear bumper-to-bumper gap in front in the adjacent lane."""
    gap_behind: float = 10.0
    """m: clear gap behind, plus ``time_gap`` times the closing speed of a faster follower."""
    time_gap: float = 1.5
    """s: see ``gap_behind``."""
    arrive_tolerance: float = 0.5
    """m: a change is done when the ego's centre is this close to the target's centre line."""
    max_change_steps: int = 20
    """Steps (0.3 s) after which a change not done is given up."""
    settle_steps: int = 10
    """Steps the ego keeps its lane after a change before the rule looks again."""

    def validate(self) -> None:
        for name in ("look_ahead", "advantage", "gap_ahead", "gap_behind", "time_gap", "arrive_tolerance"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise HighwayAdapterError(f"LaneRule.{name} = {v!r}: not a finite number >= 0")
        if not isinstance(self.max_change_steps, int) or self.max_change_steps < 1:
            raise HighwayAdapterError(f"LaneRule.max_change_steps = {self.max_change_steps!r}: not an integer >= 1")
        if not isinstance(self.settle_steps, int) or self.settle_steps < 0:
            raise HighwayAdapterError(f"LaneRule.settle_steps = {self.settle_steps!r}: not an integer >= 0")


# ---- records ----------------------------------------------------------------------------------


@dataclass
class EpisodeStats:
    """What the controller saw and did since its last reset."""

    steps: int = 0
    plan_s: list[float] = field(default_factory=list)
    """Seconds per planning call (the whole of ``act``)."""
    statuses: Counter[str] = field(default_factory=Counter)
    out_of_range: list[tuple[int, str, float]] = field(default_factory=list)
    """(step, "acceleration" | "steering", normalised value) of every action outside [-1, 1]."""
    padded: int = 0
    """History positions padded at constant velocity (vehicles seen fewer than 8 times)."""
    off_road: int = 0
    """Calls at which the ego's centre was beyond a road edge."""
    targets: list[int] = field(default_factory=list)
    """The nudge target lane of each step."""
    actions: list[np.ndarray] = field(default_factory=list)
    """Each step's action as sent ([acceleration, steering] in [-1, 1])."""


@dataclass(frozen=True)
class EpisodeResult:
    """One episode of :func:`run_episode`."""

    seed: int
    steps: int
    crashed: bool
    truncated: bool
    lane_changes: int
    mean_speed: float
    """m/s over the states after each step."""
    ms_per_step: float
    """Wall time per step, planning and simulation (ms)."""
    plan_ms: float
    """Median planning time per step (ms)."""
    out_of_range: int
    off_road: int
    """Steps the ego's centre started beyond a road edge (counted by the controller)."""
    statuses: dict[str, int]


# ---- the controller ---------------------------------------------------------------------------


class NudgeHighwayController:
    """nudge's planner as the controller of ``env``'s ego (one controlled vehicle).

    ``settings``: planner settings (default :func:`planner_settings` for the ego's length; others
    must have ``l_f = l_r = length / 2``); ``predictor``: "teacher", "student", a path, a
    ``nudge.Predictor`` or your own predictor object; ``target_lane``: a highway-env lane id to
    drive to and hold (None: ``lane_rule``); ``v_ref``: desired speed (m/s; None: the lowest
    speed limit of the layout's lanes, at most ``bounds.v_max``); ``max_neighbours``: the nearest
    vehicles within ``settings.safety.check_range`` m the planner sees (at most
    ``nudge.MAX_AGENTS - 1``). The env must be configured with :func:`env_config`
    (:func:`make_env` does it); HighwayAdapterError names the field that differs."""

    def __init__(
        self,
        env: gym.Env,
        settings: nudge.PlannerSettings | None = None,
        predictor: Any = "student",
        *,
        target_lane: int | None = None,
        v_ref: float | None = None,
        lane_rule: LaneRule | None = None,
        max_neighbours: int = 12,
    ) -> None:
        self.env = env
        self.u = env.unwrapped
        self.settings = settings if settings is not None else planner_settings(self._ego_length())
        self.lane_rule = lane_rule if lane_rule is not None else LaneRule()
        self.lane_rule.validate()
        if not isinstance(max_neighbours, int) or not 0 <= max_neighbours <= nudge.MAX_AGENTS - 1:
            raise HighwayAdapterError(f"max_neighbours = {max_neighbours!r}: not an integer in [0, {nudge.MAX_AGENTS - 1}]")
        if v_ref is not None and not (math.isfinite(v_ref) and 0 < v_ref <= self.settings.bounds["v_max"]):
            raise HighwayAdapterError(f"v_ref = {v_ref!r}: not in (0, bounds.v_max = {self.settings.bounds['v_max']}] m/s")
        self.max_neighbours = max_neighbours
        self.fixed_target = target_lane
        self.fixed_v_ref = v_ref
        self._check_env()
        if isinstance(predictor, str):
            predictor = nudge.Predictor.load(nudge.model_path(predictor))
        self.planner = nudge.Planner(self.settings, predictor)
        self.history = HistoryBuffer()
        self.stats = EpisodeStats()
        self.layout: LaneLayout | None = None
        self.last_plan: dict[str, Any] | None = None
        self._keys: dict[int, Any] = {}
        self._last_inputs = (0.0, 0.0)
        self._target: int | None = None
        self._origin: int | None = None
        self._change_steps = 0
        self._settle = 0

    # -- set-up checks
    def _ego_length(self) -> float:
        ego = getattr(self.u, "vehicle", None)
        return float(ego.LENGTH) if ego is not None else 5.0

    def _check_env(self) -> None:
        cfg = self.u.config
        b = self.settings.bounds
        if int(cfg.get("controlled_vehicles", 1)) != 1:
            raise HighwayAdapterError(f"config['controlled_vehicles'] = {cfg['controlled_vehicles']}: the adapter drives one ego")
        at = self.u.action_type
        if not isinstance(at, ContinuousAction):
            raise HighwayAdapterError(f"config['action']['type'] = {cfg['action'].get('type')!r}: needs 'ContinuousAction' (see env_config)")
        want = {
            "acceleration_range": (float(b["a_min"]), float(b["a_max"])),
            "steering_range": (-float(b["delta_max"]), float(b["delta_max"])),
        }
        for name, value in want.items():
            got = tuple(float(v) for v in getattr(at, name))
            if got != value:
                raise HighwayAdapterError(f"config['action'][{name!r}] = {list(got)}: needs {list(value)} (nudge's bounds)")
        for name, value in (("lateral", True), ("longitudinal", True), ("dynamical", False), ("clip", False)):
            if bool(getattr(at, name)) != value:
                raise HighwayAdapterError(f"config['action'][{name!r}] = {getattr(at, name)}: needs {value}")
        sim, pol = float(cfg["simulation_frequency"]), float(cfg["policy_frequency"])
        frames = int(sim // pol)
        if frames < 1 or abs(frames / sim - nudge.DT) > 1e-9:
            raise HighwayAdapterError(
                f"config['simulation_frequency'] = {sim}, config['policy_frequency'] = {pol}: a step is "
                f"{frames} frames of {1 / sim:.4f} s, not {nudge.DT} s (see env_config)"
            )
        model = self.settings.model
        half = self._ego_length() / 2.0
        for name in ("l_f", "l_r"):
            if abs(float(model[name]) - half) > 1e-9:
                raise HighwayAdapterError(
                    f"settings.model.{name} = {model[name]} m: highway-env's bicycle has {half} m (use planner_settings)"
                )

    # -- episode
    def reset(self) -> None:
        """Starts an episode: call right after ``env.reset``."""
        self._check_env()
        ego = self.u.vehicle
        self.layout = LaneLayout.from_road(self.u.road, float(ego.position[1]))
        self.history.reset()
        self.planner.reset()
        self.stats = EpisodeStats()
        self.last_plan = None
        self._keys = {}
        self._last_inputs = (0.0, 0.0)
        self._target = None
        self._origin = None
        self._change_steps = 0
        self._settle = 0

    def states(self) -> dict[int, np.ndarray]:
        """Every vehicle's nudge state [4] (x, y, ψ, v) now, by ``id`` of the highway-env vehicle
        (the ego is ``id(env.unwrapped.vehicle)``)."""
        out = {}
        for v in self.u.road.vehicles:
            x, y, psi = to_nudge(v.position[0], v.position[1], v.heading)
            out[id(v)] = np.array([x, y, psi, float(v.speed)])
            self._keys[id(v)] = v  # keeps the object alive: ids stay unique within the episode
        return out

    def target(self, ego: np.ndarray, others: list[tuple[np.ndarray, float]], v_ref: float) -> tuple[int, int | None]:
        """(target lane, retreat lane or None) in nudge lane indices by the lane rule
        (``others``: (nudge state [4], length m) of the other vehicles)."""
        lay = self.layout
        assert lay is not None
        if self.fixed_target is not None:
            n = lay.n_lanes
            if not 0 <= self.fixed_target < n:
                raise HighwayAdapterError(f"target_lane = {self.fixed_target}: highway-env lanes are 0..{n - 1}")
            return n - 1 - self.fixed_target, None
        cur = lay.nearest_lane(float(ego[1]))
        r = self.lane_rule
        if self._target is not None:
            self._change_steps += 1
            arrived = abs(float(ego[1]) - lay.centres[self._target]) <= r.arrive_tolerance
            if not arrived and self._change_steps < r.max_change_steps:
                return self._target, self._origin
            self._target, self._origin, self._change_steps = None, None, 0
            self._settle = r.settle_steps
        if self._settle > 0:
            self._settle -= 1
            return cur, None
        ego_len = float(self.u.vehicle.LENGTH)

        def lane_speed(lane: int) -> float:
            ahead = [
                (s[0] - ego[0], s[3])
                for s, _ in others
                if lay.lane_of(float(s[1])) == lane and 0.0 < s[0] - ego[0] <= r.look_ahead
            ]
            return min(v_ref, min(ahead)[1]) if ahead else v_ref

        def free(lane: int) -> bool:
            if not lay.exists(lane, float(ego[0]) - r.gap_behind, float(ego[0]) + r.look_ahead):
                return False
            for s, length in others:
                if lay.lane_of(float(s[1])) != lane:
                    continue
                gap = abs(s[0] - ego[0]) - (length + ego_len) / 2.0
                if s[0] >= ego[0]:
                    if gap < r.gap_ahead:
                        return False
                elif gap < r.gap_behind + r.time_gap * max(0.0, s[3] - ego[3]):
                    return False
            return True

        best, best_speed = cur, lane_speed(cur) + r.advantage
        for lane in (cur - 1, cur + 1):  # right first: it wins a tie
            if 0 <= lane < lay.n_lanes and free(lane):
                s = lane_speed(lane)
                if s >= best_speed + (0.0 if best == cur else 1e-9):
                    best, best_speed = lane, s
        if best != cur:
            self._target, self._origin, self._change_steps = best, cur, 0
            return best, cur
        return cur, None

    def act(self) -> np.ndarray:
        """Reads the env, plans and returns the action for ``env.step`` ([acceleration, steering]
        in [-1, 1], float64)."""
        if self.layout is None:
            raise HighwayAdapterError("act() before reset(): call reset() after env.reset()")
        t0 = time.perf_counter()
        ego_v = self.u.vehicle
        states = self.states()
        self.stats.padded += self.history.record(float(self.u.time), states)
        ego_key = id(ego_v)
        ego = states[ego_key]
        rng = float(self.settings.safety["check_range"])
        # Nearest first; a tie goes to the vehicle earlier in road.vehicles (ids differ per process).
        near = sorted(
            (float(np.hypot(*(s[:2] - ego[:2]))), i, k) for i, (k, s) in enumerate(states.items()) if k != ego_key
        )
        keys = [k for d, _, k in near if d <= rng][: self.max_neighbours]
        others = [(states[k], float(self._keys[k].LENGTH)) for k in states if k != ego_key]
        lay = self.layout
        if self.fixed_v_ref is not None:
            v_ref = self.fixed_v_ref
        else:
            limits = lay.speed_limits[~np.isnan(lay.speed_limits)]
            v_ref = float(min(limits.min(), self.settings.bounds["v_max"])) if len(limits) else float(self.settings.bounds["v_max"])
        if lay.lane_of(float(ego[1])) is None:
            self.stats.off_road += 1
        tgt, retreat = self.target(ego, others, v_ref)
        order = [ego_key, *keys]
        hist = np.stack([self.history.history(k) for k in order])
        sizes = np.array([[float(self._keys[k].LENGTH), float(self._keys[k].WIDTH)] for k in order])
        lanes: dict[str, Any] = {}
        if lay.extent_real.any():
            lanes = {"lane_bounds": lay.bounds, "lane_extents": lay.extents, "lane_extent_real": lay.extent_real}
        plan = self.planner.plan(
            hist,
            sizes,
            ego,
            float(lay.centres[tgt]),
            v_ref,
            lay.road,
            last_delta=self._last_inputs[0],
            last_accel=self._last_inputs[1],
            y_retreat=None if retreat is None else float(lay.centres[retreat]),
            **lanes,
        )
        delta, accel = float(plan["delta"][0]), float(plan["accel"][0])
        action = action_from_inputs(delta, accel, self.settings.bounds)
        for name, value in zip(("acceleration", "steering"), action, strict=True):
            if not -1.0 <= value <= 1.0:
                self.stats.out_of_range.append((self.stats.steps, name, float(value)))
        self._last_inputs = (delta, accel)
        self.last_plan = dict(plan, target_lane=tgt, v_ref=v_ref, neighbours=len(keys))
        self.stats.steps += 1
        self.stats.statuses[str(plan["status"])] += 1
        self.stats.targets.append(tgt)
        self.stats.actions.append(action)
        self.stats.plan_s.append(time.perf_counter() - t0)
        return action


def _straight_lane_y(road: Any, lane_index: Any) -> float | None:
    """highway-env y (m) of the centre line of lane ``lane_index`` when it is a straight lane
    parallel to x, else None."""
    lane = road.network.get_lane(lane_index)
    if isinstance(lane, StraightLane) and abs(float(lane.start[1]) - float(lane.end[1])) <= _TOL:
        return float(lane.start[1])
    return None


def run_episode(env: gym.Env, controller: Any, seed: int, max_steps: int | None = None) -> EpisodeResult:
    """One episode from ``env.reset(seed=seed)``, the ego driven by ``controller`` (a
    :class:`NudgeHighwayController`, or any object with ``reset()`` and ``act() -> action``;
    lane changes: changes of highway-env's lane index between straight lanes of different y),
    until the env ends it or ``max_steps``."""
    env.reset(seed=seed)
    controller.reset()
    u = env.unwrapped
    speeds, steps, lane_changes = [], 0, 0
    lane_y = _straight_lane_y(u.road, u.vehicle.lane_index)
    crashed = truncated = False
    t0 = time.perf_counter()
    while max_steps is None or steps < max_steps:
        _, _, terminated, truncated, info = env.step(controller.act())
        steps += 1
        speeds.append(float(u.vehicle.speed))
        now = _straight_lane_y(u.road, u.vehicle.lane_index)
        if now is not None:
            if lane_y is not None and abs(now - lane_y) > _TOL:
                lane_changes += 1
            lane_y = now
        crashed = bool(info.get("crashed", u.vehicle.crashed))
        if terminated or truncated:
            break
    wall = time.perf_counter() - t0
    stats = getattr(controller, "stats", None)
    plan_s = stats.plan_s if stats is not None else []
    return EpisodeResult(
        seed=seed,
        steps=steps,
        crashed=crashed,
        truncated=bool(truncated),
        lane_changes=lane_changes,
        mean_speed=float(np.mean(speeds)) if speeds else math.nan,
        ms_per_step=1000.0 * wall / max(steps, 1),
        plan_ms=1000.0 * float(np.median(plan_s)) if plan_s else math.nan,
        out_of_range=len(stats.out_of_range) if stats is not None else 0,
        off_road=stats.off_road if stats is not None else 0,
        statuses=dict(stats.statuses) if stats is not None else {},
    )
