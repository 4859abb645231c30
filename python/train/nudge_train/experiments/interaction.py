"""``nudge-train interaction``: does the predicted reaction pay? Each planner against the same
model with its reaction ablated, on dense scenes, written to ``docs/results/interaction.md``.

* **Dense scenes** (:func:`blocked`, :func:`dense_runs`): the target lane is blocked at the
  start: a vehicle whose centre lies in the target lane (between its lane bounds) at the last
  observed step overlaps the ego's longitudinal extent widened by ``margin`` metres at each end
  (|x_other − x_ego| < (L_ego + L_other) / 2 + margin). The target lane is drawn from the run's
  seed (``Scenario.target_lane``); a scene qualifies when ``seeds`` of its seeds
  ``scene_seed + r`` (r < :data:`SEED_TRIES`) draw a blocked lane, and those seeds are its runs.
* **Arms**: planners ``teacher``, ``student`` (shipped) and optionally a candidate student
  (weights file), each *aware* (default settings) and *ablated* (``ablate_reaction``: the
  planner's predictor sees the ego's keep-lane path instead of each candidate); the
  ``constant_velocity`` planner as a third baseline (its prediction never depends on the ego, so
  its ablation would be the same planner). Worlds: ``idm`` and ``teacher`` (reactive), and
  ``log_replay`` (not reactive; reported for at-fault collisions).
* **Pairs**: every arm runs the same (scene, seed) runs; a seed fixes the target lane, so pairs
  are (scene, seed, target lane), checked. Main metric: time to reach the target lane (the ego's
  centre first inside it) with failures counted at the step budget; also success (settled in the
  target lane without any collision), time to target (settled), collisions at fault or not.
  Intervals: bootstrap over scenes (:mod:`nudge_train.experiments.stats`), McNemar's exact test
  on paired success.
* **Sizes**: ``n`` dense scenes per split (one count or one per split) for every arm, the aware
  teacher planner (about 10x slower) on a seeded subset of ``teacher_n`` of them (its ablated arm runs on all ``n``; the
  aware-vs-ablated comparison uses the common pairs).
* **Merge scenes** (``scenes="merge"``, :func:`is_merge`, :func:`merge_runs`): instead of dense
  scenes, the scenes whose ego is in a lane that really ends ahead of it (an acceleration or
  auxiliary lane); the target lane is then the adjacent lane that outlasts the ego's (the
  simulator's draw never offers a lane ending within reach), and every scene's runs are its first
  ``seeds`` seeds. The report counts how many of these runs start with the target lane blocked.

Runs are cached per part under ``runs/interaction/`` with a hash of every input (scene files,
seeds, planner, settings, closed-loop config, models, the IDM file, the compiled extension) and
reused on resume. The report keeps whatever is written below its ``<!-- notes -->`` marker.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import shlex
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

import nudge

from nudge_train import paths
from nudge_train.experiments.closed_loop import model_files
from nudge_train.experiments.stats import BOOTSTRAP, cluster_bootstrap, mcnemar_exact, paired_bootstrap

__all__ = ["Arm", "InteractionConfig", "blocked", "dense_runs", "is_merge", "merge_runs", "paired", "run",
           "start_geometry", "start_reactions", "verdict"]

CACHE_SCHEMA = "nudge.interaction_cache/1"
SEED_TRIES = 32
"""Seeds ``scene_seed + r``, r < SEED_TRIES, tried per scene for a blocked target lane."""
WORLDS = ("idm", "teacher", "log_replay")
SCENE_KINDS = ("dense", "merge")
"""The scene sets of the experiment: dense scenes (a blocked target lane) or merges (a lane that ends)."""
REACTIVE = ("idm", "teacher")
CANDIDATE = "student_react"
"""Label of the candidate student's arms."""
MARKER = "<!-- notes -->"
TARGET_PP = 10.0
"""Success gain (percentage points) the issue asks of the aware planner, interval above 0."""
TARGET_S = 0.5
"""Time-to-lane gain (s) the issue asks of the aware planner, interval below 0."""
DEFAULT_HORIZON = int(nudge.PlannerSettings.default().model["horizon"])
"""The planner's default horizon (steps): the shipped student's."""


@dataclass(frozen=True)
class Arm:
    """One evaluated configuration: a planner (label), aware or ablated, in a world."""

    planner: str
    ablated: bool
    world: str

    @property
    def label(self) -> str:
        """``planner`` or ``planner (ablated)``."""
        return f"{self.planner} (ablated)" if self.ablated else self.planner


@dataclass(frozen=True)
class InteractionConfig:
    """What to run (the ``nudge-train interaction`` arguments)."""

    splits: tuple[str, ...] = ("val", "test")
    n: tuple[int, ...] = (30, 60)
    """Dense scenes drawn per split: one value for every split or one per split."""
    teacher_n: tuple[int, ...] = (15, 30)
    """Of these, the aware teacher planner's scenes: one value or one per split."""
    seeds: int = 3
    margin: float = 2.0
    scenes: str = "dense"
    """Which scenes: ``dense`` (the target lane blocked at the start) or ``merge`` (the ego's lane
    really ends ahead of it)."""
    candidate: Path | None = None
    settings: Path | None = None
    """Planner settings JSON of every arm (missing fields default; ``ablate_reaction`` is set per
    arm); ``None``: the defaults."""
    worlds: tuple[str, ...] = WORLDS
    seed: int = 0
    threads: int = 2
    batch: int = 10
    cache: Path = field(default_factory=lambda: paths.runs() / "interaction")
    bootstrap: int = BOOTSTRAP
    progress: bool = True
    animate: bool = True
    horizon: int = DEFAULT_HORIZON
    """Planning and prediction horizon (steps of 0.3 s) of every arm."""
    compare_horizon: int | None = None
    """When set, every arm also runs at this horizon on the same runs, and the report pairs them."""

    def validate(self) -> None:
        """Raise ValueError naming the first bad argument."""
        for name in ("horizon", "compare_horizon"):
            h = getattr(self, name)
            if h is not None:
                try:
                    nudge.PlannerSettings(model={"horizon": h})
                except nudge.NudgeError as err:
                    raise ValueError(f"--{name.replace('_', '-')}: {err}") from None
        for name in ("seeds", "threads", "batch"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        for name in ("n", "teacher_n"):
            values = getattr(self, name)
            if len(values) not in (1, len(self.splits)) or min(values) < 1:
                raise ValueError(f"--{name.replace('_', '-')}: one count >= 1 or one per split, got {list(values)}")
        if self.scenes not in SCENE_KINDS:
            raise ValueError(f"--scenes: unknown scene set {self.scenes!r} ({', '.join(SCENE_KINDS)})")
        if self.seeds > SEED_TRIES:
            raise ValueError(f"--seeds must be <= {SEED_TRIES}, got {self.seeds}")
        if not (math.isfinite(self.margin) and self.margin >= 0.0):
            raise ValueError(f"--margin must be a finite number >= 0, got {self.margin}")
        for w in self.worlds:
            if w not in WORLDS:
                raise ValueError(f"--worlds: unknown world {w!r} ({', '.join(WORLDS)})")
        for s in self.splits:
            if s not in ("train", "val", "test"):
                raise ValueError(f"--splits: unknown split {s!r} (train, val, test)")
        if self.candidate is not None and not Path(self.candidate).is_file():
            raise ValueError(f"--candidate {self.candidate}: no such file")
        if self.settings is not None:
            if not Path(self.settings).is_file():
                raise ValueError(f"--settings {self.settings}: no such file")
            self.base_settings()

    def base_settings(self) -> nudge.PlannerSettings:
        """The planner settings every arm starts from (``--settings``, else the defaults)."""
        if self.settings is None:
            return nudge.PlannerSettings.default()
        try:
            return nudge.PlannerSettings.from_json(Path(self.settings).read_text())
        except Exception as err:  # the settings error names the field
            raise ValueError(f"--settings {self.settings}: {err}") from err

    def sizes(self, split: str) -> tuple[int, int]:
        """(scenes drawn, aware-teacher scenes) of ``split``."""
        i = self.splits.index(split)
        return (self.n[i if len(self.n) > 1 else 0], self.teacher_n[i if len(self.teacher_n) > 1 else 0])

    def planners(self) -> list[tuple[str, str]]:
        """(label, predictor) of every planner with an ablated arm (constant velocity runs besides):
        those whose model predicts ``horizon`` steps (and ``compare_horizon``, when set); a student
        decodes a fixed 6 steps, so a longer horizon leaves the teacher."""
        out = [("teacher", "teacher"), ("student", "student")]
        if self.candidate is not None:
            out.append((CANDIDATE, str(self.candidate)))
        horizons = [h for h in (self.horizon, self.compare_horizon) if h is not None]
        return [(label, p) for label, p in out if all(serves(p, h) for h in horizons)]

    def arm_settings(self, ablated: bool, horizon: int | None = None) -> nudge.PlannerSettings:
        """The planner settings of an arm: the base settings (``--settings``, else the defaults) at
        ``horizon`` (default: ``self.horizon``, which overrides a horizon in the file),
        ``ablate_reaction`` as given."""
        return self.base_settings().replace(safety={"ablate_reaction": ablated}, model={"horizon": self.horizon if horizon is None else horizon})


def load_predictor(predictor: str, horizon: int) -> nudge.Predictor:
    """The model ``predictor`` (``teacher``, ``student`` or a weights file) for ``horizon`` steps;
    raises ``nudge.InputError`` when it cannot predict that horizon (a student's fixed decoder)."""
    path = nudge.model_path(predictor) if predictor in ("teacher", "student") else predictor
    return nudge.Predictor.load(path, horizon=horizon)


def serves(predictor: str, horizon: int) -> bool:
    """Whether the model ``predictor`` predicts ``horizon`` steps (the typed refusal, not a guess)."""
    try:
        load_predictor(predictor, horizon)
    except nudge.InputError:
        return False
    return True


# ---- dense scenes ------------------------------------------------------------------------------
def blocked(scene: nudge.Scenario, lane: int, margin: float) -> bool:
    """Whether lane ``lane`` of ``scene`` is blocked at the start: some other vehicle's centre at
    the last observed step lies in the lane (``lane_bounds[lane] <= y < lane_bounds[lane + 1]``,
    m) and its longitudinal extent overlaps the ego's widened by ``margin`` (m) at each end:
    ``|x - x_ego| < (L_ego + L) / 2 + margin`` (lengths from ``size[:, 0]``)."""
    pos = scene.history[:, -1, :]
    length = scene.size[:, 0]
    lo, hi = sorted((float(scene.lane_bounds[lane]), float(scene.lane_bounds[lane + 1])))
    others = pos[1:]
    in_lane = (others[:, 1] >= lo) & (others[:, 1] < hi)
    overlap = np.abs(others[:, 0] - pos[0, 0]) < (length[0] + length[1:]) / 2.0 + margin
    return bool(np.any(in_lane & overlap))


def dense_runs(files: Sequence[Path], seeds: int, margin: float, seed: int) -> list[tuple[Path, list[int]]]:
    """The dense scenes among ``files`` (sorted order) with their run seeds: scene i's base seed
    is drawn with ``seed`` (as ``nudge-train closed-loop`` draws scene seeds); its runs are the
    first ``seeds`` of ``base + r`` (r < :data:`SEED_TRIES`) whose target lane is blocked."""
    bases = np.random.default_rng([seed, 2]).integers(0, 2**31, size=len(files)).tolist()
    out = []
    for path, base in zip(files, bases, strict=True):
        sc = nudge.Scenario.load(path)
        found = [int(base) + r for r in range(SEED_TRIES) if blocked(sc, sc.target_lane(int(base) + r), margin)]
        if len(found) >= seeds:
            out.append((path, found[:seeds]))
    return out


def is_merge(scene: nudge.Scenario) -> bool:
    """Whether the ego, at its last observed step, is in a lane that really ends ahead of it
    (``lane_extent_real[ego_lane, 1]`` and its x <= ``lane_extents[ego_lane, 1]``, m): an
    acceleration or auxiliary lane that ends inside the scene. False for a scene without lane
    extents (its lanes run through)."""
    real = scene.lane_extent_real
    if real is None:
        return False
    lane = scene.ego_lane
    return bool(real[lane][1]) and float(scene.history[0, -1, 0]) <= float(scene.lane_extents[lane][1])


def merge_runs(files: Sequence[Path], seeds: int, seed: int) -> list[tuple[Path, list[int]]]:
    """The merge scenes among ``files`` (sorted order, :func:`is_merge`) with their run seeds: scene
    i's base seed is drawn with ``seed`` as in :func:`dense_runs`, its runs are ``base + r`` for
    r < ``seeds``. The target lane each seed draws is the adjacent lane that outlasts the ego's."""
    bases = np.random.default_rng([seed, 2]).integers(0, 2**31, size=len(files)).tolist()
    out = []
    for path, base in zip(files, bases, strict=True):
        if is_merge(nudge.Scenario.load(path)):
            out.append((path, [int(base) + r for r in range(seeds)]))
    return out


def blocked_share(runs: list[tuple[Path, list[int]]], margin: float) -> tuple[int, int]:
    """(runs whose target lane is blocked at the start (:func:`blocked`), runs)."""
    hit = total = 0
    for path, seeds in runs:
        sc = nudge.Scenario.load(path)
        for s in seeds:
            hit += blocked(sc, sc.target_lane(s), margin)
            total += 1
    return hit, total


def _draw(items: list, n: int, seed: int, salt: int) -> list[int]:
    """Indices of a seeded draw of ``n`` of ``items``, in their order."""
    order = np.random.default_rng([seed, salt]).permutation(len(items))
    return sorted(order[:n].tolist())


# ---- running -----------------------------------------------------------------------------------
def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class _Hasher:
    """File hashes, each computed once."""

    def __init__(self) -> None:
        self.memo: dict[Path, str] = {}

    def __call__(self, path: Path) -> str:
        path = Path(path)
        if path not in self.memo:
            self.memo[path] = _sha(path.read_bytes())
        return self.memo[path]


def _columns(res: dict) -> dict[str, list]:
    keep = ("scenario", "seed", "target_lane", "success", "steps_to_lane", "steps_to_target", "collisions_at_fault",
            "collisions_not_at_fault", "aborts", "n_steps", "free_gap", "error")
    out = {}
    for k in keep:
        v = res["runs"][k]
        out[k] = v.tolist() if isinstance(v, np.ndarray) else list(v)
    status = res["steps"]["status"]
    run = res["steps"]["run"].tolist()
    out["unsafe_steps"] = [0] * len(out["seed"])
    for r, st in zip(run, status, strict=True):
        if st in ("Unsafe", "Fallback", "SolverFailed"):
            out["unsafe_steps"][r] += 1
    return out


def _run_arm(arm: Arm, predictor: str, runs: list[tuple[Path, list[int]]], cfg: InteractionConfig, split: str,
             hasher: _Hasher, bar: tqdm) -> tuple[dict[str, list], float, float]:
    """The runs of one arm (cached per part): its columns, the wall time of its parts (s, as
    measured when each ran) and the time computed now (s)."""
    settings = cfg.arm_settings(arm.ablated)
    config = nudge.SimConfig(world=arm.world)
    inputs = {"schema": CACHE_SCHEMA, "native": hasher(Path(nudge._native.__file__)), "predictor": predictor,
              "settings": json.loads(settings.to_json()), "config": json.loads(config.to_json()),
              "models": {str(paths.repo_relative(f)): hasher(f) for f in model_files(predictor, arm.world)}}
    folder = Path(cfg.cache) / split / _sha(json.dumps(inputs, sort_keys=True).encode())[:20]
    merged: dict[str, list] = {}
    wall = computed = 0.0
    for start in range(0, len(runs), cfg.batch):
        part = runs[start: start + cfg.batch]
        files = [p for p, s in part for _ in s]
        seeds = [x for _, s in part for x in s]
        key = _sha(json.dumps({"inputs": inputs, "scenes": [p.name for p in files],
                               "scene_sha": [hasher(p) for p in files], "seeds": seeds}, sort_keys=True).encode())
        file = folder / f"{key[:20]}.json"
        data = None
        if file.is_file():
            try:
                data = json.loads(file.read_text())
            except json.JSONDecodeError:
                data = None
            if data is not None and data.get("key") != key:
                data = None
        if data is None:
            t0 = time.perf_counter()
            res = nudge.simulate(files, predictor, scene_seeds=seeds, runs=1, threads=cfg.threads, settings=settings,
                                 config=config, on_error="skip")
            dt = time.perf_counter() - t0
            data = {"key": key, "wall_s": dt, "runs": _columns(res)}
            folder.mkdir(parents=True, exist_ok=True)
            tmp = file.with_suffix(".tmp")
            tmp.write_text(json.dumps(data))
            tmp.replace(file)
            computed += dt
        wall += data["wall_s"]
        for k, v in data["runs"].items():
            merged.setdefault(k, []).extend(v)
        bar.update(len(seeds))
    return merged, wall, computed


def collect(cfg: InteractionConfig, split: str, log=print) -> dict:  # noqa: ANN001 (a print-like callable)
    """Selects the dense (or merge) scenes of ``split`` and runs (or loads) every arm on them."""
    files = sorted(paths.scenes(split).glob("*.safetensors"))
    if not files:
        raise FileNotFoundError(f"no scenario files in {paths.scenes(split)}")
    t0 = time.perf_counter()
    if cfg.scenes == "merge":
        dense = merge_runs(files, cfg.seeds, cfg.seed)
    else:
        dense = dense_runs(files, cfg.seeds, cfg.margin, cfg.seed)
    if not dense:
        raise FileNotFoundError(f"no {cfg.scenes} scenes in {paths.scenes(split)}")
    n, teacher_n = cfg.sizes(split)
    chosen = [dense[i] for i in _draw(dense, n, cfg.seed, 1)]
    teacher_runs = [chosen[i] for i in _draw(chosen, teacher_n, cfg.seed, 3)]
    log(f"{split}: {len(dense)} {cfg.scenes} scenes of {len(files)} ({time.perf_counter() - t0:.0f} s); "
        f"{len(chosen)} drawn, the aware teacher planner on {len(teacher_runs)}")
    todo = []
    for world in cfg.worlds:
        for label, predictor in cfg.planners():
            for ablated in (False, True):
                runs = teacher_runs if (label == "teacher" and not ablated) else chosen
                todo.append((Arm(label, ablated, world), predictor, runs))
        todo.append((Arm("constant_velocity", False, world), "constant_velocity", chosen))
    hasher = _Hasher()
    total = sum(len(r) * cfg.seeds for _, _, r in todo)
    arms = {}
    with tqdm(total=total, desc=f"interaction {split}", unit="run", disable=not cfg.progress) as bar:
        for arm, predictor, runs in todo:
            bar.set_postfix_str(f"{arm.label} in {arm.world}")
            arms[arm] = _run_arm(arm, predictor, runs, cfg, split, hasher, bar)
    return {"split": split, "n_files": len(files), "dense": dense, "chosen": chosen, "teacher_runs": teacher_runs,
            "blocked": blocked_share(chosen, cfg.margin), "arms": arms, "wall_s": time.perf_counter() - t0}


# ---- statistics ----------------------------------------------------------------------------------
def _time(cols: dict[str, list], column: str, budget: int) -> np.ndarray:
    """Time (s) from the step counts of ``column``, failures (-1) at the budget."""
    s = np.asarray(cols[column], dtype=np.float64)
    return np.where(s >= 0, s, budget) * nudge.DT


def _ok(cols: dict[str, list]) -> np.ndarray:
    return np.array([e is None for e in cols["error"]], dtype=bool)


def vehicle_of(scenario: str) -> str:
    """The ego vehicle of a scenario name, its start time dropped:
    ``us101-23_1-t06.6-ego90`` -> ``us101-23_1-ego90`` (names without a ``-t<seconds>`` part are
    their own vehicle)."""
    return re.sub(r"-t\d+(?:\.\d+)?-", "-", scenario, count=1)


def _no_interval(t: tuple[float, float, float], clusters: int) -> tuple[float, float, float]:
    """``t`` (estimate, low, high) with the bounds NaN when fewer than 2 clusters were resampled:
    a bootstrap over one cluster has no spread to show."""
    return t if clusters >= 2 else (t[0], math.nan, math.nan)


def _clusters(names: np.ndarray, by_vehicle: bool) -> np.ndarray:
    """The bootstrap's cluster of each run: its scene, or its ego vehicle when ``by_vehicle``."""
    return np.array([vehicle_of(str(n)) for n in names]) if by_vehicle else names


def summarise(cols: dict[str, list], budget: int, n_boot: int, by_vehicle: bool = False) -> dict:
    """Success, time to lane and to target (failures at the budget), collisions of one arm; the
    intervals resample scenes, or ego vehicles when ``by_vehicle``."""
    ok = _ok(cols)
    scen = _clusters(np.asarray(cols["scenario"])[ok], by_vehicle)
    succ = np.asarray(cols["success"], dtype=np.float64)[ok]
    ttl = _time(cols, "steps_to_lane", budget)[ok]
    ttt = _time(cols, "steps_to_target", budget)[ok]
    fault = np.asarray(cols["collisions_at_fault"], dtype=np.int64)[ok]
    not_fault = np.asarray(cols["collisions_not_at_fault"], dtype=np.int64)[ok]
    reached = np.asarray(cols["steps_to_lane"], dtype=np.int64)[ok] >= 0
    k = len(set(scen.tolist()))
    return {"runs": int(ok.sum()), "errors": int((~ok).sum()),
            "scenes": len(set(np.asarray(cols["scenario"])[ok].tolist())), "clusters": k,
            "success": _no_interval(cluster_bootstrap(succ, scen, n_boot=n_boot), k),
            "reached": float(reached.mean()) if reached.size else math.nan,
            "ttl": _no_interval(cluster_bootstrap(ttl, scen, n_boot=n_boot, seed=1), k),
            "ttt": float(ttt.mean()) if ttt.size else math.nan,
            "at_fault": (int(fault.sum()), int((fault > 0).sum())),
            "not_at_fault": (int(not_fault.sum()), int((not_fault > 0).sum())),
            "aborts": float(np.mean(cols["aborts"])) if cols["aborts"] else math.nan,
            "unsafe_share": float(np.sum(np.asarray(cols["unsafe_steps"])[ok]) /
                                  max(1, np.sum(np.asarray(cols["n_steps"])[ok])))}


def paired(a: dict[str, list], b: dict[str, list], budget: int, n_boot: int, by_vehicle: bool = False) -> dict:
    """B against A on the (scene, seed) runs both ran: success both / only A / only B / neither,
    McNemar's exact p, the success difference B − A (percentage points) and the time-to-lane and
    time-to-target differences B − A (s), each with a paired bootstrap interval over scenes (over
    ego vehicles when ``by_vehicle``).
    Raises ValueError when a pair's target lanes differ (a seed fixes the lane)."""
    def index(c: dict[str, list]) -> dict[tuple[str, int], int]:
        return {(s, int(d)): i for i, (s, d, e) in enumerate(zip(c["scenario"], c["seed"], c["error"], strict=True))
                if e is None}
    ia, ib = index(a), index(b)
    common = sorted(set(ia) & set(ib))
    ra = np.array([ia[k] for k in common], dtype=int)
    rb = np.array([ib[k] for k in common], dtype=int)
    if not common:
        return {"pairs": 0}
    lanes_a = np.asarray(a["target_lane"])[ra]
    lanes_b = np.asarray(b["target_lane"])[rb]
    if np.any(lanes_a != lanes_b):
        raise ValueError("paired runs with different target lanes")
    names = np.array([k[0] for k in common])
    scen = _clusters(names, by_vehicle)
    sa = np.asarray(a["success"], dtype=bool)[ra]
    sb = np.asarray(b["success"], dtype=bool)[rb]
    only_a, only_b = int((sa & ~sb).sum()), int((~sa & sb).sum())
    ttl = (_time(a, "steps_to_lane", budget)[ra], _time(b, "steps_to_lane", budget)[rb])
    ttt = (_time(a, "steps_to_target", budget)[ra], _time(b, "steps_to_target", budget)[rb])
    d_succ = paired_bootstrap(sa.astype(np.float64), sb.astype(np.float64), scen, n_boot)
    la = np.asarray(a["steps_to_lane"], dtype=np.int64)[ra] >= 0
    lb = np.asarray(b["steps_to_lane"], dtype=np.int64)[rb] >= 0
    k = len(set(scen.tolist()))
    return {"pairs": len(common), "scenes": len(set(names.tolist())), "clusters": k, "both": int((sa & sb).sum()),
            "only_a": only_a, "only_b": only_b, "neither": int((~sa & ~sb).sum()),
            "p": mcnemar_exact(only_a, only_b), "d_success_pp": _no_interval(tuple(100.0 * x for x in d_succ), k),
            "d_ttl": _no_interval(paired_bootstrap(*ttl, scen, n_boot, seed=1), k),
            "d_ttt": _no_interval(paired_bootstrap(*ttt, scen, n_boot, seed=2), k),
            "lane_only_a": int((la & ~lb).sum()), "lane_only_b": int((~la & lb).sum()),
            "ttl_diff": (ttl[1] - ttl[0]), "keys": common}


def verdict(p: dict) -> str:
    """Whether aware (B) against ablated (A) meets the issue's bar."""
    if not p.get("pairs"):
        return "–"
    succ = p["d_success_pp"][0] >= TARGET_PP and p["d_success_pp"][1] > 0.0
    ttl = p["d_ttl"][0] <= -TARGET_S and p["d_ttl"][2] < 0.0
    return "**met**" if (succ or ttl) else "not met"


# ---- start geometry: what the safety rule asks of a dense start ----------------------------------
def start_gaps(runs: list[tuple[Path, list[int]]], settings: nudge.PlannerSettings) -> dict:
    """Per dense (scene, target lane), for the target-lane vehicle nearest along the road at the
    start: the bumper gap (m; negative: overlapping), the gap the planner's ellipse needs to
    put the ego level with it in the target lane (centre distance
    ``ellipse_scale * (L_ego + L) / 2 + margin_x`` minus the half lengths), and ``depth``: how far
    (m) the ellipse lets the ego's near edge into the target lane while that vehicle is level
    with it at its start lateral position (lateral semi-axis
    ``ellipse_scale * (W_ego + W) / 2 + margin_y``; negative: the edge stays short of the line).

    The isotropic, unsliced ellipse: for an ego longer than ``ego_segment_length`` the planner's
    sliced ellipses reach less far along the road, so ``need`` is an upper bound there."""
    rows = []
    for path, seeds in runs:
        sc = nudge.Scenario.load(path)
        for lane in sorted({sc.target_lane(s) for s in seeds}):
            row = start_geometry(sc, lane, settings)
            if row is not None:
                rows.append(row)
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 3)
    return {"gap": a[:, 0], "need": a[:, 1], "depth": a[:, 2]}


def start_geometry(sc: nudge.Scenario, lane: int, settings: nudge.PlannerSettings) -> tuple[float, float, float] | None:
    """(gap, need, depth) of :func:`start_gaps` for one start (``sc``: anything with ``history``
    ``[n, 8, 2]``, ``size`` ``[n, 2]`` (length, width) and ``lane_bounds``), or None when no
    vehicle is in the target lane."""
    pos = sc.history[:, -1, :]
    length, width = sc.size[:, 0], sc.size[:, 1]
    lo, hi = _lane(sc.lane_bounds, lane)
    best = None
    for j in range(1, len(pos)):
        if lo <= pos[j, 1] < hi:
            half = (length[0] + length[j]) / 2.0
            gap = abs(pos[j, 0] - pos[0, 0]) - half
            if best is None or gap < best[0]:
                req = settings.safety["ellipse_scale"] * half + settings.safety["margin_x"] - half
                b = settings.safety["ellipse_scale"] * (width[0] + width[j]) / 2.0 + settings.safety["margin_y"]
                line = lo if (lo + hi) / 2.0 > pos[0, 1] else hi
                best = (float(gap), float(req), float(abs(pos[j, 1] - line) - b + width[0] / 2.0))
    return best


def _lane(bounds: np.ndarray, lane: int) -> tuple[float, float]:
    return tuple(sorted((float(bounds[lane]), float(bounds[lane + 1]))))  # type: ignore[return-value]


def start_reactions(runs: list[tuple[Path, list[int]]], predictors: dict[str, str],
                    horizon: int = 6) -> dict[str, np.ndarray]:
    """Each model's reaction at every dense (scene, target lane) start: the target-lane
    follower's (nearest vehicle whose centre is in the target lane and behind the ego's) predicted
    x at the last of ``horizon`` steps (1.8 s by default) under a lane-change candidate minus under
    the keep-lane path (m; negative = it falls back). Lane change: the ego at its last observed
    speed along the road, y from its last observed position to the target lane's centre by a
    smoothstep over the first 6 steps (1.8 s), then on that centre; keep-lane: the same x at the
    ego's y. ``predictors``: label -> predictor name or weights file, each loaded for ``horizon``
    steps. Starts without a follower are left out."""
    models = {label: load_predictor(p, horizon) for label, p in predictors.items()}
    out: dict[str, list[float]] = {label: [] for label in models}
    for path, seeds in runs:
        sc = nudge.Scenario.load(path)
        pos = sc.history[:, -1, :]
        v = float(sc.speed[0])
        for lane in sorted({sc.target_lane(s) for s in seeds}):
            lo, hi = _lane(sc.lane_bounds, lane)
            behind = [j for j in range(1, sc.n_agents) if lo <= pos[j, 1] < hi and pos[j, 0] < pos[0, 0]]
            if not behind:
                continue
            follower = max(behind, key=lambda j: pos[j, 0])
            k = np.arange(1, horizon + 1, dtype=np.float64)
            f = np.minimum(k / 6.0, 1.0)
            x = pos[0, 0] + v * nudge.DT * k
            y = pos[0, 1] + ((lo + hi) / 2.0 - pos[0, 1]) * f * f * (3.0 - 2.0 * f)
            cands = np.stack([np.stack([x, y], axis=1), np.stack([x, np.full(horizon, pos[0, 1])], axis=1)])
            for label, model in models.items():
                pred = model.predict(sc.history, cands)
                out[label].append(float(pred[0, follower - 1, -1, 0] - pred[1, follower - 1, -1, 0]))
    return {label: np.asarray(v) for label, v in out.items()}


# ---- figure ------------------------------------------------------------------------------------
def find_pair(data: dict, planners: Sequence[str]) -> tuple[str, str, str, int, float] | None:
    """A run where the aware planner reaches the target lane and succeeds while its ablation never
    reaches it: (world, planner, scenario, seed, time-to-lane difference ablated (at the budget)
    − aware, s). Planners in the order of ``planners`` (the first with such a run wins), worlds
    idm before teacher, and within those the largest difference; None when none exists."""
    for planner in planners:
        for world in REACTIVE:
            a = data["arms"].get(Arm(planner, False, world))
            b = data["arms"].get(Arm(planner, True, world))
            if a is None or b is None:
                continue
            best = None
            ib = {(s, int(d)): i for i, (s, d) in enumerate(zip(b[0]["scenario"], b[0]["seed"], strict=True))}
            for i, (s, d) in enumerate(zip(a[0]["scenario"], a[0]["seed"], strict=True)):
                j = ib.get((s, int(d)))
                if j is None or a[0]["steps_to_lane"][i] < 0 or not a[0]["success"][i] or b[0]["steps_to_lane"][j] >= 0:
                    continue
                diff = (nudge.SimConfig.default().max_steps - a[0]["steps_to_lane"][i]) * nudge.DT
                if best is None or diff > best[4]:
                    best = (world, planner, s, int(d), diff)
            if best is not None:
                return best
    return None


def draw_pair(split: str, pair: tuple[str, str, str, int, float], predictor: str, out_png: Path,
              out_gif_dir: Path | None, cfg: InteractionConfig | None = None) -> list[Path]:
    """Re-runs the pair with traces; draws the ego's lateral position over time for both arms
    with the target lane (PNG) and writes both animations (GIF) when ``out_gif_dir`` is given."""
    world, _, scenario, seed, _ = pair
    path = paths.scenes(split) / f"{scenario}.safetensors"
    recs = {}
    for ablated in (False, True):
        recs[ablated] = nudge.simulate([path], predictor, scene_seeds=[seed], runs=1, threads=1,
                                       settings=(cfg or InteractionConfig()).arm_settings(ablated),
                                       world=world, trace=True)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sc = nudge.Scenario.load(path)
    lane = int(recs[False]["runs"]["target_lane"][0])
    lo, hi = sorted((float(sc.lane_bounds[lane]), float(sc.lane_bounds[lane + 1])))
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.axhspan(lo, hi, color="0.9", label="target lane")
    for ablated, style in ((False, "-"), (True, "--")):
        y = recs[ablated]["steps"]["y"]
        t = (np.arange(len(y)) + 1) * nudge.DT
        ax.plot(np.r_[0.0, t], np.r_[sc.history[0, -1, 1], y], style,
                label="ablated (predictor sees keep-lane)" if ablated else "aware")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("ego y (m)")
    ax.set_title(f"{scenario}, seed {seed}, {world} world", fontsize=9)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    written = [out_png]
    if out_gif_dir is not None:
        for ablated in (False, True):
            d = out_gif_dir / ("ablated" if ablated else "aware")
            written += nudge.animate(recs[ablated], d, mp4=False)
    return written


# ---- report --------------------------------------------------------------------------------------
def _ci(t: tuple[float, float, float], scale: float = 1.0, digits: int = 1, sign: bool = False) -> str:
    f = f"{{:{'+' if sign else ''}.{digits}f}}"
    if math.isfinite(t[0]) and not (math.isfinite(t[1]) and math.isfinite(t[2])):
        return f"{f.format(t[0] * scale)} [no interval: one cluster]"
    if not all(math.isfinite(x) for x in t):
        return "–"
    return f"{f.format(t[0] * scale)} [{f.format(t[1] * scale)}, {f.format(t[2] * scale)}]"


def split_section(data: dict, cfg: InteractionConfig, budget: int) -> tuple[list[str], dict]:
    """The markdown of one split and its numbers (for the JSON)."""
    split = data["split"]
    arms = data["arms"]
    n_dense, n_files = len(data["dense"]), data["n_files"]
    if cfg.scenes == "merge":
        hit, total = data["blocked"]
        vehicles = len({vehicle_of(p.stem) for p, _ in data["chosen"]})
        which = (f"Merge scenes: **{n_dense} of {n_files}** (the ego in a lane that really ends ahead of it), the "
                 f"chosen ones of {vehicles} ego vehicles; "
                 f"{hit} of the {total} runs drawn start with the target lane blocked (± {cfg.margin:g} m); ")
    else:
        which = (f"Dense scenes: **{n_dense} of {n_files}** qualify (a blocked target lane drawn by {cfg.seeds} of "
                 "the seeds tried); ")
    lines = [f"## Split `{split}`", "",
             which + f"{len(data['chosen'])} drawn × {cfg.seeds} seeds = {len(data['chosen']) * cfg.seeds} runs "
             f"per arm, the aware teacher planner on {len(data['teacher_runs'])} of them "
             f"({len(data['teacher_runs']) * cfg.seeds} runs). Simulation: "
             f"{sum(v[1] for v in arms.values()) / 60:.1f} min summed over the cached parts "
             f"({sum(v[2] for v in arms.values()) / 60:.1f} min computed by this invocation).", "",
             "### Every arm", "",
             "Success and time to lane: mean [95 % bootstrap interval over "
             + ("ego vehicles" if cfg.scenes == "merge" else "scenes") + "]; time to lane/target: failures at "
             f"the budget ({budget} steps = {budget * nudge.DT:.1f} s); unsafe steps: share of steps whose plan was "
             "Unsafe, Fallback or SolverFailed.", "",
             "| world | planner | runs (scenes) | success % | reached lane % | time to lane s | time to target s | "
             "at-fault events (runs) | not at fault (runs) | aborts / run | unsafe steps |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    numbers: dict = {cfg.scenes: n_dense, "files": n_files, "blocked_runs": list(data["blocked"]), "arms": {},
                     "pairs": {}}
    for arm, (cols, _, _) in arms.items():
        s = summarise(cols, budget, cfg.bootstrap, by_vehicle=cfg.scenes == "merge")
        numbers["arms"][f"{arm.world}/{arm.label}"] = s
        err = f" + {s['errors']} failed" if s["errors"] else ""
        lines.append(f"| {arm.world} | {arm.label} | {s['runs']}{err} ({s['scenes']}) | "
                     f"{_ci(s['success'], 100.0)} | {100.0 * s['reached']:.1f} | {_ci(s['ttl'], digits=2)} | "
                     f"{s['ttt']:.2f} | {s['at_fault'][0]} ({s['at_fault'][1]}) | "
                     f"{s['not_at_fault'][0]} ({s['not_at_fault'][1]}) | {s['aborts']:.2f} | "
                     f"{100.0 * s['unsafe_share']:.1f} % |")
    lines += ["", "### Aware against ablated (the same model), paired by (scene, seed, target lane)", "",
              "Differences aware − ablated; negative time = the aware planner is faster. Bar (issue 15): success "
              f"+{TARGET_PP:.0f} pp or time to lane −{TARGET_S} s or better with the interval excluding zero.", "",
              "| world | planner | pairs (scenes) | both / only ablated / only aware / neither | McNemar p | "
              "success Δ pp | time to lane Δ s | time to target Δ s | bar |",
              "|---|---|---|---|---|---|---|---|---|"]
    comparisons = []
    for world in cfg.worlds:
        for label, _ in cfg.planners():
            comparisons.append((world, Arm(label, True, world), Arm(label, False, world)))
        for label, _ in cfg.planners():
            comparisons.append((world, Arm("constant_velocity", False, world), Arm(label, False, world)))
    for world, a, b in comparisons:
        if a not in arms or b not in arms:
            continue
        p = paired(arms[a][0], arms[b][0], budget, cfg.bootstrap, by_vehicle=cfg.scenes == "merge")
        name = f"{b.label} vs {a.label}"
        numbers["pairs"][f"{world}/{name}"] = {k: v for k, v in p.items() if k not in ("keys", "ttl_diff")}
        if not p["pairs"]:
            continue
        bar = verdict(p) if a.ablated and world in REACTIVE else ("(not reactive)" if a.ablated else "")
        lines.append(f"| {world} | {name} | {p['pairs']} ({p['scenes']}) | {p['both']} / {p['only_a']} / "
                     f"{p['only_b']} / {p['neither']} | {p['p']:.3g} | {_ci(p['d_success_pp'], sign=True)} | "
                     f"{_ci(p['d_ttl'], digits=2, sign=True)} | {_ci(p['d_ttt'], digits=2, sign=True)} | {bar} |")
        if a.ablated:
            d = p["ttl_diff"]
            lines_key = f"{world}/{name}"
            numbers["pairs"][lines_key]["ttl_faster"] = int((d < -1e-9).sum())
            numbers["pairs"][lines_key]["ttl_slower"] = int((d > 1e-9).sum())
    # How often the two arms of one model differ at all.
    lines += ["", "Pairs whose time to lane differs at all (aware faster / ablated faster / equal), and pairs in which "
              "only one arm ever reaches the target lane (only aware / only ablated):", ""]
    for world in cfg.worlds:
        for label, _ in cfg.planners():
            key = f"{world}/{label} vs {label} (ablated)"
            q = numbers["pairs"].get(key)
            if q and "ttl_faster" in q:
                lines.append(f"- {world}, {label}: {q['ttl_faster']} / {q['ttl_slower']} / "
                             f"{q['pairs'] - q['ttl_faster'] - q['ttl_slower']}; reaching the lane: "
                             f"{q['lane_only_b']} / {q['lane_only_a']}")
    return lines, numbers


def report(results: list[dict], cfg: InteractionConfig, command: str, extra: list[str]) -> tuple[str, dict]:
    """The generated part of ``docs/results/interaction.md`` and its numbers."""
    config = nudge.SimConfig.default()
    budget = int(config.max_steps)
    idm = json.loads((nudge.assets_dir() / "worlds" / "idm.json").read_text())
    rule = idm["intrusion"]
    title = "# Interaction: the aware planner against the same model with its reaction ablated"
    if cfg.scenes == "merge":
        title += ", on merges"
    if cfg.horizon != DEFAULT_HORIZON:
        title += f", horizon {cfg.horizon} steps ({cfg.horizon * nudge.DT:.1f} s)"
    if cfg.scenes == "merge":
        where = "On real merges (the ego's lane ends)"
        selection = (f"- Merge scene: at the last observed step the ego is in a lane that really ends ahead of it "
                     "(an acceleration or auxiliary lane: `lane_extent_real[ego_lane]` ends, the ego before its "
                     "end). The target lane is the simulator's draw, which never offers a lane ending within the "
                     "run's reach: the adjacent lane that outlasts the ego's. A scene's runs are its first "
                     f"{cfg.seeds} seeds scene_seed + r (scene seeds drawn with seed {cfg.seed} as in `nudge-train "
                     "closed-loop`); seeds differ only in the idm world's drivers. Scenes drawn per split: a seeded "
                     + ", ".join(f"{cfg.sizes(sp)[0]} ({sp})" for sp in cfg.splits)
                     + " of them; the aware teacher planner (about 10× slower than the others) on a seeded "
                     + ", ".join(f"{cfg.sizes(sp)[1]} ({sp})" for sp in cfg.splits) + " of those.")
    else:
        where = "In dense traffic"
        selection = (f"- Dense scene: the target lane is blocked at the start, i.e. a vehicle whose centre lies in "
                     f"the target lane overlaps the ego's longitudinal extent ± {cfg.margin:g} m (|x − x_ego| < "
                     f"(L_ego + L)/2 + {cfg.margin:g} m) at the last observed step. The target lane comes from the "
                     f"run's seed; a scene qualifies when {cfg.seeds} of the seeds scene_seed + r (r < {SEED_TRIES}) "
                     "draw a blocked lane, and those are its runs (scene seeds drawn with seed "
                     f"{cfg.seed} as in `nudge-train closed-loop`). Scenes drawn per split: a seeded "
                     + ", ".join(f"{cfg.sizes(sp)[0]} ({sp})" for sp in cfg.splits)
                     + " of the qualifying ones; the aware teacher planner (about 10× slower than the others) on a "
                     "seeded " + ", ".join(f"{cfg.sizes(sp)[1]} ({sp})" for sp in cfg.splits) + " of those.")
    lines = [title, "",
             f"Generated by `{command}` (python/train/nudge_train/experiments/interaction.py).", "",
             f"**Question.** {where}, does a planner whose predictor answers the ego's plan (aware) reach the "
             "target lane sooner, or more often, than the same planner whose predictor only ever sees the ego "
             "keeping its lane (ablated: planner setting `ablate_reaction`, `--ablate-reaction`: the predictor sees "
             f"the keep-lane path x_k = x_0 + k·0.3 s·v_0, y_k = y_0, k = 1..{cfg.horizon}, predicted once per "
             "planning step, "
             "so the predicted traffic cannot depend on the plan; cost, safety rule and fallbacks unchanged)?", "",
             "**Set-up.**",
             selection,
             "- Planners: " + ", ".join(f"`{label}`" for label, _ in cfg.planners()) + " "
             + (f"(`{CANDIDATE}`: **candidate, not shipped**: `{paths.repo_relative(Path(cfg.candidate))}`, the "
                "reaction-distilled student of docs/results/reaction.md) "
                if cfg.candidate and CANDIDATE in dict(cfg.planners()) else "")
             + "each aware and ablated; `constant_velocity` as a third baseline (its prediction never depends on the "
             "ego, so its ablated planner is the same planner; tested in `crates/planner/tests/ablate_reaction.rs`).",
             f"- Worlds: `idm` as shipped (`assets/worlds/idm.json`, fitted in docs/results/idm_fit.md, not tuned "
             f"here): drivers drawn from the fitted population; a follower yields to the ego once the ego's nearest "
             f"edge is {rule['threshold_m']} m inside its lane with probability {rule['p_yield']}, otherwise only once "
             "the ego is wholly inside; `teacher` (the shipped teacher predicts the others given the ego's executed "
             "plan); `log_replay` (the logged future, nobody reacts; for at-fault collisions only)"
             + ("." if "log_replay" in cfg.worlds else "; here: " + ", ".join(f"`{w}`" for w in cfg.worlds)
                + " only."),
             f"- Closed loop: the default `SimConfig` (`{json.dumps(json.loads(config.to_json()), sort_keys=True)}`, "
             "world set per arm), "
             + (f"planner settings `{json.dumps(json.loads(Path(cfg.settings).read_text()), sort_keys=True)}` "
                f"(`--settings {paths.repo_relative(Path(cfg.settings))}`, the rest default)"
                if cfg.settings is not None else "default planner settings")
             + (f" (horizon {cfg.horizon} steps = {cfg.horizon * nudge.DT:.1f} s)." if cfg.horizon == DEFAULT_HORIZON
                else f" except the horizon: **{cfg.horizon} steps = {cfg.horizon * nudge.DT:.1f} s** (default "
                     f"{DEFAULT_HORIZON} = {DEFAULT_HORIZON * nudge.DT:.1f} s); planners whose model cannot predict it "
                     "(the students' fixed 6-step decoder) are left out."),
             "- Main metric: time to lane, the time until the ego's centre first lies inside the target lane, "
             f"failures (never) counted at the budget {budget * nudge.DT:.1f} s. Also success (settled in the target "
             "lane within the budget without any collision), time to target (settled), collisions at fault or not "
             "(docs/results/closed_loop.md defines them). Intervals: 95 % percentile bootstrap over "
             + ("ego vehicles (a merge scene's ego appears at several start times, 0.3 s apart, in scenes that are "
                "not independent: `vehicle_of`)" if cfg.scenes == "merge" else "scenes")
             + f" ({cfg.bootstrap} resamples; runs of one scene are not independent); McNemar's exact test on paired "
             "success. In the `teacher` and `log_replay` worlds a run depends on its seed only through the target "
             "lane, so seeds of one scene that draw the same lane repeat a run exactly; in `idm` the seed also "
             "draws the drivers.",
             f"- Machine: 2-core machine shared with other jobs, {cfg.threads} runs side by side, `nice -n 5`.",
             "- Fixed before any run: the blocked-lane margin, the seeds, the metrics and the bar; the sizes follow "
             "the compute the machine allowed. Nothing was tuned on either split; "
             + ("the test split ran once." if "test" in cfg.splits else "the test split did not run."), ""]
    numbers = {}
    for data in results:
        sec, num = split_section(data, cfg, budget)
        lines += sec + [""]
        numbers[data["split"]] = num
    lines += extra
    return "\n".join(lines) + "\n", numbers


def horizon_section(results: list[dict], refs: list[dict], cfg: InteractionConfig) -> tuple[list[str], dict]:
    """Every arm at ``cfg.horizon`` against the same arm at ``cfg.compare_horizon`` on the same runs
    (paired by scene, seed and target lane), and each planner's aware − ablated difference at both."""
    budget = int(nudge.SimConfig.default().max_steps)
    h, h0 = cfg.horizon, cfg.compare_horizon
    lines = [f"## Horizon {h} ({h * nudge.DT:.1f} s) against horizon {h0} ({h0 * nudge.DT:.1f} s)", "",
             f"The same arms on the same runs at both horizons (`--compare-horizon {h0}`), paired by (scene, seed, "
             f"target lane); differences horizon {h} − horizon {h0}, negative time = the longer horizon is faster.", "",
             "| split | world | arm | pairs (scenes) | both / only h0 / only h / neither | McNemar p | success Δ pp | "
             "time to lane Δ s | time to target Δ s |",
             "|---|---|---|---|---|---|---|---|---|"]
    numbers: dict = {}
    for data, ref in zip(results, refs, strict=True):
        for arm, (cols, _, _) in data["arms"].items():
            if arm not in ref["arms"]:
                continue
            p = paired(ref["arms"][arm][0], cols, budget, cfg.bootstrap)
            numbers[f"{data['split']}/{arm.world}/{arm.label}"] = {k: v for k, v in p.items()
                                                                  if k not in ("keys", "ttl_diff")}
            if not p["pairs"]:
                continue
            lines.append(f"| {data['split']} | {arm.world} | {arm.label} | {p['pairs']} ({p['scenes']}) | "
                         f"{p['both']} / {p['only_a']} / {p['only_b']} / {p['neither']} | {p['p']:.3g} | "
                         f"{_ci(p['d_success_pp'], sign=True)} | {_ci(p['d_ttl'], digits=2, sign=True)} | "
                         f"{_ci(p['d_ttt'], digits=2, sign=True)} |")
    lines += ["", f"Aware − ablated (the same model) at horizon {h0} and at horizon {h} (pairs as above):", "",
              f"| split | world | planner | success Δ pp, h = {h0} | success Δ pp, h = {h} | time to lane Δ s, "
              f"h = {h0} | time to lane Δ s, h = {h} | bar at h = {h} |",
              "|---|---|---|---|---|---|---|---|"]
    for data, ref in zip(results, refs, strict=True):
        for world in cfg.worlds:
            for label, _ in cfg.planners():
                a, b = Arm(label, True, world), Arm(label, False, world)
                if not all(x in d["arms"] for x in (a, b) for d in (data, ref)):
                    continue
                p0 = paired(ref["arms"][a][0], ref["arms"][b][0], budget, cfg.bootstrap)
                p1 = paired(data["arms"][a][0], data["arms"][b][0], budget, cfg.bootstrap)
                if not (p0["pairs"] and p1["pairs"]):
                    continue
                bar = verdict(p1) if world in REACTIVE else "(not reactive)"
                lines.append(f"| {data['split']} | {world} | {label} | {_ci(p0['d_success_pp'], sign=True)} | "
                             f"{_ci(p1['d_success_pp'], sign=True)} | {_ci(p0['d_ttl'], digits=2, sign=True)} | "
                             f"{_ci(p1['d_ttl'], digits=2, sign=True)} | {bar} |")
    return lines + [""], numbers


def run(cfg: InteractionConfig, out: Path, json_path: Path | None, command: str) -> int:
    """``nudge-train interaction``: every split, the report (keeping its hand-written notes), the
    figure of one pair where the aware planner merges and its ablation does not. Returns the exit
    status (2 for a bad argument or a split without scenes)."""
    try:
        cfg.validate()
        results = [collect(cfg, split, log=lambda s: print(s, flush=True)) for split in cfg.splits]
        ref_cfg = (None if cfg.compare_horizon is None
                   else replace(cfg, horizon=cfg.compare_horizon, compare_horizon=cfg.horizon))
        refs = [] if ref_cfg is None else [collect(ref_cfg, split, log=lambda s: print(s, flush=True))
                                           for split in cfg.splits]
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    extra = []
    horizon_numbers: dict = {}
    if refs:
        extra, horizon_numbers = horizon_section(results, refs, cfg)
    extra += [f"## What the safety rule asks of a {cfg.scenes} start", ""]
    rule_threshold = float(json.loads((nudge.assets_dir() / "worlds" / "idm.json").read_text())
                           ["intrusion"]["threshold_m"])
    settings = nudge.PlannerSettings.default()
    for data in results:
        g = start_gaps(data["chosen"], settings)
        if g["gap"].size:
            extra.append(f"- `{data['split']}` ({g['gap'].size} {cfg.scenes} (scene, target lane) starts): bumper gap to the "
                         f"nearest target-lane vehicle median {np.median(g['gap']):+.2f} m (negative = overlapping "
                         f"along the road); the √2 ellipse with margin_x {settings.safety['margin_x']} m needs a gap of "
                         f"{np.median(g['need']):.2f} m (median) to have the ego level with it in the target lane; "
                         f"{100.0 * np.mean(g['gap'] < g['need']):.0f} % of the starts have less. While that "
                         f"vehicle is level with the ego, the ellipse lets the ego's near edge at most "
                         f"{np.median(g['depth']):+.2f} m (median; max {np.max(g['depth']):+.2f} m) into the "
                         f"target lane (negative: short of the line); the idm world's yielding followers react "
                         f"only at +{rule_threshold:.1f} m ({100.0 * np.mean(g['depth'] > rule_threshold):.0f} % of "
                         "these starts allow that).")
    react_horizons = sorted({DEFAULT_HORIZON, cfg.horizon})
    extra += ["", "## The predicted reaction at these starts", "",
              "The target-lane follower's predicted x at "
              + " and at ".join(f"{h * nudge.DT:.1f} s" for h in react_horizons)
              + " under a lane change to the target lane's centre (smoothstep over 1.8 s at the ego's speed, then on "
              f"the centre) minus under the keep-lane path, at every {cfg.scenes} (scene, target lane) start with a "
              "follower "
              "(the vehicle the nudge should slow down); median [95 % bootstrap interval over starts], the share "
              "below −1 cm and the most negative value.", "",
              "| split | model | starts | at (s) | reaction (m) | share < −1 cm | most negative (m) |",
              "|---|---|---|---|---|---|---|"]
    for data in results:
        for h in react_horizons:
            reactions = start_reactions(data["chosen"], dict(cfg.planners()), h)
            for label, r in reactions.items():
                if r.size:
                    ci = cluster_bootstrap(r, np.arange(r.size), np.median, n_boot=cfg.bootstrap)
                    extra.append(f"| {data['split']} | {label} | {r.size} | {h * nudge.DT:.1f} | "
                                 f"{_ci(ci, digits=3, sign=True)} | {100.0 * np.mean(r < -0.01):.0f} % | "
                                 f"{r.min():+.3f} |")
    extra.append("")
    # The models that react first (docs/results/reaction.md: the shipped student does not).
    planners = [label for label in ("teacher", CANDIDATE, "student") if label in dict(cfg.planners())]
    fig_lines = ["## One run where the aware planner merges and its ablation does not", "",
                 "Searched in the test split first, planners in the order " + ", ".join(f"`{p}`" for p in planners)
                 + " (the models that react first), the idm world before the teacher world.", ""]
    for data in results[::-1]:
        pair = find_pair(data, planners)
        if pair is None:
            fig_lines.append(f"- `{data['split']}`: no run in which an aware planner reached the target lane and "
                             "its ablation never did (reactive worlds).")
            continue
        world, planner, scenario, seed, diff = pair
        predictor = dict(cfg.planners())[planner]
        tag = ("" if cfg.scenes == "dense" else f"_{cfg.scenes}") + (
            "" if cfg.horizon == DEFAULT_HORIZON else f"_h{cfg.horizon}")
        png = paths.figures() / f"interaction_pair{tag}.png"
        written = []
        if cfg.animate:
            written = draw_pair(data["split"], pair, predictor, png, paths.figures() / f"interaction{tag}", cfg)
        fig_lines += [f"`{data['split']}` split, `{world}` world, planner `{planner}`: scene `{scenario}`, "
                      f"seed {seed}: "
                      f"the aware planner reaches the target lane, the ablated one does not within "
                      f"{nudge.SimConfig.default().max_steps * nudge.DT:.0f} s (of such runs of this planner and "
                      "world, the one whose aware planner reaches the lane earliest).", ""]
        if written:
            fig_lines.append(f"![aware vs ablated]({Path('..') / 'figures' / png.name})")
            fig_lines += ["", "Animations: " + ", ".join(f"`{paths.repo_relative(p)}`" for p in written[1:]), ""]
        break
    text, numbers = report(results, cfg, command, extra + fig_lines)
    existing = out.read_text() if out.is_file() else ""
    notes = existing.split(MARKER, 1)[1] if MARKER in existing else "\n"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text + "\n" + MARKER + notes)
    print(text)
    print(f"wrote {paths.repo_relative(out)}")
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        if horizon_numbers:
            numbers["horizon"] = horizon_numbers
        json_path.write_text(json.dumps(numbers, indent=1, default=float))
    return 0


def command_line(argv: Sequence[str]) -> str:
    """The command as the report names it (no machine paths)."""
    return "nudge-train interaction " + shlex.join(argv)
