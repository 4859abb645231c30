"""``nudge-train closed-loop``: planners x worlds x seeds on the scenes of a split, paired by
(scene, seed), written to ``docs/results/closed_loop.md``.

Every chosen scene runs ``--seeds`` times (run r of scene i draws its target lane from seed
``scene_seed[i] + r``, the scene seeds drawn with ``--seed``), the same (scene, seed) pairs in
every arm; an arm is one (planner, world, settings). The slow teacher planner runs on a seeded
subset of ``--teacher-n`` scenes. ``--compare A B`` runs every planner x world with two planner
settings files and compares B with A. The metrics are computed in Rust
(``nudge_sim::metrics``); this module only aggregates them:

* per arm: success with a 95 % interval (bootstrap over scenes), collisions at fault / not
  (each one listed and explained), off-road steps, straddle time, slow steps (executed and
  planned), min time to collision, comfort, time to the target with failures counted at the
  budget, progress, the score; per density stratum (terciles of the free gap in the target lane);
* paired differences against a reference arm: McNemar's exact test on success, a paired bootstrap
  on the time to target.

Runs are cached per chunk part under ``runs/closed_loop/`` with a hash of every input (scene
files, seeds, planner, world, settings, closed-loop config, the models, the IDM file and the
compiled extension), verified on resume.
"""

from __future__ import annotations

import hashlib
import json
import math
import shlex
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import nudge
from nudge.distributed import RayConnectError, RayRunError

from nudge_train import paths
from nudge_train.provenance import scene_list_sha256, write_provenance
from nudge_train.experiments.stats import (BOOTSTRAP, cluster_bootstrap, mcnemar_exact, paired_bootstrap, stratum,
                                           terciles)

__all__ = ["Arm", "Chunk", "EvalConfig", "collect", "explain", "report", "run"]

CACHE_SCHEMA = "nudge.closed_loop_cache/1"
STRATA = ("dense", "medium", "sparse")
STEP_KEEP = ("run", "mpc_s", "status", "decided_by", "cost")
"""Step columns kept in the cache (the run columns hold every per-step metric's count)."""

RUN_NEEDED = ("success", "collisions_at_fault", "collisions_not_at_fault", "collisions_at_fault_nuplan",
              "off_road_steps", "straddle_steps", "slow_steps", "slow_planned_steps", "slow_planned_free_steps",
              "min_ttc", "max_abs_jerk", "max_abs_lat_accel", "max_abs_yaw_rate", "comfortable", "progress_ratio",
              "score", "n_steps", "start_overhang", "max_abs_heading", "max_overshoot")
"""Run columns the summary reads; a cached part written without one of them is recomputed."""


@dataclass(frozen=True)
class Arm:
    """One evaluated configuration: a planning predictor in a world with one planner settings."""

    planner: str
    world: str
    settings: str

    def label(self, with_settings: bool) -> str:
        """``planner`` or ``planner [settings]``."""
        return f"{self.planner} [{self.settings}]" if with_settings else self.planner


@dataclass(frozen=True)
class EvalConfig:
    """What to run (the ``nudge-train closed-loop`` arguments)."""

    scenes: Path
    n: int | None = None
    seeds: int = 3
    planners: tuple[str, ...] = ("student", "teacher")
    worlds: tuple[str, ...] = ("teacher", "idm", "log_replay")
    teacher_n: int = 60
    settings: Path | None = None
    config: Path | None = None
    compare: tuple[Path, Path] | None = None
    reference: str | None = None
    seed: int = 0
    threads: int = 2
    batch: int = 30
    cache: Path = field(default_factory=lambda: paths.runs() / "closed_loop")
    bootstrap: int = BOOTSTRAP
    progress: bool = True
    ablate_reaction: bool = False
    """Every settings arm with ``ablate_reaction`` on (the planner's predictor sees the ego's
    keep-lane path instead of each candidate)."""
    ray: str | None = None
    """Compute the parts not in the cache as Ray tasks: ``""`` a local Ray of ``threads`` CPUs
    (or the one this process has initialised), else the address of a cluster; None: no Ray."""
    ray_chunk: int = 8
    """Runs per Ray task."""

    def validate(self) -> None:
        """Raise ValueError naming the first bad argument."""
        if self.n is not None and self.n < 1:
            raise ValueError(f"--n must be >= 1, got {self.n}")
        if self.seeds < 1:
            raise ValueError(f"--seeds must be >= 1, got {self.seeds}")
        if self.teacher_n < 0:
            raise ValueError(f"--teacher-n must be >= 0, got {self.teacher_n}")
        if self.teacher_n == 0 and "teacher" in self.planners:
            raise ValueError("--teacher-n must be >= 1 when the teacher plans (--planners includes teacher)")
        if self.batch < 1 or self.threads < 1:
            raise ValueError("--batch and --threads must be >= 1")
        if self.ray_chunk < 1:
            raise ValueError(f"--ray-chunk must be >= 1, got {self.ray_chunk}")
        for w in self.worlds:
            if w not in ("teacher", "idm", "log_replay"):
                raise ValueError(f"--worlds: unknown world {w!r} (teacher, idm, log_replay)")
        if not self.planners or not self.worlds:
            raise ValueError("--planners and --worlds need at least one entry")
        if self.reference is not None and self.reference not in self.planners:
            raise ValueError(f"--reference {self.reference!r} is not among --planners {list(self.planners)}")
        if self.settings is not None and self.compare is not None:
            raise ValueError("--settings and --compare exclude each other")


@dataclass
class Chunk:
    """The merged results of one arm: run columns, collision rows, kept step columns, the wall
    time of its computation (s) and whether any part was computed now."""

    arm: Arm
    runs: dict[str, list]
    collisions: dict[str, list]
    steps: dict[str, list]
    wall_s: float
    computed_s: float


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _file_sha(path: Path, memo: dict[Path, str]) -> str:
    if path not in memo:
        memo[path] = _sha(path.read_bytes())
    return memo[path]


def _jsonable(table: dict) -> dict[str, list]:
    """numpy columns -> lists (floats keep NaN / inf; json writes them as NaN / Infinity)."""
    out = {}
    for k, v in table.items():
        if isinstance(v, np.ndarray):
            out[k] = v.tolist()
        else:
            out[k] = list(v)
    return out


def _settings_arms(cfg: EvalConfig) -> list[tuple[str, nudge.PlannerSettings]]:
    """(label, settings) of every settings arm (``ablate_reaction`` applied, labelled)."""
    arms = _loaded_settings_arms(cfg)
    if cfg.ablate_reaction:
        arms = [(f"{label}, reaction ablated", s.replace(safety={"ablate_reaction": True})) for label, s in arms]
    return arms


def _loaded_settings_arms(cfg: EvalConfig) -> list[tuple[str, nudge.PlannerSettings]]:
    """(label, settings) of every settings arm as given."""
    def load(p: Path) -> nudge.PlannerSettings:
        return nudge.PlannerSettings.from_json(Path(p).read_text())
    if cfg.compare is not None:
        a, b = cfg.compare
        la, lb = Path(a).stem, Path(b).stem
        if la == lb:
            la, lb = f"A:{la}", f"B:{lb}"
        return [(la, load(a)), (lb, load(b))]
    if cfg.settings is not None:
        return [(Path(cfg.settings).stem, load(cfg.settings))]
    return [("default", nudge.PlannerSettings.default())]


def _sim_config(cfg: EvalConfig) -> nudge.SimConfig:
    return nudge.SimConfig.from_json(Path(cfg.config).read_text()) if cfg.config else nudge.SimConfig.default()


def choose(cfg: EvalConfig) -> tuple[list[Path], list[int], list[int]]:
    """The scenes (sorted file order of a seeded draw of ``n``), their seeds, and the indices of
    the teacher planner's subset."""
    files = sorted(Path(cfg.scenes).glob("*.safetensors"))
    rng = np.random.default_rng([cfg.seed, 1])
    order = rng.permutation(len(files))
    pick = sorted(order[: cfg.n].tolist()) if cfg.n is not None else list(range(len(files)))
    chosen = [files[i] for i in pick]
    scene_seeds = np.random.default_rng([cfg.seed, 2]).integers(0, 2**31, size=len(chosen)).tolist()
    subset = sorted(np.random.default_rng([cfg.seed, 3]).permutation(len(chosen))[: cfg.teacher_n].tolist())
    return chosen, [int(s) for s in scene_seeds], subset


def model_files(planner: str, world: str) -> list[Path]:
    """The files a closed-loop arm depends on: the planning model (a weights file unless
    constant velocity) and the world's model (the teacher, or the IDM driver population)."""
    files = []
    if planner in ("teacher", "student"):
        files.append(nudge.model_path(planner))
    elif planner != "constant_velocity":
        files.append(Path(planner))
    if world == "teacher":
        files.append(nudge.model_path("teacher"))
    if world == "idm":
        files.append(nudge.assets_dir() / "worlds" / "idm.json")
    return files


def _cached_part(file: Path, key: str, n_runs: int, log) -> dict | None:  # noqa: ANN001
    """The cached part at ``file`` when it holds the runs of ``key`` with every needed column,
    else None (saying why when it exists)."""
    if not file.is_file():
        return None
    try:
        data = json.loads(file.read_text())
    except json.JSONDecodeError:
        return None
    if data.get("key") != key or len(data["runs"]["seed"]) != n_runs:
        log(f"  {file}: inputs changed, recomputing")
        return None
    if any(k not in data.get("steps", {}) for k in STEP_KEEP):
        log(f"  {file}: written without the step columns {list(STEP_KEEP)}, recomputing")
        return None
    if any(k not in data.get("runs", {}) for k in RUN_NEEDED):
        log(f"  {file}: written without the run columns {list(RUN_NEEDED)}, recomputing")
        return None
    return data


def _part_data(key: str, inputs: dict, part_inputs: dict, wall_s: float, res: dict) -> dict:
    """A cache part: the simulation result's columns the summary reads, with its inputs."""
    return {"key": key, "inputs": inputs, "part": part_inputs, "wall_s": wall_s,
            "runs": _jsonable(res["runs"]), "collisions": _jsonable(res["collisions"]),
            "steps": {k: _jsonable({k: res["steps"][k]})[k] for k in STEP_KEEP}}


def _write_part(file: Path, data: dict) -> None:
    file.parent.mkdir(parents=True, exist_ok=True)
    tmp = file.with_suffix(".tmp")
    tmp.write_text(json.dumps(data))
    tmp.replace(file)


@dataclass
class _Part:
    """One cached part of an arm: its scenes (indices), key, file and inputs."""

    idx: list[int]
    key: str
    file: Path
    inputs: dict


def collect(cfg: EvalConfig, log=print, command: str | None = None) -> tuple[list[Chunk], dict]:  # noqa: ANN001 (a print-like callable)
    """Runs (or loads from the cache) every arm; returns the chunks and what was run. Every arm's
    cache folder carries a ``provenance.json`` (``docs/records.md``) of the runs it holds,
    rewritten when a part of it is computed (``command``: the command line it names).

    With ``cfg.ray`` set, every part not in the cache is computed at once as Ray tasks of
    ``cfg.ray_chunk`` runs (``nudge.distributed``) before the arms are merged: the same runs,
    tables and cache files as one process computes (the parts' ``wall_s`` is then the sum of
    their tasks' wall times), and each computed arm's provenance names the Ray used."""
    cfg.validate()
    scenes, scene_seeds, subset = choose(cfg)
    if not scenes:
        raise FileNotFoundError(f"no scenario files in {cfg.scenes}")
    sim_cfg = _sim_config(cfg)
    arms = _settings_arms(cfg)
    memo: dict[Path, str] = {}
    scene_sha = [_file_sha(p, memo) for p in scenes]
    native = Path(nudge._native.__file__)
    base = {"schema": CACHE_SCHEMA, "native": _file_sha(native, memo), "seeds": cfg.seeds}
    todo = [(p, w, a) for a in arms for w in cfg.worlds for p in cfg.planners]
    t_start = time.perf_counter()
    # Every arm's parts, and what the cache holds of them.
    plan = []
    for planner, world, (label, settings) in todo:
        idx = subset if planner == "teacher" else list(range(len(scenes)))
        config = sim_cfg.replace(world=world)
        inputs = dict(base, planner=planner, world=world, settings=json.loads(settings.to_json()),
                      config=json.loads(config.to_json()),
                      models={str(paths.repo_relative(f)): _file_sha(f, memo) for f in model_files(planner, world)})
        chunk_key = _sha(json.dumps(inputs, sort_keys=True).encode())
        folder = Path(cfg.cache) / chunk_key[:20]
        parts = []
        for pi, i0 in enumerate(range(0, len(idx), cfg.batch)):
            part = idx[i0: i0 + cfg.batch]
            part_inputs = {"chunk": chunk_key, "scenes": [scenes[i].name for i in part],
                           "scene_sha": [scene_sha[i] for i in part], "scene_seeds": [scene_seeds[i] for i in part]}
            key = _sha(json.dumps(part_inputs, sort_keys=True).encode())
            parts.append(_Part(part, key, folder / f"part-{pi:04d}.json", part_inputs))
        plan.append((Arm(planner, world, label), settings, config, inputs, folder, parts))
    cached = {(ci, pi): _cached_part(p.file, p.key, len(p.idx) * cfg.seeds, log)
              for ci, (*_, parts) in enumerate(plan) for pi, p in enumerate(parts)}
    ray_used = None
    if cfg.ray is not None:
        from nudge import distributed

        missing = [k for k, v in cached.items() if v is None]
        if missing:
            ray_used = distributed.connect(cfg.ray or None, num_cpus=cfg.threads)
            sweeps = []
            for ci, pi in missing:
                arm, settings, config, _, _, parts = plan[ci]
                part = parts[pi]
                sweeps.append(distributed.Sweep(
                    tuple(str(scenes[i]) for i in part.idx), tuple(scene_seeds[i] for i in part.idx), cfg.seeds,
                    {"predictor": arm.planner, "settings": settings.to_json(), "config": config.to_json(),
                     "on_error": "skip"},
                    label=f"{arm.planner} in {arm.world} ({arm.settings}), part {pi + 1}"))
            if cfg.progress:
                log(f"ray ({ray_used}): {len(missing)} parts, {sum(len(s.specs()) for s in sweeps)} runs in tasks of "
                    f"{cfg.ray_chunk}")
            results, walls = distributed.run_sweeps(sweeps, chunk=cfg.ray_chunk, progress=cfg.progress)
            for (ci, pi), res, dt in zip(missing, results, walls, strict=True):
                part = plan[ci][5][pi]
                data = _part_data(part.key, plan[ci][3], part.inputs, dt, res)
                _write_part(part.file, data)
                cached[(ci, pi)] = dict(data, computed=True)
    chunks: list[Chunk] = []
    for ci, (arm, settings, config, inputs, folder, parts) in enumerate(plan):
        planner, world, label = arm.planner, arm.world, arm.settings
        idx = [i for p in parts for i in p.idx]
        merged = {"runs": {}, "collisions": {}, "steps": {}}
        wall = computed = 0.0
        offset = 0
        for pi, part in enumerate(parts):
            data = cached[(ci, pi)]
            if data is None:
                t0 = time.perf_counter()
                res = nudge.simulate([scenes[i] for i in part.idx], planner,
                                     scene_seeds=[scene_seeds[i] for i in part.idx], runs=cfg.seeds,
                                     threads=cfg.threads, settings=settings, config=config, on_error="skip")
                data = _part_data(part.key, inputs, part.inputs, time.perf_counter() - t0, res)
                _write_part(part.file, data)
                computed += data["wall_s"]
            elif data.pop("computed", False):
                computed += data["wall_s"]
            wall += data["wall_s"]
            for table in ("runs", "collisions", "steps"):
                for k, v in data[table].items():
                    if k == "run" and table != "runs":
                        v = [r + offset for r in v]
                    merged[table].setdefault(k, []).extend(v)
            offset += len(data["runs"]["seed"])
            if cfg.progress:
                elapsed = time.perf_counter() - t_start
                log(f"[{ci + 1}/{len(plan)}] {planner} in {world} ({label}): part {pi + 1}/{len(parts)}, "
                    f"{offset} runs, {wall:.0f} s of simulation ({elapsed:.0f} s elapsed)")
        if computed > 0 or not (folder / "provenance.json").is_file():
            files = [(scenes[i], scene_sha[i]) for i in idx]
            write_provenance(folder, {
                "command": command, "settings": inputs["settings"],
                "sim_config": inputs["config"], "predictor": planner, "world": world,
                "models": inputs["models"], "native_sha256": base["native"],
                "scenes": {"count": len(files), "list_sha256": scene_list_sha256([(p.name, h) for p, h in files]),
                           "files": [{"path": paths.repo_relative(p), "sha256": h} for p, h in files]},
                "seeds": {"scene_seeds": [scene_seeds[i] for i in idx], "runs_per_scene": cfg.seeds,
                          "rule": "run r of a scene draws scene_seed + r"},
                "threads": cfg.threads,
                "ray": None if ray_used is None else {"address": ray_used, "runs_per_task": cfg.ray_chunk,
                                                      "task_threads": 1}})
        chunks.append(Chunk(arm, merged["runs"], merged["collisions"], merged["steps"], wall, computed))
    meta = {"scenes": scenes, "scene_seeds": scene_seeds, "subset": subset, "config": sim_cfg,
            "settings_labels": [a[0] for a in arms], "wall_s": time.perf_counter() - t_start}
    return chunks, meta


# ---- aggregation ---------------------------------------------------------------------------------
def _arr(chunk: Chunk, name: str, dtype=np.float64) -> np.ndarray:  # noqa: ANN001
    return np.asarray(chunk.runs[name], dtype=dtype)


def time_to_target(chunk: Chunk, budget_steps: int, column: str = "steps_to_target") -> np.ndarray:
    """Time to the target (s) of every run, failures (-1) counted at the budget."""
    s = _arr(chunk, column)
    return np.where(s >= 0, s, budget_steps) * nudge.DT


def summarise(chunk: Chunk, budget_steps: int, n_boot: int = BOOTSTRAP, overshoot_tol: float = 0.3) -> dict:
    """The report's numbers of one arm (runs that could not run are counted, not averaged);
    ``overshoot_tol`` (m): runs whose centre went farther beyond the target centre are counted."""
    ok = np.array([e is None for e in chunk.runs["error"]])
    scen = np.asarray(chunk.runs["scenario"])[ok]
    f = {k: _arr(chunk, k)[ok] for k in RUN_NEEDED}
    ttt = time_to_target(chunk, budget_steps)[ok]
    ttl = time_to_target(chunk, budget_steps, "steps_to_lane")[ok]
    n = int(ok.sum())
    ttc = f["min_ttc"]
    mpc = np.asarray(chunk.steps.get("mpc_s", []), dtype=np.float64) * 1e3
    cost = np.asarray(chunk.steps.get("cost", []), dtype=np.float64)
    cost = cost[np.isfinite(cost)]
    status, counts = np.unique(np.asarray(chunk.steps.get("status", []), dtype=str), return_counts=True)

    def med(v: np.ndarray) -> float:
        v = v[np.isfinite(v)]
        return float(np.median(v)) if v.size else math.nan

    return {
        "runs": n, "errors": int((~ok).sum()), "scenes": len(set(scen.tolist())),
        "success": cluster_bootstrap(f["success"], scen, n_boot=n_boot) if n else (math.nan,) * 3,
        "at_fault": (int(f["collisions_at_fault"].sum()), int((f["collisions_at_fault"] > 0).sum())),
        "not_at_fault": (int(f["collisions_not_at_fault"].sum()), int((f["collisions_not_at_fault"] > 0).sum())),
        "at_fault_nuplan": (int(f["collisions_at_fault_nuplan"].sum()),
                            int((f["collisions_at_fault_nuplan"] > 0).sum())),
        "off_road": (int(f["off_road_steps"].sum()), int((f["off_road_steps"] > 0).sum())),
        "straddle_s": float(f["straddle_steps"].mean() * nudge.DT) if n else math.nan,
        "slow": (int(f["slow_steps"].sum()), int((f["slow_steps"] > 0).sum())),
        "slow_planned": (int(f["slow_planned_steps"].sum()), int((f["slow_planned_steps"] > 0).sum())),
        "slow_planned_free": (int(f["slow_planned_free_steps"].sum()), int((f["slow_planned_free_steps"] > 0).sum())),
        "min_ttc_median": med(ttc), "ttc_below": int((ttc <= 0.95).sum()),
        "comfortable": float(f["comfortable"].mean()) if n else math.nan,
        "jerk_median": med(f["max_abs_jerk"]), "lat_median": med(f["max_abs_lat_accel"]),
        "yaw_median": med(f["max_abs_yaw_rate"]), "jerk_max": float(np.max(f["max_abs_jerk"], initial=0.0)),
        "lat_max": float(np.max(f["max_abs_lat_accel"], initial=0.0)),
        "yaw_max": float(np.max(f["max_abs_yaw_rate"], initial=0.0)),
        "time_to_target": float(ttt.mean()) if n else math.nan, "time_to_lane": float(ttl.mean()) if n else math.nan,
        "progress_ratio": med(f["progress_ratio"]),
        "heading": (med(f["max_abs_heading"]), float(np.max(f["max_abs_heading"], initial=0.0))),
        "overshoot": (float(np.max(f["max_overshoot"], initial=0.0)), int((f["max_overshoot"] > overshoot_tol).sum())),
        "score": cluster_bootstrap(f["score"], scen, n_boot=n_boot, seed=1) if n else (math.nan,) * 3,
        "mpc_ms": (med(mpc), float(np.percentile(mpc, 90)) if mpc.size else math.nan),
        "status": dict(zip(status.tolist(), counts.tolist(), strict=True)),
        "cost": (med(cost), float(cost.mean()) if cost.size else math.nan),
    }


def _pairs(a: Chunk, b: Chunk) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row indices of the (scene, seed) pairs both arms ran, and their scenes."""
    def index(c: Chunk) -> dict[tuple[str, int], int]:
        return {(s, int(d)): i for i, (s, d, e) in
                enumerate(zip(c.runs["scenario"], c.runs["seed"], c.runs["error"], strict=True)) if e is None}
    ia, ib = index(a), index(b)
    common = sorted(set(ia) & set(ib))
    return (np.array([ia[k] for k in common], dtype=int), np.array([ib[k] for k in common], dtype=int),
            np.array([k[0] for k in common]))


def paired(a: Chunk, b: Chunk, budget_steps: int, n_boot: int = BOOTSTRAP) -> dict:
    """B against A on their common (scene, seed) pairs: success concordance, McNemar's exact
    p-value and the success difference B - A (a fraction) with a paired bootstrap interval over
    scenes; the time to target (failures at the budget) difference B - A with the same interval."""
    ia, ib, scen = _pairs(a, b)
    sa, sb = _arr(a, "success")[ia] > 0, _arr(b, "success")[ib] > 0
    only_a, only_b = int((sa & ~sb).sum()), int((~sa & sb).sum())
    ta, tb = time_to_target(a, budget_steps)[ia], time_to_target(b, budget_steps)[ib]
    return {"pairs": len(ia), "both": int((sa & sb).sum()), "only_a": only_a, "only_b": only_b,
            "neither": int((~sa & ~sb).sum()), "p": mcnemar_exact(only_a, only_b),
            "success": paired_bootstrap(sa, sb, scen, n_boot) if len(ia) else (math.nan,) * 3,
            "ttt": paired_bootstrap(ta, tb, scen, n_boot) if len(ia) else (math.nan,) * 3}


def explain(c: dict, brake_limit: float) -> str:
    """Why one collision row (a dict of the collision columns) is or is not the ego's fault."""
    faster = f" closing at {c['other_v'] - c['ego_v']:.1f} m/s" if c["other_behind"] else ""
    if not c["at_fault"]:
        return (f"hit from behind inside its lane by a vehicle{faster}, the ego at {c['ego_accel']:+.1f} m/s² "
                f"(≥ −{brake_limit:g})")
    why = [f"hit from behind by a vehicle{faster}"] if c["rear_hit"] else []
    if not c["other_behind"]:
        why.append("the other vehicle is ahead (the ego ran into it)" if c["dx"] > 0 else "side by side")
    elif not c["rear_hit"]:
        why.append(f"side contact (|Δy| {abs(c['dy']):.2f} m ≥ half the widths)")
    if not c["ego_in_lane"]:
        why.append("the ego is not inside one lane (straddling or off the road)")
    if c["ego_accel"] < -brake_limit:
        why.append(f"the ego brakes at {c['ego_accel']:+.1f} m/s² (< −{brake_limit:g})")
    return "; ".join(why)


# ---- the report ----------------------------------------------------------------------------------
def _ci(t: tuple[float, float, float], scale: float = 100.0, digits: int = 1) -> str:
    if not np.isfinite(t[0]):
        return "-"
    return f"{scale * t[0]:.{digits}f} [{scale * t[1]:.{digits}f}, {scale * t[2]:.{digits}f}]"


def _f(v: float, digits: int = 2) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


RULES = """\
## How runs are judged

The metrics are computed in Rust from the run's states (`nudge_sim::metrics`, where every
rule is documented) and reach Python and the CLI as the same columns.

- **Success**: the ego settles in the target lane (|y − y_target| ≤ 0.3 m and |ψ| ≤ 0.03 rad for 2
  steps) within the budget of {budget} steps ({budget_s:.1f} s) **and never collides**.
- **Collisions, at fault or not**: a collision is a step at which the ego's box overlaps another
  vehicle's (separating-axis test); an event is the first step of a contact with one vehicle and is
  classified at that step. The ego is **not** at fault only when (a) the other vehicle is behind it
  (centre behind the ego's centre along the road) and hits its rear (lateral offset of the centres
  below half the sum of the widths), (b) the ego is wholly inside one lane (its box spans no lane
  line and is on the road) and (c) its applied acceleration is ≥ −{brake:g} m/s² (`fault_brake_limit`);
  otherwise it is at fault.
- **nuPlan's own rule, beside it** (for comparison with results reported under nuPlan; never used
  for success or the score): every event is also typed as nuplan-devkit's
  `no_ego_at_fault_collisions` types it, in its order: the ego stopped (speed ≤ 0.05 m/s), the other
  stopped, the other behind (its centre more than 150° off the ego's heading seen from the ego's rear
  axle, `l_r` behind its centre), the ego's front edge touching the other's box (front), else lateral;
  the ego is at fault for a front collision, one with a stopped vehicle, and a lateral one unless it
  is wholly inside one lane. Unlike the rule above, nuPlan never blames the ego for a vehicle coming
  from behind, however hard the ego braked, nor for a side contact inside its lane.
- **Off-road steps**: a corner of the ego's box beyond the outermost lane bounds by more than the
  ego's own overhang at the start plus 0.1 m.
- **Straddle time**: steps whose ego box spans a lane line (× 0.3 s).
- **Slow steps in a live lane**: the ego's speed is below 0.3 × the median speed of the other
  vehicles within 50 m along the road in its lane (else in the adjacent lanes) while that median
  exceeds 3 m/s; *executed* (speed after the step) and *planned* (the applied plan's last speed).
  A planned one is **on a free road** when nothing is in the ego's path within 2 s of headway at the
  faster of its speed and the traffic's (the two-second rule): the bumper gap, how far the ego's box
  can move along the road before it touches the nearest box ahead, is at least 2 s × that speed or
  there is no such box. A plan ending slow behind a nearer vehicle answers a queue; one on a free
  road is the standstill in a live lane the planner must never plan.
- **Min TTC**: per step, over the vehicles ahead whose lateral extent overlaps the ego's, bumper gap /
  closing speed along the road; per run the minimum (runs where nobody closed in have none).
- **Comfort**: longitudinal jerk from the applied accelerations, yaw rate and lateral acceleration
  (speed × yaw rate) from the executed states at 0.3 s; a run is comfortable when every value is
  within nuPlan's limits (nuplan-devkit `ego_is_comfortable`: acceleration in [−4.05, 2.40] m/s²,
  |jerk| ≤ 4.13 m/s³, |lateral acceleration| ≤ 4.89 m/s², |yaw rate| ≤ 0.95 rad/s, |yaw
  acceleration| ≤ 1.93 rad/s²).
- **Time to target**: steps until settled, failures counted at the budget; *time to lane*: steps until
  the ego's centre first lies inside the target lane, failures at the budget.
- **Progress**: the ego's progress along the road over the logged ego's at the last step the log
  covers (median over runs).
- **Heading and overshoot**: the largest |ψ| relative to the road over a run (median over runs, and
  the largest); how far the ego's centre went beyond the target lane's centre in the direction of the
  lane change (the largest, and the runs beyond the settling tolerance {settle:g} m).
- **Score** (nuPlan-style, per run in [0, 1]): 0 with an at-fault collision or an off-road step,
  else (5·success + 5·min(1, progress ratio) + 5·[min TTC > 0.95 s] + 4·(1 − slow steps / steps)
  + 2·comfortable) / 21.
- **Density strata**: the free gap in the target lane around the ego at the start (bumper to bumper
  between the nearest target-lane vehicles ahead of and behind the ego's position; a missing one at
  60 m), cut into terciles over the evaluated (scene, seed) pairs: dense ≤ {t1:.1f} m < medium ≤
  {t2:.1f} m < sparse.
- **Intervals**: 95 % percentile intervals from {boot} bootstrap resamples of the scenes (runs of one
  scene are resampled together). **Paired differences** use the (scene, seed) pairs both arms ran:
  McNemar's exact test on success (binomial on the discordant pairs), a paired bootstrap over scenes
  on the time to target.

Worlds: `teacher` (the shipped teacher predicts the others given the ego's plan), `idm` (every other
vehicle keeps its lane and lateral position and follows IDM with a driver drawn per vehicle from the
population fitted to real NGSIM car-following, `assets/worlds/idm.json`; the ego counts as being in
the lane of its centre at the start and enters another lane by the fitted intrusion rule: a follower
counts it once its nearest edge is 0.7 m inside the follower's lane with probability 0.7, otherwise
only once it is wholly inside, and keeps counting it while any part of it is in the lane; see
`nudge_sim::idm` and `docs/results/idm_fit.md`), `log_replay` (the logged future; the others
never react; once a vehicle's log ends it keeps its last displacement along the road and repeats
{decay:g} of its last sideways one per step, `replay_lateral_decay`, fitted to real tracks in
`docs/results/replay_extrapolation.md`; most logs are shorter than a run).
"""


def report(chunks: list[Chunk], meta: dict, cfg: EvalConfig, command: str) -> str:
    """The markdown report."""
    sim_cfg = meta["config"]
    budget = int(sim_cfg.max_steps)
    brake = float(sim_cfg.fault_brake_limit)
    many = len(meta["settings_labels"]) > 1
    # Density strata over the evaluated (scene, seed) pairs (the free gap depends on both).
    gaps: dict[tuple[str, int], float] = {}
    for c in chunks:
        for s, d, g, e in zip(c.runs["scenario"], c.runs["seed"], c.runs["free_gap"], c.runs["error"], strict=True):
            if e is None:
                gaps[(s, int(d))] = float(g)
    cuts = terciles(np.array(list(gaps.values()))) if gaps else (math.nan, math.nan)
    overhang: dict[str, float] = {}
    for c in chunks:
        for s, o, e in zip(c.runs["scenario"], c.runs["start_overhang"], c.runs["error"], strict=True):
            if e is None:
                overhang[s] = float(o)
    over = np.array([o for o in overhang.values() if o > 0])
    n_sc = len(meta["scenes"])
    lines = [
        "# Closed-loop evaluation: planners × worlds × seeds",
        "",
        f"Generated by `{command}`. Split: `{paths.repo_relative(cfg.scenes)}`, {n_sc} scenes × {cfg.seeds} seeds "
        f"(scene seeds drawn with seed {cfg.seed}); the teacher planner on a seeded subset of "
        f"{len(meta['subset'])} of them. Planners: {', '.join(cfg.planners)}; worlds: {', '.join(cfg.worlds)}; "
        f"planner settings: {', '.join(meta['settings_labels'])}. Closed-loop config: "
        f"`{json.dumps(json.loads(sim_cfg.to_json()), sort_keys=True)}` (world set per arm).",
        "",
        f"Wall time: {sum(c.wall_s for c in chunks) / 60:.1f} min of simulation (the sum over the cached chunk "
        f"parts, each measured when it ran, {cfg.threads} runs side by side on a 2-core machine shared with other "
        f"jobs); this invocation {meta['wall_s'] / 60:.1f} min "
        f"({sum(c.computed_s for c in chunks) / 60:.1f} min computed, the rest read from the cache).",
        "",
        f"Egos that start with a corner over the road's edge: {len(over)} of {len(overhang)} scenes"
        + (f" ({int((over >= 0.1).sum())} by 0.1 m or more; overhang {over.min():.3f}–{over.max():.2f} m, median "
           f"{np.median(over):.2f} m); the off-road test allows each ego its own start overhang + 0.1 m."
           if len(over) else "."),
        "",
        "In the `teacher` and `log_replay` worlds a run depends on its seed only through the target lane (both "
        "worlds are deterministic), so seeds of one scene that draw the same lane repeat a run exactly; in the "
        "`idm` world the seed also draws the drivers. The intervals resample scenes, which accounts for runs of "
        "one scene being alike.",
        "",
        "@SUMMARY@",
        RULES.format(budget=budget, budget_s=budget * nudge.DT, brake=brake, t1=cuts[0], t2=cuts[1],
                     boot=cfg.bootstrap, settle=float(sim_cfg.settle_y),
                     decay=float(sim_cfg.replay_lateral_decay)),
        "## Results per world and planner",
        "",
        "| world | planner | runs (scenes) | success % [95 % CI] | collisions at fault: events (runs) | "
        "not at fault | at fault under nuPlan's rule | off-road steps (runs) | straddle s / run | slow steps executed (runs) | planned (runs) | "
        "planned on a free road (runs) | "
        "min TTC median s (runs ≤ 0.95 s) | comfortable % | max jerk / lat acc / yaw rate, median (max) | "
        "max abs heading rad, median (max) | overshoot m, max (runs > tol) | "
        "time to target s | time to lane s | progress vs log | score [95 % CI] | planning ms median (p90) |",
        "|" + "---|" * 22,
    ]
    summaries = {}
    for c in chunks:
        s = summarise(c, budget, cfg.bootstrap, float(sim_cfg.settle_y))
        summaries[c.arm] = s
        err = f" +{s['errors']} failed" if s["errors"] else ""
        lines.append(
            f"| {c.arm.world} | {c.arm.label(many)} | {s['runs']}{err} ({s['scenes']}) | {_ci(s['success'])} | "
            f"{s['at_fault'][0]} ({s['at_fault'][1]}) | {s['not_at_fault'][0]} ({s['not_at_fault'][1]}) | "
            f"{s['at_fault_nuplan'][0]} ({s['at_fault_nuplan'][1]}) | "
            f"{s['off_road'][0]} ({s['off_road'][1]}) | {_f(s['straddle_s'])} | {s['slow'][0]} ({s['slow'][1]}) | "
            f"{s['slow_planned'][0]} ({s['slow_planned'][1]}) | "
            f"{s['slow_planned_free'][0]} ({s['slow_planned_free'][1]}) | {_f(s['min_ttc_median'])} ({s['ttc_below']}) | "
            f"{_f(100 * s['comfortable'], 1)} | {_f(s['jerk_median'], 1)} / {_f(s['lat_median'])} / "
            f"{_f(s['yaw_median'], 3)} ({_f(s['jerk_max'], 1)} / {_f(s['lat_max'])} / {_f(s['yaw_max'], 3)}) | "
            f"{_f(s['heading'][0], 3)} ({_f(s['heading'][1], 3)}) | {_f(s['overshoot'][0])} ({s['overshoot'][1]}) | "
            f"{_f(s['time_to_target'])} | {_f(s['time_to_lane'])} | {_f(s['progress_ratio'], 3)} | "
            f"{_ci(s['score'], 1.0, 3)} | {_f(s['mpc_ms'][0])} ({_f(s['mpc_ms'][1])}) |")
    key = []
    for c in chunks:
        s = summaries[c.arm]
        key.append(f"- **{c.arm.world} world, {c.arm.label(many)}**: success {_ci(s['success'])} %, "
                   f"{s['at_fault'][0]} at-fault and {s['not_at_fault'][0]} not-at-fault collisions "
                   f"({s['at_fault_nuplan'][0]} at fault under nuPlan's rule), "
                   f"off the road in {s['off_road'][1]} of {s['runs']} runs, slow in a live lane in {s['slow'][1]} "
                   f"runs (planned in {s['slow_planned'][1]}, on a free road in {s['slow_planned_free'][1]}), "
                   f"score {s['score'][0]:.3f}.")
    lines[lines.index("@SUMMARY@")] = "## Summary\n\n" + "\n".join(key) + "\n"
    lines += ["", "Planner status per step: " + "; ".join(
        f"{c.arm.world}/{c.arm.label(many)}: " + ", ".join(f"{k} {v}" for k, v in summaries[c.arm]["status"].items())
        for c in chunks), ""]
    lines += ["Planner cost per step (the objective of the applied plan, docs/reference/settings.md; finite steps), "
              "median (mean): " + "; ".join(
                  f"{c.arm.world}/{c.arm.label(many)}: {_f(summaries[c.arm]['cost'][0])} "
                  f"({_f(summaries[c.arm]['cost'][1])})" for c in chunks), ""]
    # Density strata.
    lines += ["## Per density stratum", "",
              f"Free gap in the target lane at the start: dense ≤ {cuts[0]:.1f} m < medium ≤ {cuts[1]:.1f} m < sparse "
              f"(terciles over {len(gaps)} (scene, seed) pairs).", "",
              "| world | planner | stratum | runs | success % [95 % CI] | at-fault collisions (runs) | "
              "not at fault | off-road steps | slow steps | score |", "|" + "---|" * 10]
    for c in chunks:
        ok = np.array([e is None for e in c.runs["error"]])
        strata = stratum(_arr(c, "free_gap"), cuts, STRATA)
        scen = np.asarray(c.runs["scenario"])
        for name in STRATA:
            m = ok & (strata == name)
            if not m.any():
                continue
            succ = cluster_bootstrap(_arr(c, "success")[m], scen[m], n_boot=cfg.bootstrap)
            af = _arr(c, "collisions_at_fault")[m]
            lines.append(
                f"| {c.arm.world} | {c.arm.label(many)} | {name} | {int(m.sum())} | {_ci(succ)} | "
                f"{int(af.sum())} ({int((af > 0).sum())}) | {int(_arr(c, 'collisions_not_at_fault')[m].sum())} | "
                f"{int(_arr(c, 'off_road_steps')[m].sum())} | {int(_arr(c, 'slow_steps')[m].sum())} | "
                f"{_arr(c, 'score')[m].mean():.3f} |")
    # Paired differences.
    lines += ["", "## Paired differences", ""]
    comparisons = []
    if many:
        la, lb = meta["settings_labels"]
        for c in chunks:
            if c.arm.settings == lb:
                ref = next(r for r in chunks if r.arm == Arm(c.arm.planner, c.arm.world, la))
                comparisons.append((ref, c))
        lines.append(f"Reference: settings {la}; B − A on the (scene, seed) pairs both ran.")
    else:
        ref_planner = cfg.reference or cfg.planners[0]
        for c in chunks:
            if c.arm.planner != ref_planner:
                ref = next(r for r in chunks if r.arm == Arm(ref_planner, c.arm.world, c.arm.settings))
                comparisons.append((ref, c))
        lines.append(f"Reference: the {ref_planner} planner in the same world; B − A on the (scene, seed) pairs "
                     "both ran.")
    lines += ["", "| world | A | B | pairs | both succeed | only A | only B | neither | McNemar p (exact) | "
              "success B − A pp [95 % CI] | time to target B − A s [95 % CI] |", "|" + "---|" * 11]
    for a, b in comparisons:
        p = paired(a, b, budget, cfg.bootstrap)
        lines.append(f"| {b.arm.world} | {a.arm.label(many)} | {b.arm.label(many)} | {p['pairs']} | {p['both']} | "
                     f"{p['only_a']} | {p['only_b']} | {p['neither']} | {p['p']:.3g} | "
                     f"{_ci(p['success'], 100.0, 1)} | {_ci(p['ttt'], 1.0, 2)} |")
    if not comparisons:
        lines.append("| - | - | - | - | - | - | - | - | - | - | - |")
    # Every collision, explained.
    lines += ["", "## Every collision", "",
              "dx, dy: the other vehicle's centre minus the ego's (m); ψ: headings (rad); v: speeds (m/s); "
              "a: the ego's applied acceleration (m/s²).", "",
              "| world | planner | scene | seed | step | other (id) | at fault | dx | dy | ψ ego / other | "
              "v ego / other | a | why | nuPlan type (at fault) |", "|" + "---|" * 14]
    any_collision = False
    for c in chunks:
        cols = c.collisions
        for i in range(len(cols.get("run", []))):
            row = {k: v[i] for k, v in cols.items()}
            r = row["run"]
            any_collision = True
            lines.append(
                f"| {c.arm.world} | {c.arm.label(many)} | {c.runs['scenario'][r]} | {c.runs['seed'][r]} | "
                f"{row['step']} | {row['other']} ({row['other_id']}) | {'yes' if row['at_fault'] else 'no'} | "
                f"{row['dx']:+.2f} | {row['dy']:+.2f} | {row['ego_heading']:+.3f} / {row['other_heading']:+.3f} | "
                f"{row['ego_v']:.1f} / {row['other_v']:.1f} | {row['ego_accel']:+.2f} | {explain(row, brake)} | "
                f"{row['nuplan_type']} ({'yes' if row['nuplan_at_fault'] else 'no'}) |")
    if not any_collision:
        lines.append("| - | - | - | - | - | - | - | - | - | - | - | - | no collision | - |")
    return "\n".join(lines) + "\n"


BEFORE_COLUMNS = ("runs", "success % [95 % CI]", "at-fault events (runs)", "not at fault (runs)", "runs off the road",
                  "slow executed (planned; on a free road) runs", "max abs heading rad, median (max)",
                  "overshoot max m (runs > 0.3 m)", "score", "planning ms median (p90)")


def _before_after_cells(s: dict) -> tuple[str, ...]:
    """One arm's summary (as `summarise` returns it, or read back from its JSON) as the cells of
    `BEFORE_COLUMNS`."""
    return (str(s["runs"]), _ci(tuple(s["success"])), f"{s['at_fault'][0]} ({s['at_fault'][1]})",
            f"{s['not_at_fault'][0]} ({s['not_at_fault'][1]})", str(s["off_road"][1]),
            f"{s['slow'][1]} ({s['slow_planned'][1]}; {s['slow_planned_free'][1] if 'slow_planned_free' in s else '-'})",
            f"{s['heading'][0]:.3f} ({s['heading'][1]:.3f})",
            f"{s['overshoot'][0]:.2f} ({s['overshoot'][1]})", f"{s['score'][0]:.3f}",
            f"{s['mpc_ms'][0]:.1f} ({s['mpc_ms'][1]:.1f})")


def before_after(before: dict, after: dict, label: str) -> str:
    """A markdown section comparing the arms of `after` with the same arms (keys
    "world/planner/settings") of `before`, both as written by ``--json``; `label` says what
    "before" is. Arms only one side has are listed as missing."""
    lines = ["## Before and after", "", f"Before: {label}. Same scenes, seeds and arms; each cell before → after.",
             "", "| world | planner | " + " | ".join(BEFORE_COLUMNS) + " |",
             "|---|---|" + "---|" * len(BEFORE_COLUMNS)]
    for key in after:
        world, planner, _ = key.split("/")
        if key not in before:
            lines.append(f"| {world} | {planner} | " + " | ".join(["(no before)"] * len(BEFORE_COLUMNS)) + " |")
            continue
        cells = [f"{b} → **{a}**" if b != a else a
                 for b, a in zip(_before_after_cells(before[key]), _before_after_cells(after[key]), strict=True)]
        lines.append(f"| {world} | {planner} | " + " | ".join(cells) + " |")
    lines += [f"| {k.split('/')[0]} | {k.split('/')[1]} | (before only) |" for k in before if k not in after]
    return "\n".join(lines) + "\n"


def run(cfg: EvalConfig, out: Path | None, json_path: Path | None, command: str,
        before: tuple[Path, str] | None = None) -> int:
    """``nudge-train closed-loop``: collect, print and write the report; with `before` (a JSON
    written by ``--json`` of an earlier run and what it was), a before-and-after section. Returns
    the exit status (2 when the scene folder holds no scenario or an argument is invalid)."""
    try:
        before_data = json.loads(before[0].read_text()) if before is not None else None
        chunks, meta = collect(cfg, log=lambda s: print(s, flush=True), command=command)
    except (ValueError, FileNotFoundError, RayConnectError, RayRunError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    budget = int(meta["config"].max_steps)
    summaries = {f"{c.arm.world}/{c.arm.planner}/{c.arm.settings}": summarise(c, budget, cfg.bootstrap)
                 for c in chunks}
    text = report(chunks, meta, cfg, command)
    if before_data is not None:
        text += "\n" + before_after(before_data, json.loads(json.dumps(summaries)), before[1])
    print(text)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
        print(f"wrote {paths.repo_relative(out)}")
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(summaries, indent=1))
    return 0


def command_line(argv: Sequence[str]) -> str:
    """The command as the report names it (no machine paths)."""
    return "nudge-train closed-loop " + shlex.join(argv)
