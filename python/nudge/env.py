"""Gymnasium environments over nudge's closed loop: real NGSIM scenes, the ``teacher``,
``idm`` and ``log_replay`` worlds, nudge's metrics (docs/env.md).

Importing the module registers ``nudge/LaneChange-v0``::

    import gymnasium as gym
    import nudge.env

    env = gym.make("nudge/LaneChange-v0", world="idm", action_mode="control")
    obs, info = env.reset(seed=0)
    agent = nudge.env.NudgeAgent(env)           # nudge's own planner, through the env
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(agent.act(obs))
        done = terminated or truncated
    print(info["run"]["outcome"], info["run"]["score"])

``gym.make("nudge.env:nudge/LaneChange-v0", ...)`` imports the module itself. The closed loop
is nudge's own (``nudge._native.Session``, the loop ``nudge.simulate`` runs): this module only
turns its observation into the spaces below and the action into the step's inputs.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any

try:
    import gymnasium as gym
    from gymnasium import spaces
except ImportError as e:  # pragma: no cover - exercised in a venv without gymnasium
    raise ImportError(
        "nudge.env needs gymnasium>=1.0, an optional dependency: "
        "pip install 'nudge-planner[env]' (or pip install 'gymnasium>=1.0')"
    ) from e

import numpy as np

import nudge
from nudge._native import InputError
from nudge._native import Session as _Session

__all__ = [
    "ACTION_MODES",
    "ENV_ID",
    "NEIGHBOURS",
    "TIMING_COLUMNS",
    "LaneChangeEnv",
    "NudgeAgent",
    "default_reward",
]

ENV_ID = "nudge/LaneChange-v0"
"""The id registered with Gymnasium on import."""

ACTION_MODES = ("control", "trajectory")
"""``control``: one ``[δ, a]`` pair, held over the horizon; ``trajectory``: ``[T, 2]`` inputs."""

NEIGHBOURS = 8
"""Default number K of nearest other vehicles in the observation."""

TIMING_COLUMNS = ("mpc_s", "z_s", "z_median_s")
"""The wall-time columns of ``steps.csv``: in ``info`` only with ``timings=True`` (they differ
from run to run, so an episode's ``info`` is a function of its seed only without them)."""

END_TERMINAL = ("settled", "lane_ended", "lane_not_begun", "turned_across")
"""End reasons that terminate an episode (the run's own stopping rules); ``max_steps``
truncates it."""


def default_reward(info: Mapping[str, Any]) -> float:
    """The default reward of a step from its ``info``: −1 when the ego's box overlaps another
    vehicle's after the step, −1 when the run ends with the ego in a lane that ended or had
    not begun or turned across the road, +1 when it ends settled in the target lane without
    any collision (a success), 0 otherwise. Pass ``reward_fn`` to the environment for your own.
    """
    r = -1.0 if info["collision"] else 0.0
    end = info.get("end_reason")
    if end in ("lane_ended", "lane_not_begun", "turned_across"):
        r -= 1.0
    elif end == "settled" and info["run"]["success"]:
        r += 1.0
    return r


def _missing_as_none(row: Mapping[str, Any]) -> dict[str, Any]:
    """A records row with its missing values (NaN in the CSV files) as ``None``: ``info`` is
    then equal to itself for the same seed (NaN is not equal to NaN)."""
    return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in row.items()}


def _box(low: Any, high: Any, shape: tuple[int, ...]) -> spaces.Box:
    return spaces.Box(
        low=np.broadcast_to(np.asarray(low, dtype=np.float64), shape).copy(),
        high=np.broadcast_to(np.asarray(high, dtype=np.float64), shape).copy(),
        shape=shape,
        dtype=np.float64,
    )


class LaneChangeEnv(gym.Env):
    """One closed-loop lane change per episode on a real scene, in one of nudge's worlds.

    Args:
        scenes: scenario files (default: the shipped scenes, :func:`nudge.scene_paths`).
        world: ``"teacher"``, ``"idm"`` or ``"log_replay"`` (default: the ``SimConfig``'s).
        predictor: nudge's planning predictor (``"student"``, ``"teacher"``,
            ``"constant_velocity"`` or a weights path): nudge's planner plans with it
            (:meth:`nudge_plan`) and nudge's safety check judges every plan with it.
        action_mode: ``"control"`` or ``"trajectory"`` (docs/env.md).
        neighbours: K, the number of nearest other vehicles observed.
        settings: :class:`nudge.PlannerSettings` (horizon, input bounds, the ego's model).
        config: :class:`nudge.SimConfig` (``max_steps``, stopping rule); ``world`` overrides
            its world.
        world_predictor, idm: the world model of a ``teacher`` / ``idm`` world.
        reward_fn: ``reward_fn(info) -> float`` (default :func:`default_reward`).
        timings: put the wall-time columns (:data:`TIMING_COLUMNS`) in ``info``.
        **config_overrides: any ``SimConfig`` field, e.g. ``max_steps=20``.
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        scenes: Sequence[str | os.PathLike[str]] | None = None,
        world: str | None = None,
        predictor: str | os.PathLike[str] = "student",
        action_mode: str = "control",
        neighbours: int = NEIGHBOURS,
        settings: nudge.PlannerSettings | None = None,
        config: nudge.SimConfig | None = None,
        world_predictor: str | os.PathLike[str] | None = None,
        idm: str | os.PathLike[str] | None = None,
        reward_fn: Callable[[Mapping[str, Any]], float] | None = None,
        timings: bool = False,
        render_mode: str | None = None,
        **config_overrides: Any,
    ) -> None:
        if action_mode not in ACTION_MODES:
            raise InputError(
                f"invalid argument `action_mode`: expected one of {ACTION_MODES}, "
                f"got {action_mode!r}"
            )
        if isinstance(neighbours, bool) or not isinstance(neighbours, int) or neighbours < 0:
            raise InputError(
                f"invalid argument `neighbours`: expected an int >= 0, got {neighbours!r}"
            )
        if render_mode is not None:
            raise InputError(f"invalid argument `render_mode`: none is offered, got {render_mode!r}")
        if world is not None:
            config_overrides["world"] = world
        paths = [os.fspath(p) for p in (scenes if scenes is not None else nudge.scene_paths())]

        self._session = _Session(
            paths,
            os.fspath(predictor),
            world_predictor=None if world_predictor is None else os.fspath(world_predictor),
            idm=None if idm is None else os.fspath(idm),
            settings=settings,
            config=config,
            assets=os.fspath(nudge.assets_dir()),
            **config_overrides,
        )
        self.render_mode = render_mode
        self.timings = bool(timings)
        self.action_mode = action_mode
        self.neighbours = neighbours
        self.reward_fn = reward_fn if reward_fn is not None else default_reward
        sd = self._session.settings.to_dict()
        self.horizon = int(sd["model"]["horizon"])
        self.dt = float(sd["model"]["dt"])
        b = sd["bounds"]
        self.bounds = {"delta_max": b["delta_max"], "a_min": b["a_min"], "a_max": b["a_max"]}
        self.scene_names = list(self._session.scene_names)
        self.world = self._session.config.world
        self.max_lanes = max(self._session.lane_counts)
        lo = [-b["delta_max"], b["a_min"]]
        hi = [b["delta_max"], b["a_max"]]
        if action_mode == "control":
            self.action_space = _box(lo, hi, (2,))
        else:
            self.action_space = _box(lo, hi, (self.horizon, 2))
        k, lanes = neighbours, self.max_lanes
        self.observation_space = spaces.Dict(
            {
                "ego": _box(-np.inf, np.inf, (4,)),
                "last_inputs": _box(lo, hi, (2,)),
                "target": _box(-np.inf, np.inf, (4,)),
                "neighbours": _box(-np.inf, np.inf, (k, 6)),
                "neighbours_mask": spaces.MultiBinary(k),
                "lanes": _box(-np.inf, np.inf, (lanes,)),
                "lanes_mask": spaces.MultiBinary(lanes),
                "road": _box(-np.inf, np.inf, (2,)),
            }
        )
        self._raw: dict[str, Any] | None = None
        self._x0 = 0.0
        self._nudge: dict[str, np.ndarray] | None = None
        self._done = True

    # ---- observation ----------------------------------------------------------------------

    def planner_observation(self) -> dict[str, Any]:
        """The current step's full observation as a Python planner gets it
        (docs/python_planner.md): every agent's history, sizes, lanes, goal, bounds."""
        if self._raw is None:
            raise InputError("no episode in progress: call reset() first")
        return self._raw

    def _observe(self, raw: dict[str, Any]) -> dict[str, np.ndarray]:
        self._raw = raw
        ego = np.asarray(raw["ego"], dtype=np.float64)
        x, y, psi, v = (float(e) for e in ego)
        history = np.asarray(raw["history"], dtype=np.float64)
        sizes = np.asarray(raw["sizes"], dtype=np.float64)
        last = history[1:, -1, :]
        prev = history[1:, -2, :]
        rel = last - np.array([x, y])
        order = np.argsort(np.hypot(rel[:, 0], rel[:, 1]), kind="stable")[: self.neighbours]
        k = self.neighbours
        neighbours = np.zeros((k, 6), dtype=np.float64)
        mask = np.zeros(k, dtype=np.int8)
        for row, j in enumerate(order):
            vel = (last[j] - prev[j]) / self.dt
            neighbours[row] = [rel[j, 0], rel[j, 1], vel[0], vel[1], sizes[j + 1, 0], sizes[j + 1, 1]]
            mask[row] = 1
        centres = np.asarray(raw["lane_centres"], dtype=np.float64)
        lanes = np.zeros(self.max_lanes, dtype=np.float64)
        lanes_mask = np.zeros(self.max_lanes, dtype=np.int8)
        lanes[: len(centres)] = centres - y
        lanes_mask[: len(centres)] = 1
        retreat = raw["y_retreat"]
        road = np.asarray(raw["road"], dtype=np.float64)
        return {
            "ego": np.array([x - self._x0, y, psi, v], dtype=np.float64),
            "last_inputs": np.asarray(raw["last_inputs"], dtype=np.float64).copy(),
            "target": np.array(
                [
                    raw["y_target"] - y,
                    raw["v_ref"],
                    0.0 if retreat is None else retreat - y,
                    0.0 if retreat is None else 1.0,
                ],
                dtype=np.float64,
            ),
            "neighbours": neighbours,
            "neighbours_mask": mask,
            "lanes": lanes,
            "lanes_mask": lanes_mask,
            "road": road - y,
        }

    # ---- Gymnasium API --------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Starts an episode. ``seed`` seeds the environment's generator, which draws the
        scene and the run's target-lane seed; ``options={"scene": index or name,
        "run_seed": int}`` picks either explicitly (the run ``nudge.simulate`` makes of that
        scene with that seed)."""
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"scene", "run_seed"}
        if unknown:
            raise InputError(
                f"reset: unknown option(s) {sorted(unknown)}; expected 'scene', 'run_seed'"
            )
        n = len(self.scene_names)
        scene = options.get("scene")
        if scene is None:
            scene = int(self.np_random.integers(n))
        elif isinstance(scene, str):
            if scene not in self.scene_names:
                raise InputError(f"reset: option 'scene': no scene named {scene!r}")
            scene = self.scene_names.index(scene)
        run_seed = options.get("run_seed")
        if run_seed is None:
            run_seed = int(self.np_random.integers(0, 2**63 - 1))
        raw = self._session.reset(scene, run_seed)
        self._x0 = float(raw["ego"][0])
        self._nudge = None
        self._done = False
        target_lane, y_target = self._session.target()
        info = {
            "scenario": self.scene_names[scene],
            "scene": scene,
            "run_seed": run_seed,
            "target_lane": target_lane,
            "y_target": y_target,
            "world": self.world,
        }
        return self._observe(raw), info

    def _inputs(self, action: Any) -> tuple[list[float], list[float], bool]:
        """The step's inputs (δ over the horizon, a over the horizon) of `action`, whether
        they are nudge's pending plan's; refuses an action outside the action space."""
        a = np.asarray(action)
        shape = self.action_space.shape
        if a.shape != shape:
            raise InputError(f"action: expected shape {shape} ({self.action_mode} mode), got {a.shape}")
        if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
            raise InputError(f"action: expected real numbers, got dtype {a.dtype}")
        a = a.astype(np.float64)
        rows = a.reshape(-1, 2)
        names = ("steering δ (rad)", "acceleration a (m/s²)")
        bounds = (
            (-self.bounds["delta_max"], self.bounds["delta_max"]),
            (self.bounds["a_min"], self.bounds["a_max"]),
        )
        for k, row in enumerate(rows):
            for c in (0, 1):
                val = float(row[c])
                lo, hi = bounds[c]
                where = f"action[{c}]" if self.action_mode == "control" else f"action[{k}, {c}]"
                if not math.isfinite(val):
                    raise InputError(f"{where} ({names[c]}) is not finite ({val})")
                if not lo <= val <= hi:
                    raise InputError(
                        f"{where} ({names[c]}) = {val} is outside [{lo}, {hi}]: actions are "
                        "refused, never clamped (wrap the env in gymnasium.wrappers.ClipAction "
                        "to clip them)"
                    )
        plan = self._nudge
        if plan is not None:
            mine = (
                rows[0].tobytes() == np.array([plan["delta"][0], plan["accel"][0]]).tobytes()
                if self.action_mode == "control"
                else rows.tobytes() == np.stack([plan["delta"], plan["accel"]], axis=1).tobytes()
            )
            if mine:
                return list(map(float, plan["delta"])), list(map(float, plan["accel"])), True
        if self.action_mode == "control":
            return [float(rows[0, 0])] * self.horizon, [float(rows[0, 1])] * self.horizon, False
        return [float(v) for v in rows[:, 0]], [float(v) for v in rows[:, 1]], False

    def step(
        self, action: Any
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """Applies ``action`` for one 0.3 s step (docs/env.md)."""
        if self._done:
            raise InputError("step: the episode has ended (or not begun): call reset() first")
        delta, accel, mine = self._inputs(action)
        self._nudge = None
        row, end, run, collisions = self._session.step(delta, accel)
        info: dict[str, Any] = _missing_as_none(row)
        if not self.timings:
            for k in TIMING_COLUMNS:
                del info[k]
        info["nudge_plan"] = mine
        if end is not None:
            self._done = True
            info["end_reason"] = end
            info["run"] = _missing_as_none(run)
            info["collisions"] = collisions
        obs = self._observe(self._session.observation())
        reward = float(self.reward_fn(info))
        terminated = end in END_TERMINAL
        truncated = end == "max_steps"
        return obs, reward, terminated, truncated, info

    # ---- nudge's own planner ----------------------------------------------------------------

    def nudge_plan(self) -> np.ndarray:
        """nudge's own action for the current step (its planner with the env's planning
        predictor; the same plan ``nudge.simulate`` makes at this step): ``[δ, a]`` in
        ``control`` mode, ``[T, 2]`` in ``trajectory`` mode. Passing it to :meth:`step`
        unchanged applies nudge's whole plan (``info["nudge_plan"]`` is ``True``)."""
        if self._done:
            raise InputError("nudge_plan: the episode has ended (or not begun): call reset() first")
        plan = self._session.nudge_plan()
        self._nudge = {"delta": np.asarray(plan["delta"]), "accel": np.asarray(plan["accel"])}
        if self.action_mode == "control":
            return np.array([plan["delta"][0], plan["accel"][0]], dtype=np.float64)
        return np.stack([plan["delta"], plan["accel"]], axis=1).astype(np.float64)


class NudgeAgent:
    """nudge's planner as an agent of a :class:`LaneChangeEnv` (or a wrapper of one):
    ``agent.act(obs)`` is the env's :meth:`LaneChangeEnv.nudge_plan` for the current step."""

    def __init__(self, env: gym.Env) -> None:
        base = env.unwrapped
        if not isinstance(base, LaneChangeEnv):
            raise InputError(f"NudgeAgent: expected a nudge LaneChangeEnv, got {type(base).__name__}")
        self.env = base

    def act(self, observation: Any = None) -> np.ndarray:
        """The action nudge takes now (``observation`` is not needed: the env holds the
        full state)."""
        return self.env.nudge_plan()


gym.register(id=ENV_ID, entry_point="nudge.env:LaneChangeEnv", disable_env_checker=False)
