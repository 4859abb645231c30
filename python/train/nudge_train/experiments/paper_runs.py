"""The measurements behind the paper's Figures 7–10, by vehicle count N (``nudge-train paper``).

* **Scenes cut to N** (:func:`cut_scene`): a real scene of the split with at least N vehicles,
  cut to the ego and its N − 1 nearest vehicles at the last observed step
  (``nudge.Scenario.nearest``), written as a scenario file with every per-vehicle tensor sliced
  and checked by reading it back: its history, sizes and vehicle ids must equal
  ``Scenario.nearest``'s bit for bit.
* **Closed loop** (:func:`collect_closed_loop`): per N, ``sims`` seeded scenes of the eligible
  ones, one run each (random target lane: the scene seed), in the teacher world, one thread, for
  every planning predictor. The arms run chunk by chunk (``chunk`` scenes, every predictor on a
  chunk before the next, the first predictor rotating), so a change in the machine's load falls
  on every arm alike. The numbers are the simulator's step columns (``mpc_s``, ``z_s``,
  ``z_updates``, ``cost``, ...), no new timers.
* **Inference** (:func:`collect_inference`): per N, one prediction for ``t_plan`` = 6 (one ego
  candidate: the ego's constant-velocity future) on ``infer_scenes`` of the cut scenes, the Rust
  predictors (``nudge.Predictor.predict``, the binding's call) and the PyTorch reference
  (``teacher_interactive`` / ``student_interactive``, inference mode), one thread, the four
  interleaved per scene; median of ``infer_reps`` timed calls after two warm-up calls per scene.

Every (N, predictor) result and every N's inference result is cached as JSON under the cache
folder with the hash of its inputs (scene files, seeds, predictor and world models, planner
settings, closed-loop configuration, the compiled extension) and the hash of its own content;
a rerun verifies both and recomputes what fails (:func:`load_cached`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

CACHE_SCHEMA = "nudge.paper_cache/1"
RUN_KEEP = ("scenario", "seed", "n_agents", "target_lane", "success", "steps_to_target", "collision",
            "collisions_at_fault", "collisions_not_at_fault", "n_steps", "error")
"""Run columns kept in the cache (``nudge.simulate``'s names)."""
STEP_KEEP = ("run", "mpc_s", "z_s", "z_updates", "z_median_s", "iterations", "predictor_calls", "cost", "status")
"""Step columns kept in the cache (``nudge.simulate``'s names; times in seconds)."""
PER_AGENT = ("agent_ids", "future", "future_valid", "heading", "history", "size", "speed")
"""Tensors of a scenario file with one row per vehicle (sliced when a scene is cut)."""

Log = Callable[[str], None]


def sha256(data: bytes) -> str:
    """Hex sha256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def file_sha(path: Path, memo: dict[Path, str] | None = None) -> str:
    """Hex sha256 of a file's bytes (memoised in ``memo`` when given)."""
    if memo is None:
        return sha256(Path(path).read_bytes())
    if path not in memo:
        memo[path] = sha256(Path(path).read_bytes())
    return memo[path]


def load_average() -> tuple[float, float, float] | None:
    """The 1, 5 and 15 minute load averages, or None where the system has none."""
    try:
        return os.getloadavg()
    except OSError:
        return None


# ---- scenes -------------------------------------------------------------------------------------
def eligible_scenes(scenes_dir: Path) -> tuple[list[Path], np.ndarray]:
    """The scenario files of ``scenes_dir`` (sorted) and their vehicle counts (ego included)."""
    import nudge

    files = sorted(Path(scenes_dir).glob("*.safetensors"))
    counts = np.array([nudge.Scenario.load(f).n_agents for f in files], dtype=np.int64)
    return files, counts


def draw_scenes(files: Sequence[Path], counts: np.ndarray, n: int, sims: int, seed: int) -> tuple[list[Path], list[int]]:
    """``sims`` scenes with at least ``n`` vehicles (a seeded draw without replacement, in draw
    order; all of them when fewer) and one scene seed each (the target lane's draw)."""
    pool = [f for f, c in zip(files, counts, strict=True) if c >= n]
    order = np.random.default_rng([seed, n, 1]).permutation(len(pool))[:sims]
    seeds = np.random.default_rng([seed, n, 2]).integers(0, 2**31, size=len(order))
    return [pool[i] for i in order], [int(s) for s in seeds]


def cut_scene(src: Path, n: int, out: Path) -> Path:
    """Writes ``src`` cut to its ego and ``n`` − 1 nearest vehicles to ``out`` (kept when it
    already holds exactly that cut) and returns ``out``.

    Raises:
        ValueError: ``src`` has fewer than ``n`` vehicles, repeats a vehicle id, or the written
            file does not read back as ``Scenario.nearest(n - 1)`` (naming the file).
    """
    import nudge
    from safetensors import safe_open
    from safetensors.numpy import load_file, save_file

    scene = nudge.Scenario.load(src)
    if scene.n_agents < n:
        raise ValueError(f"{src}: {scene.n_agents} vehicles, cannot cut to N = {n}")
    want = scene.nearest(n - 1)

    def same(path: Path) -> bool:
        got = nudge.Scenario.load(path)
        return (got.n_agents == want.n_agents and np.array_equal(got.history, want.history)
                and np.array_equal(got.size, want.size) and np.array_equal(got.agent_ids, want.agent_ids)
                and np.array_equal(got.speed, want.speed) and np.array_equal(got.lane_bounds, want.lane_bounds))

    if out.is_file() and same(out):
        return out
    ids = [int(i) for i in scene.agent_ids]
    if len(set(ids)) != len(ids):
        raise ValueError(f"{src}: repeated vehicle ids, cannot map the cut back to rows")
    rows = np.array([ids.index(int(i)) for i in want.agent_ids], dtype=np.int64)
    tensors = load_file(str(src))
    with safe_open(str(src), "np") as f:
        meta = dict(f.metadata() or {})
    cut = {k: (np.ascontiguousarray(v[rows]) if k in PER_AGENT else v) for k, v in tensors.items()}
    meta["cut"] = f"ego and its {n - 1} nearest vehicles at the last observed step"
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    save_file(cut, str(tmp), metadata=meta)
    tmp.replace(out)
    if not same(out):
        raise ValueError(f"{out}: the cut does not read back as Scenario.nearest({n - 1}) of {src}")
    return out


# ---- cache --------------------------------------------------------------------------------------
def _payload_sha(payload: dict) -> str:
    return sha256(json.dumps(payload, sort_keys=True, allow_nan=True).encode())


def write_cached(path: Path, key: str, payload: dict) -> None:
    """Writes ``payload`` with its input ``key`` and content hash, atomically."""
    doc = {"schema": CACHE_SCHEMA, "key": key, "content_sha256": _payload_sha(payload), "payload": payload}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(doc, allow_nan=True))
    tmp.replace(path)


def load_cached(path: Path, key: str, log: Log) -> dict | None:
    """The payload cached at ``path`` when its schema, input key and content hash all check out;
    else None (logging why, so the caller recomputes)."""
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, OSError) as err:
        log(f"  {path}: unreadable ({err}); recomputing")
        return None
    if not isinstance(doc, dict) or doc.get("schema") != CACHE_SCHEMA:
        log(f"  {path}: not a {CACHE_SCHEMA} file; recomputing")
        return None
    if doc.get("key") != key:
        log(f"  {path}: inputs changed; recomputing")
        return None
    payload = doc.get("payload")
    if not isinstance(payload, dict) or doc.get("content_sha256") != _payload_sha(payload):
        log(f"  {path}: content hash mismatch; recomputing")
        return None
    return payload


def _column(values: Any) -> list:
    return values.tolist() if isinstance(values, np.ndarray) else list(values)


# ---- closed loop --------------------------------------------------------------------------------
@dataclass(frozen=True)
class LoopSpec:
    """What the closed-loop measurement runs (see the module doc)."""

    scenes_dir: Path
    cache: Path
    ns: tuple[int, ...]
    sims: int
    predictors: tuple[str, ...]
    world: str
    seed: int
    chunk: int
    max_steps: int | None
    progress: bool


def _inputs(spec: LoopSpec, predictor: str, n: int, scenes: list[Path], seeds: list[int],
            memo: dict[Path, str]) -> dict:
    import nudge

    models = {}
    if predictor in ("teacher", "student"):
        models["planner"] = file_sha(nudge.model_path(predictor), memo)
    if spec.world == "teacher":
        models["world"] = file_sha(nudge.model_path("teacher"), memo)
    return {"what": "closed_loop", "n": n, "predictor": predictor, "world": spec.world,
            "scenes": [p.name for p in scenes], "scene_sha": [file_sha(p, memo) for p in scenes], "seeds": seeds,
            "settings": json.loads(nudge.PlannerSettings.default().to_json()),
            "config": json.loads(_sim_config(spec).to_json()), "models": models,
            "native": file_sha(Path(nudge._native.__file__), memo)}


def _sim_config(spec: LoopSpec) -> Any:
    import nudge

    cfg = nudge.SimConfig.default().replace(world=spec.world)
    return cfg if spec.max_steps is None else cfg.replace(max_steps=spec.max_steps)


def collect_closed_loop(spec: LoopSpec, log: Log) -> dict[int, dict[str, Any]]:
    """Per N: ``{"pool": scenes with >= N vehicles, "scenes": names run, "arms": {predictor:
    payload}}``; a payload holds ``runs`` and ``steps`` (the kept columns), ``wall_s`` (its
    simulations' wall time, s), ``cpu_s`` (their process CPU time), ``load`` (load averages
    before and after) and ``computed_at``."""
    import nudge
    from tqdm import tqdm

    files, counts = eligible_scenes(spec.scenes_dir)
    if not files:
        raise FileNotFoundError(f"no scenario files in {spec.scenes_dir}")
    memo: dict[Path, str] = {}
    config = _sim_config(spec)
    settings = nudge.PlannerSettings.default()
    out: dict[int, dict[str, Any]] = {}
    plan = []
    for n in spec.ns:
        chosen, seeds = draw_scenes(files, counts, n, spec.sims, spec.seed)
        cuts = [cut_scene(p, n, spec.cache / "scenes" / f"n{n:02d}" / p.name) for p in chosen]
        keys = {p: sha256(json.dumps(_inputs(spec, p, n, cuts, seeds, memo), sort_keys=True).encode())
                for p in spec.predictors}
        cached = {p: load_cached(spec.cache / "closed_loop" / f"n{n:02d}-{p}.json", keys[p], log)
                  for p in spec.predictors}
        out[n] = {"pool": int((counts >= n).sum()), "scenes": [p.name for p in cuts], "arms": {}}
        out[n]["arms"] = {p: c for p, c in cached.items() if c is not None}
        todo = [p for p in spec.predictors if cached[p] is None]
        plan.append((n, cuts, seeds, keys, todo))
    units = sum(len(todo) * math.ceil(len(cuts) / spec.chunk) for n, cuts, _, _, todo in plan)
    bar = tqdm(total=units, desc="closed loop by N", unit="chunk", disable=not spec.progress)
    for n, cuts, seeds, keys, todo in plan:
        if not todo:
            continue
        acc = {p: {"runs": {k: [] for k in RUN_KEEP}, "steps": {k: [] for k in STEP_KEEP}, "wall_s": 0.0,
                   "cpu_s": 0.0} for p in todo}
        load_start = load_average()
        for ci, lo in enumerate(range(0, len(cuts), spec.chunk)):
            part = list(range(lo, min(lo + spec.chunk, len(cuts))))
            order = todo[ci % len(todo):] + todo[: ci % len(todo)]
            for p in order:
                bar.set_postfix_str(f"N={n} {p}")
                t0, c0 = time.perf_counter(), time.process_time()
                res = nudge.simulate([cuts[i] for i in part], p, scene_seeds=[seeds[i] for i in part], runs=1,
                                     threads=1, settings=settings, config=config, on_error="skip")
                a = acc[p]
                a["wall_s"] += time.perf_counter() - t0
                a["cpu_s"] += time.process_time() - c0
                offset = len(a["runs"]["seed"])
                for k in RUN_KEEP:
                    a["runs"][k].extend(_column(res["runs"][k]))
                for k in STEP_KEEP:
                    vals = _column(res["steps"][k])
                    a["steps"][k].extend([v + offset for v in vals] if k == "run" else vals)
                bar.update(1)
        load_end = load_average()
        for p in todo:
            payload = dict(acc[p], load=[load_start, load_end], computed_at=time.strftime("%Y-%m-%d %H:%M UTC",
                                                                                        time.gmtime()))
            write_cached(spec.cache / "closed_loop" / f"n{n:02d}-{p}.json", keys[p], payload)
            out[n]["arms"][p] = json.loads(json.dumps(payload, allow_nan=True))
    bar.close()
    return out


# ---- inference ----------------------------------------------------------------------------------
def _median_ms(fn: Callable[[], object], reps: int) -> float:
    for _ in range(2):
        fn()
    samples = []
    for _ in range(reps):
        t0 = time.perf_counter_ns()
        fn()
        samples.append(time.perf_counter_ns() - t0)
    return float(np.median(samples)) / 1e6


INFER_ARMS = ("teacher_rust", "student_rust", "teacher_torch", "student_torch")
"""The inference series: model and implementation."""


def collect_inference(scenes_by_n: dict[int, list[Path]], cache: Path, scenes_per_n: int, reps: int,
                      progress: bool, log: Log) -> dict[int, dict[str, Any]]:
    """Per N: ``{arm: [median ms per scene]}`` for the arms of :data:`INFER_ARMS`, plus
    ``scenes``, ``load`` and ``wall_s``; one thread (the caller sets ``RAYON_NUM_THREADS`` before
    the extension starts; torch is set here)."""
    import nudge
    import torch
    from tqdm import tqdm

    from nudge_train.constants import PRED_LEN
    from nudge_train.models.interactive import student_interactive, teacher_interactive
    from nudge_train.training.export import load_generator

    torch.set_num_threads(1)
    weights = {m: nudge.model_path(m) for m in ("teacher", "student")}
    rust = {m: nudge.Predictor.load(w) for m, w in weights.items()}
    gens = {m: load_generator(Path(w), "cpu") for m, w in weights.items()}
    memo: dict[Path, str] = {}
    out: dict[int, dict[str, Any]] = {}
    bar = tqdm(total=len(scenes_by_n), desc="inference by N", unit="N", disable=not progress)
    for n, scenes in scenes_by_n.items():
        use = scenes[:scenes_per_n]
        inputs = {"what": "inference", "n": n, "scene_sha": [file_sha(p, memo) for p in use], "reps": reps,
                  "weights": {m: file_sha(Path(w), memo) for m, w in weights.items()},
                  "native": file_sha(Path(nudge._native.__file__), memo), "torch": torch.__version__}
        key = sha256(json.dumps(inputs, sort_keys=True).encode())
        path = cache / "inference" / f"n{n:02d}.json"
        payload = load_cached(path, key, log)
        if payload is None:
            series: dict[str, list[float]] = {a: [] for a in INFER_ARMS}
            load_start, t_start = load_average(), time.perf_counter()
            for p in use:
                sc = nudge.Scenario.load(p)
                hist = np.ascontiguousarray(sc.history, dtype=np.float64)
                steps = np.arange(1, PRED_LEN + 1) * nudge.DT
                x0, y0 = hist[0, -1]
                cand = np.stack([x0 + sc.speed[0] * steps, np.full(PRED_LEN, y0)], -1)[None]
                th, tc = torch.from_numpy(hist.astype(np.float32)), torch.from_numpy(cand.astype(np.float32))
                fns = {
                    "teacher_rust": lambda: rust["teacher"].predict(hist, cand),
                    "student_rust": lambda: rust["student"].predict(hist, cand),
                    "teacher_torch": lambda: teacher_interactive(gens["teacher"], th, tc),
                    "student_torch": lambda: student_interactive(gens["student"], th, tc),
                }
                with torch.inference_mode():
                    for arm in INFER_ARMS:
                        series[arm].append(_median_ms(fns[arm], reps))
            payload = {**series, "scenes": [p.name for p in use], "load": [load_start, load_average()],
                       "wall_s": time.perf_counter() - t_start}
            write_cached(path, key, payload)
        out[n] = payload
        bar.update(1)
    bar.close()
    return out
