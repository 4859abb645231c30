"""``nudge-train slow-plans``: what the plans that end slow on a free road brake for.

The closed-loop metrics count plans whose last speed is below ``nudge.SLOW_FRACTION`` (0.3) of the
surrounding traffic's while no vehicle is in the ego's path within two seconds
(``nudge_sim::metrics``, step column ``slow_planned_free``). That test sweeps the boxes
as they are along the road, so it cannot see a vehicle moving across into the ego's lane. This
command reads the runs of a ``closed-loop`` cache, re-simulates every run with such a plan with
``trace=True`` (checking that it reproduces the cached run), and describes each flagged step by
what decided the plan (``decided_by``, recorded with every step) and by
the vehicle the plan's safety binds on (its smallest ``b``) and what that vehicle really did in
the world over the plan's horizon:

* ``enters`` -- its box is outside the ego's lane at the step and reaches into it within the
  horizon (a cut-in that happened);
* ``in_lane`` -- its box already reaches into the ego's lane at the step;
* ``ahead`` -- it stays outside the ego's lane and its centre is ahead of the ego's;
* ``behind`` -- it stays outside the ego's lane and its centre is level with or behind the ego's;
* ``none`` -- the plan's safety binds on no vehicle.

Lanes are the trace's lane bounds (road frame, m); the ego's lane is the one holding its centre.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import nudge

from nudge_train import paths
from nudge_train.errors import ConfigError
from nudge_train.experiments.closed_loop import CACHE_SCHEMA
from nudge_train.jsonio import load_json

__all__ = ["FlaggedRun", "SlowStep", "classify", "flagged_runs", "lane_entry", "run"]

CATEGORIES = ("enters", "in_lane", "ahead", "behind", "none")
"""The categories of a flagged step, in the report's order (see the module docs)."""


@dataclass(frozen=True)
class FlaggedRun:
    """One cached run with at least one plan ending slow on a free road."""

    planner: str
    world: str
    scene: str
    seed: int
    settings: str
    """Planner settings JSON of its arm (as ``nudge.PlannerSettings`` writes it)."""
    config: str
    """Closed-loop settings JSON of its arm."""
    slow_planned_free_steps: int
    success: bool
    decided_by: tuple[str, ...]
    """What decided each step's plan, as the cache recorded it (``decided_by``, step by step)."""


@dataclass(frozen=True)
class SlowStep:
    """One flagged step: the ego, its plan and the vehicle the plan's safety binds on."""

    world: str
    planner: str
    settings: str
    """``default`` for the shipped planner settings, else ``settings`` and a hash of them."""
    scene: str
    seed: int
    step: int
    status: str
    decided_by: str
    """What decided the applied plan (``steps.csv``'s ``decided_by``: ``admm``, ``refined``,
    ``backtracked``, ``fallback:<family>:<rank key>``, ...)."""
    ego_speed: float
    """m/s, at the step."""
    plan_end_speed: float
    """m/s, the plan's last state."""
    slow_below: float
    """m/s: ``nudge.SLOW_FRACTION`` x the surrounding traffic's speed."""
    binding: int
    """Agent index of the vehicle the plan's smallest b is against (0 when none)."""
    binding_b: float
    dx: float
    """m, its centre ahead of the ego's along the road (negative: behind)."""
    dy: float
    """m, its centre to the left of the ego's."""
    speed: float
    """m/s, its observed speed along the road over the last step (NaN at step 0)."""
    toward: float
    """m/s, its observed lateral speed towards the ego's centre (NaN at step 0)."""
    entry_now: float
    """m, how far its box reaches into the ego's lane at the step."""
    entry_max: float
    """m, the most its box reaches into the ego's lane over the step and the plan's horizon."""
    category: str


def lane_entry(y: np.ndarray, half_width: float, lower: float, upper: float) -> np.ndarray:
    """How far (m, >= 0) a box of centres ``y`` ``[n]`` (m) and half width ``half_width`` (m)
    reaches into the lane ``[lower, upper]`` (m) at each of its ``n`` states; NaN where the
    centre is not finite (a logged vehicle past its log)."""
    if not (math.isfinite(lower) and math.isfinite(upper) and lower < upper):
        raise ValueError(f"lane [{lower}, {upper}] is not a finite interval")
    if not (math.isfinite(half_width) and half_width > 0.0):
        raise ValueError(f"half width {half_width} is not a positive finite length")
    y = np.asarray(y, dtype=np.float64)
    reach = np.clip(np.minimum(upper, y + half_width) - np.maximum(lower, y - half_width), 0.0, None)
    return np.where(np.isfinite(y), reach, np.nan)


def classify(entry_now: float, entry_max: float, dx: float) -> str:
    """The category of a flagged step (module docs) from the binding vehicle's reach into the
    ego's lane now and over the horizon (m) and its centre's offset along the road (m)."""
    if not all(math.isfinite(v) for v in (entry_now, entry_max, dx)):
        raise ValueError(f"non-finite geometry: entry now {entry_now}, max {entry_max}, dx {dx}")
    if entry_now > 0.0:
        return "in_lane"
    if entry_max > 0.0:
        return "enters"
    return "ahead" if dx > 0.0 else "behind"


def settings_label(settings: str) -> str:
    """``default`` when the planner settings JSON ``settings`` holds the shipped defaults, else
    ``settings <first 8 hex digits of its SHA-256>``."""
    if settings == nudge.PlannerSettings().to_json():
        return "default"
    return "settings " + hashlib.sha256(settings.encode()).hexdigest()[:8]


MAX_PART_BYTES = 64 << 20
"""Largest cache part read (bytes); a part of 100 runs is about 1 MB."""

_SCENE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]{0,199}")
"""A scene name: a plain file stem (no separator, not ``.``/``..``, no leading dot)."""


def scene_file(scenes: Path, name: object, where: str) -> Path:
    """The scene file of ``name`` in the folder ``scenes``: ``name`` must be a plain scene name
    (letters, digits, ``._-``, no leading dot; so no ``..``, ``/`` or absolute path) and the
    resolved file must lie inside ``scenes``. Raises ConfigError naming ``where`` otherwise."""
    if not isinstance(name, str) or not _SCENE_NAME.fullmatch(name):
        raise ConfigError(where, f"{name!r} is not a scene name (a file stem in the scenes folder)")
    path = scenes / f"{name}.safetensors"
    root = scenes.resolve()
    if root not in path.resolve().parents:
        raise ConfigError(where, f"{name!r} is not a scene name: it resolves outside {scenes}")
    return path


def _column(file: Path, table: dict, section: str, name: str, kind: type, n: int | None) -> list:
    """Column ``name`` of ``section`` (``runs``/``steps``): a list of ``n`` (None: any number of)
    values of ``kind`` (``int``: an integer, not a bool; ``bool``; ``str``)."""
    if name not in table:
        raise ConfigError(file, f"{section}.{name}: missing", key=f"{section}.{name}")
    col = table[name]
    if not isinstance(col, list):
        raise ConfigError(file, f"{section}.{name}: a list expected", key=f"{section}.{name}")
    if n is not None and len(col) != n:
        raise ConfigError(file, f"{section}: columns of different lengths ({section}.{name} has {len(col)}, "
                          f"expected {n}; every column must have the same length)", key=f"{section}.{name}")
    for i, v in enumerate(col):
        ok = (isinstance(v, int) and not isinstance(v, bool)) if kind is int else isinstance(v, kind)
        if not ok:
            what = "an integer" if kind is int else kind.__name__
            raise ConfigError(file, f"{section}.{name}[{i}]: {v!r} is not {what}", key=f"{section}.{name}[{i}]")
    return col


def _read_part(file: Path) -> list[FlaggedRun]:
    """The flagged runs of one cache part, every part of it checked (untrusted input)."""
    data = load_json(file, max_bytes=MAX_PART_BYTES)
    if not isinstance(data, dict):
        raise ConfigError(file, "not a closed-loop cache part (not a JSON object)")
    inputs = data.get("inputs", {})
    if not isinstance(inputs, dict) or inputs.get("schema") != CACHE_SCHEMA:
        schema = inputs.get("schema") if isinstance(inputs, dict) else None
        raise ConfigError(file, f"not a closed-loop cache part (schema {schema!r})", key="inputs.schema")
    for key, kind in (("planner", str), ("world", str), ("settings", dict), ("config", dict)):
        if key not in inputs:
            raise ConfigError(file, f"inputs.{key}: missing", key=f"inputs.{key}")
        if not isinstance(inputs[key], kind):
            raise ConfigError(file, f"inputs.{key}: {type(inputs[key]).__name__}, expected {kind.__name__}",
                              key=f"inputs.{key}")
    try:
        settings = nudge.PlannerSettings.from_json(json.dumps(inputs["settings"])).to_json()
        nudge.SimConfig.from_json(json.dumps(inputs["config"]))
    except (nudge.NudgeError, ValueError) as err:
        raise ConfigError(file, f"inputs.settings/inputs.config: {err}", key="inputs.settings") from None
    runs, steps = data.get("runs"), data.get("steps", {})
    if not isinstance(runs, dict):
        raise ConfigError(file, "runs: a JSON object of columns expected", key="runs")
    if not isinstance(steps, dict):
        raise ConfigError(file, "steps: a JSON object of columns expected", key="steps")
    if "decided_by" not in steps:
        raise ConfigError(file, "the cache part has no decided_by column (written by an older nudge-train; "
                          "rerun closed-loop on it)", key="steps.decided_by")
    flagged = _column(file, runs, "runs", "slow_planned_free_steps", int, None)
    n = len(flagged)
    scenario = _column(file, runs, "runs", "scenario", object, n)
    seed = _column(file, runs, "runs", "seed", int, n)
    success = _column(file, runs, "runs", "success", bool, n)
    step_run = _column(file, steps, "steps", "run", int, None)
    decided_by = _column(file, steps, "steps", "decided_by", str, len(step_run))
    out = []
    for i, count in enumerate(flagged):
        scene_file(Path("."), scenario[i], f"{file}: runs.scenario[{i}]")
        if count > 0:
            decided = tuple(d for j, d in zip(step_run, decided_by, strict=True) if j == i)
            out.append(FlaggedRun(planner=inputs["planner"], world=inputs["world"], scene=scenario[i], seed=seed[i],
                                  settings=settings, config=json.dumps(inputs["config"]),
                                  slow_planned_free_steps=count,
                                  success=success[i], decided_by=decided))
    return out


def flagged_runs(cache: Path) -> list[FlaggedRun]:
    """Every run of the ``closed-loop`` cache ``cache`` (its chunk folders of ``part-*.json``)
    with at least one plan ending slow on a free road, in a fixed order.

    The cache is untrusted input: each part is opened by the checked open (a regular file of at
    most :data:`MAX_PART_BYTES`), a repeated JSON key is refused, and every part it reads is
    checked (the inputs' schema, planner, world, settings and config; the run and step columns:
    lists of one length, integers, booleans, text; scene names plain file stems).

    Raises:
        ConfigError (a ``ValueError``): naming the file and the part (``runs.seed[3]``). (Each
        run is checked again when it is re-simulated, so a cache from another build is refused
        there only if it behaves differently.)
    """
    out = []
    for file in sorted(Path(cache).glob("*/part-*.json")):
        out.extend(_read_part(file))
    return sorted(out, key=lambda r: (r.world, r.planner, r.scene, r.seed, r.settings))


def describe_step(trace: dict, k: int, where: str) -> dict:
    """The ego, its plan and the binding vehicle at step ``k`` of a ``nudge.simulate`` trace
    (``agents`` ``[steps + 1, agents, 3]`` road-frame x, y (m), heading; ``sizes`` ``[agents,
    2]`` length, width (m); ``lane_bounds`` (m, ascending); ``speed`` (m/s); ``plan`` ``[steps,
    T + 1, 4]``; ``binding``, ``binding_b``): the :class:`SlowStep` fields other than the run's
    and the step's own. Raises ``ValueError`` naming ``where`` when the ego's centre is off the
    lanes or the binding vehicle has no position at the step."""
    agents, sizes, bounds = trace["agents"], trace["sizes"], np.asarray(trace["lane_bounds"])
    plan = trace["plan"][k]
    horizon = len(plan) - 1
    ego = agents[k][0]
    lane = int(np.searchsorted(bounds, ego[1])) - 1
    if not 0 <= lane < len(bounds) - 1:
        raise ValueError(f"{where}: the ego's centre y {ego[1]:.2f} m is off the lanes")
    lower, upper = float(bounds[lane]), float(bounds[lane + 1])
    b = int(trace["binding"][k])
    fields = {"ego_speed": float(trace["speed"][k]), "plan_end_speed": float(plan[-1][3]), "binding": b,
              "binding_b": float(trace["binding_b"][k])}
    if b == 0:
        return fields | {"dx": math.nan, "dy": math.nan, "speed": math.nan, "toward": math.nan, "entry_now": 0.0,
                         "entry_max": 0.0, "category": "none"}
    entry = lane_entry(agents[k: k + horizon + 1, b, 1], float(sizes[b][1]) / 2.0, lower, upper)
    if not np.isfinite(entry[0]):
        raise ValueError(f"{where}: the binding vehicle {b} has no position")
    dx = float(agents[k][b][0] - ego[0])
    dy = float(agents[k][b][1] - ego[1])
    if k > 0:
        speed = float((agents[k][b][0] - agents[k - 1][b][0]) / nudge.DT)
        toward = -float((agents[k][b][1] - agents[k - 1][b][1]) / nudge.DT) * math.copysign(1.0, dy)
    else:
        speed = toward = math.nan
    entry_now, entry_max = float(entry[0]), float(np.nanmax(entry))
    return fields | {"dx": dx, "dy": dy, "speed": speed, "toward": toward, "entry_now": entry_now,
                     "entry_max": entry_max, "category": classify(entry_now, entry_max, dx)}


def _steps_of(r: FlaggedRun, scenes: Path) -> list[SlowStep]:
    """Re-simulates ``r`` with its trace and describes its flagged steps; raises ``ValueError``
    when the re-simulation does not reproduce the cached run."""
    scene = scene_file(scenes, r.scene, f"{r.scene!r} ({r.planner} planner, {r.world} world, seed {r.seed})")
    res = nudge.simulate([scene], r.planner, scene_seeds=[r.seed], runs=1, threads=1,
                         settings=nudge.PlannerSettings.from_json(r.settings),
                         config=nudge.SimConfig.from_json(r.config), trace=True)
    runs, steps, t = res["runs"], res["steps"], res["traces"][0]
    got = (int(runs["slow_planned_free_steps"][0]), bool(runs["success"][0]),
           tuple(str(d) for d in steps["decided_by"]))
    if got != (r.slow_planned_free_steps, r.success, r.decided_by):
        raise ValueError(f"{r.scene} seed {r.seed} ({r.planner} planner, {r.world} world): the re-simulation gives "
                         f"{got[:2]} (flagged steps, success), the cache {(r.slow_planned_free_steps, r.success)}"
                         + ("" if got[2] == r.decided_by else "; what decided its plans differs"))
    out = []
    for k in range(len(steps["step"])):
        if steps["slow_planned_free"][k]:
            where = f"{r.scene} seed {r.seed} step {k}"
            out.append(SlowStep(world=r.world, planner=r.planner, settings=settings_label(r.settings), scene=r.scene,
                                seed=r.seed, step=k, status=str(t["status"][k]),
                                decided_by=r.decided_by[k],
                                slow_below=float(steps["traffic_v"][k]) * nudge.SLOW_FRACTION,
                                **describe_step(t, k, where)))
    return out


def report(steps: list[SlowStep], source: str, command: str) -> str:
    """The markdown report: counts per arm and category, then every flagged step."""
    lines = [f"# Plans that end slow on a free road: what they brake for ({source})", "",
             f"Generated by `{command}`. Categories: see `nudge_train.experiments.slow_plans`.", "",
             "| world | planner | settings | flagged steps (runs) | " + " | ".join(CATEGORIES) + " |",
             "|---|---|---|---|" + "---|" * len(CATEGORIES)]
    arms = sorted({(s.world, s.planner, s.settings) for s in steps})
    for arm in arms:
        mine = [s for s in steps if (s.world, s.planner, s.settings) == arm]
        count = Counter(s.category for s in mine)
        runs = len({(s.scene, s.seed) for s in mine})
        lines.append(f"| {' | '.join(arm)} | {len(mine)} ({runs}) | " + " | ".join(str(count[c]) for c in CATEGORIES)
                     + " |")
    if not steps:
        lines.append("| – | – | – | 0 (0) |" + " 0 |" * len(CATEGORIES))
    lines += ["", "What decided the flagged plans (`decided_by`): "
              + (", ".join(f"{k} {v}" for k, v in sorted(Counter(s.decided_by for s in steps).items())) or "–") + "."]
    lines += ["", "| world | planner | settings | scene | seed | step | status | decided by | ego m/s | plan ends m/s | "
              "slow below m/s | binding b | dx m | dy m | its m/s | towards m/s | in ego lane now / max m | category |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in steps:
        lines.append(f"| {s.world} | {s.planner} | {s.settings} | {s.scene} | {s.seed} | {s.step} | {s.status} | "
                     f"{s.decided_by} | "
                     f"{s.ego_speed:.1f} | {s.plan_end_speed:.1f} | {s.slow_below:.1f} | {s.binding_b:.3f} | "
                     f"{s.dx:.1f} | {s.dy:.2f} | "
                     f"{s.speed:.1f} | {s.toward:.2f} | {s.entry_now:.2f} / {s.entry_max:.2f} | {s.category} |")
    return "\n".join(lines) + "\n"


def run(cache: Path, scenes: Path, out: Path | None, json_path: Path | None, command: str, progress: bool) -> int:
    """Describes every flagged step of the cache's runs; writes the report and the JSON rows."""
    flagged = flagged_runs(cache)
    seen = set()
    steps: list[SlowStep] = []
    for i, r in enumerate(flagged):
        key = (r.world, r.planner, r.scene, r.seed, r.settings)
        if key in seen:
            continue
        seen.add(key)
        steps.extend(_steps_of(r, scenes))
        if progress:
            print(f"[{i + 1}/{len(flagged)}] {r.world} {r.planner} {r.scene} seed {r.seed}", flush=True)
    text = report(steps, str(paths.repo_relative(scenes)), command)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
    else:
        print(text)
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps([asdict(s) for s in steps], indent=1) + "\n")
    return 0
