"""Sharded, resumable generation of the distillation set (single process or Ray).

A shard is the closed-loop runs of ``scenes_per_shard`` consecutive scenes of one split. It is
computed by :func:`compute_shard` (``nudge.simulate`` with the teacher as the planning
predictor, recording every candidate it is asked to evaluate), written to a temporary name and
renamed when complete; a rerun skips every shard whose file exists with the same content key.
Shard contents depend only on the scenes, their seeds and the content key (never on timings,
thread counts or where it ran), so Ray and single-process runs write identical shards.

Storage integrity (:func:`shard_bytes`, :func:`verified_shard`): a shard's bytes are canonical
(metadata keys sorted, so two processes write identical files) and carry a ``content_sha256``
over their whole content; the manifest lists each shard's file sha256 and content hash. A rerun
verifies every existing shard: one that fails (flipped bytes, edited metadata, no hash) is named
in the log and in ``last_run.replaced`` and regenerated, never kept. Stale temp files of a killed
run are removed at the start of the next one.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from safetensors.numpy import load as load_bytes
from safetensors.numpy import save
from tqdm import tqdm

import nudge

from nudge_train.artefacts import atomic_write_bytes, atomic_write_text, remove_stale_temps, sha256_bytes
from nudge_train.constants import DISTILL_SCHEMA
from nudge_train.data.st_io import CONTENT_HASH, add_content_hash, canonicalize, verify_content_hash
from nudge_train.errors import ArtefactError, ConfigError
from nudge_train.jsonio import load_json, loads_json
from nudge_train.provenance import sha256_file

from .config import DistillConfig
from .scenes import scene_interactive, scene_seed, split_scenes


@dataclass(frozen=True)
class ShardSpec:
    """One unit of work: ``scenes`` (paths) of ``split`` with their target-lane ``seeds``."""

    split: str
    index: int
    scenes: tuple[str, ...]
    seeds: tuple[int, ...]

    @property
    def file(self) -> str:
        return f"{self.split}-{self.index:05d}.safetensors"


def plan_shards(cfg: DistillConfig) -> dict[str, list[ShardSpec]]:
    """The shards of every split in ``cfg.splits`` (deterministic in ``cfg``)."""
    out: dict[str, list[ShardSpec]] = {}
    for split in cfg.splits:
        paths = split_scenes(cfg, split)
        specs = []
        for k, i in enumerate(range(0, len(paths), cfg.scenes_per_shard)):
            chunk = paths[i : i + cfg.scenes_per_shard]
            specs.append(ShardSpec(split, k, tuple(str(p) for p in chunk),
                                   tuple(scene_seed(cfg.seed, split, p.stem) for p in chunk)))
        out[split] = specs
    return out


def compute_shard(spec: ShardSpec, teacher: str, world: str, runs: int, max_steps: int, threads: int | None,
                  content_key: str, teacher_sha256: str) -> tuple[dict[str, np.ndarray], dict[str, str], dict]:
    """Runs one shard; returns its tensors, safetensors metadata and a summary dict."""
    t0 = time.perf_counter()
    world_model = teacher if world == "teacher" else None
    r = nudge.simulate(list(spec.scenes), teacher, world=world, world_predictor=world_model, scene_seeds=list(spec.seeds), runs=runs,
                       threads=threads, max_steps=max_steps, record=True, on_error="skip")
    wall = time.perf_counter() - t0
    ex, rr = r["examples"], r["runs"]
    n_runs = len(rr["scenario"])
    failed = np.array([e is not None for e in rr["error"]], dtype=np.uint8)
    agents = np.diff(ex["context_offsets"])[ex["example_context"]] if len(ex["example_context"]) else np.zeros(0, np.int64)
    tensors: dict[str, np.ndarray] = {
        "history": np.ascontiguousarray(ex["history"], dtype=np.float32),
        "context_offsets": ex["context_offsets"].astype(np.int64),
        "context_run": ex["context_run"].astype(np.int64),
        "example_context": ex["example_context"].astype(np.int64),
        "candidate": np.ascontiguousarray(ex["candidate"], dtype=np.float32),
        "prediction": np.ascontiguousarray(ex["prediction"], dtype=np.float32),
        "prediction_offsets": ex["prediction_offsets"].astype(np.int64),
        "run_scene": rr["scene_index"].astype(np.int64),
        "run_seed": rr["seed"].astype(np.int64),
        "run_target_lane": rr["target_lane"].astype(np.int64),
        "run_steps": rr["n_steps"].astype(np.int64),
        "run_success": rr["success"].astype(np.uint8),
        "run_collision": rr["collision"].astype(np.uint8),
        "run_failed": failed,
        "scene_interactive": np.array([scene_interactive(Path(p)) for p in spec.scenes], dtype=np.uint8),
        "scene_agents": np.array([nudge.Scenario.load(p).n_agents for p in spec.scenes], dtype=np.int64),
    }
    summary = {
        "file": spec.file,
        "scenes": len(spec.scenes),
        "runs": n_runs,
        "failed_runs": int(failed.sum()),
        "contexts": int(len(tensors["context_run"])),
        "examples": int(len(tensors["example_context"])),
        "duplicates": int(ex["duplicates"]),
        "steps": int(rr["n_steps"].sum()),
        "agents_hist": np.bincount(agents, minlength=48).tolist(),
        "interactive_examples": int(tensors["scene_interactive"][tensors["run_scene"][tensors["context_run"][
            tensors["example_context"]]]].sum()) if len(agents) else 0,
        "interactive_scenes": int(tensors["scene_interactive"].sum()),
        "wall_s": wall,
    }
    errors = sorted({e for e in rr["error"] if e is not None})
    meta = {
        "schema": DISTILL_SCHEMA,
        "split": spec.split,
        "shard": str(spec.index),
        "content_key": content_key,
        "teacher_sha256": teacher_sha256,
        "scenes": json.dumps([Path(p).stem for p in spec.scenes]),
        "seeds": json.dumps(list(spec.seeds)),
        "errors": json.dumps(errors),
        "summary": json.dumps({k: v for k, v in summary.items() if k != "wall_s"}),
    }
    return tensors, meta, summary


def shard_bytes(tensors: dict[str, np.ndarray], meta: dict[str, str]) -> bytes:
    """The file bytes of a shard: safetensors with the header in canonical order (identical in
    every process) and the ``content_sha256`` metadata entry."""
    return add_content_hash(canonicalize(save(tensors, metadata=meta)))


def _file_summary(data: bytes) -> dict:
    """What the manifest records about a shard's file: size, sha256, content hash."""
    meta = verify_content_hash(data, "<shard>")
    return {"bytes": len(data), "sha256": sha256_bytes(data), CONTENT_HASH: meta[CONTENT_HASH]}


def write_shard(path: Path, tensors: dict[str, np.ndarray], meta: dict[str, str]) -> dict:
    """Writes the shard temp-then-rename; returns its :func:`_file_summary`."""
    data = shard_bytes(tensors, meta)
    atomic_write_bytes(path, data)
    return _file_summary(data)


def verified_shard(path: Path) -> tuple[bytes, dict[str, str]]:
    """The bytes and metadata of an existing shard whose content hash checks out.

    Raises:
        ArtefactError: naming the file: unreadable, malformed, no content hash or a mismatch.
    """
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ArtefactError(path, f"cannot read: {err}") from None
    return data, verify_content_hash(data, path)


def complete_summary(path: Path, spec: ShardSpec, content_key: str) -> dict | None:
    """The summary of an existing complete shard for ``spec``: ``None`` if absent or written for
    other inputs (another content key or scene list).

    Raises:
        ArtefactError: the file exists but fails its content hash (it must not be kept).
    """
    if not path.exists():
        return None
    data, meta = verified_shard(path)
    if meta.get("content_key") != content_key or meta.get("scenes") != json.dumps([Path(p).stem for p in spec.scenes]):
        return None
    s = loads_json(meta["summary"], f"{path}: summary")
    s.update(_file_summary(data))
    s["wall_s"] = 0.0
    return s


def run_shard(spec: ShardSpec, out: Path, teacher: str, world: str, runs: int, max_steps: int, threads: int | None,
              content_key: str, teacher_sha256: str) -> dict:
    """Computes and writes one shard unless it is already complete; returns its summary."""
    path = out / spec.file
    try:
        done = complete_summary(path, spec, content_key)
    except ArtefactError:
        done = None  # damaged: regenerated below (generate() names it in the log)
    if done is not None:
        done["skipped"] = True
        return done
    tensors, meta, summary = compute_shard(spec, teacher, world, runs, max_steps, threads, content_key, teacher_sha256)
    summary.update(write_shard(path, tensors, meta))
    summary["skipped"] = False
    return summary


def _ray_map(specs: list[ShardSpec], ray_address: str | None, args: tuple) -> Iterable[dict]:
    """Fans shards out to Ray workers (one CPU each); each returns the shard's bytes, which the
    driver writes (so workers need the scenes and the teacher, not the output folder)."""
    import ray

    if not ray.is_initialized():
        ray.init(address=ray_address, log_to_driver=False)
    teacher, world, runs, max_steps, content_key, teacher_sha256 = args

    @ray.remote(num_cpus=1)
    def work(spec: ShardSpec) -> tuple[bytes, dict]:
        tensors, meta, summary = compute_shard(spec, teacher, world, runs, max_steps, 1, content_key, teacher_sha256)
        return shard_bytes(tensors, meta), summary

    pending = {work.remote(s): s for s in specs}
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        spec = pending.pop(ready[0])
        data, summary = ray.get(ready[0])
        yield spec, data, summary


def generate(cfg: DistillConfig, ray_address: str | None = None, use_ray: bool = False,
             log: Callable[[str], None] = print) -> dict:
    """Generates (or completes) the distillation set described by ``cfg``; returns the manifest.

    With ``use_ray`` or a ``ray_address``, shards run as Ray tasks (an already initialised Ray is
    used as is; otherwise ``ray.init(address=ray_address)``).
    """
    cfg.out.mkdir(parents=True, exist_ok=True)
    teacher = str(cfg.teacher)
    if not cfg.teacher.exists():
        raise FileNotFoundError(f"teacher weights not found: {cfg.teacher}")
    nudge.Predictor.load(teacher)  # fail early with WeightsError on a bad file
    teacher_sha = sha256_file(cfg.teacher)
    settings = nudge.PlannerSettings.default()
    # The closed loop's own defaults (the crawl reference, aborts, ...) shape the runs as much
    # as the planner's settings; world and max_steps come from cfg and are in the key already.
    sim_config = nudge.SimConfig.default()
    key = cfg.content_key(teacher_sha + settings.to_json() + sim_config.to_json())
    shards = plan_shards(cfg)
    manifest: dict = {
        "schema": DISTILL_SCHEMA,
        "content_key": key,
        "teacher": {"path": teacher, "sha256": teacher_sha, "noise": "the file's fixed_noise"},
        # The planner code that produced the data (not part of the content key, so that a
        # rebuild does not discard finished shards; regenerate after planner changes).
        "native": {"file": Path(nudge._native.__file__).name, "sha256": sha256_file(Path(nudge._native.__file__)),
                   "version": nudge.__version__},
        "planner_settings": settings.to_dict(),
        "sim_config": sim_config.to_dict(),
        "config": cfg.to_json(),
        "splits": {},
    }
    stale = remove_stale_temps(cfg.out)
    if stale:
        log(f"distill: removed {len(stale)} stale temp file(s) of an interrupted run: {', '.join(stale)}")
    previous_runs: list[dict] = []
    if (cfg.out / "manifest.json").exists():
        try:
            old = load_json(cfg.out / "manifest.json")
            if isinstance(old, dict) and old.get("content_key") == key:
                previous_runs = list(old.get("generation_runs", []))
        except (OSError, ConfigError) as err:
            log(f"distill: the previous manifest is unreadable ({err}); it is rebuilt from the shards")
            previous_runs = []
    todo: list[ShardSpec] = []
    replaced: list[str] = []
    results: dict[tuple[str, int], dict] = {}
    for split, specs in shards.items():
        for spec in specs:
            try:
                done = complete_summary(cfg.out / spec.file, spec, key)
            except ArtefactError as err:
                log(f"distill: {err}; regenerating {spec.file}")
                replaced.append(spec.file)
                done = None
            if done is None:
                todo.append(spec)
            else:
                done["skipped"] = True
                results[(split, spec.index)] = done
    # Interleave the splits so that an interrupted run has every split in proportion.
    n_of = {split: max(len(specs), 1) for split, specs in shards.items()}
    todo.sort(key=lambda s: ((s.index + 0.5) / n_of[s.split], cfg.splits.index(s.split)))
    n_scenes = sum(len(s.scenes) for s in todo)
    log(f"distill: {len(results)} shard(s) complete, {len(todo)} to run ({n_scenes} scenes)")

    def _write_manifest() -> None:
        for split, specs in shards.items():
            entries = [results[(split, s.index)] for s in specs if (split, s.index) in results]
            manifest["splits"][split] = {
                "scenes": [Path(p).stem for s in specs for p in s.scenes],
                "scene_seeds": [x for s in specs for x in s.seeds],
                "shards_planned": len(specs),
                "shards": [{k: v for k, v in e.items() if k not in ("skipped", "wall_s", "agents_hist")} for e in entries],
                "examples": sum(e["examples"] for e in entries),
                "contexts": sum(e["contexts"] for e in entries),
                "interactive_examples": sum(e["interactive_examples"] for e in entries),
                "interactive_scenes": sum(e["interactive_scenes"] for e in entries),
                "agents_hist": np.sum([e["agents_hist"] for e in entries], axis=0).tolist() if entries else [],
                "complete": len(entries) == len(specs),
            }
        atomic_write_text(cfg.out / "manifest.json", json.dumps(manifest, indent=1))

    t0 = time.perf_counter()
    made = 0
    bar = tqdm(total=n_scenes, unit="scene", desc="distill", disable=not cfg.progress, smoothing=0.1)
    try:
        if use_ray or ray_address is not None:
            it = _ray_map(todo, ray_address, (teacher, cfg.world, cfg.runs, cfg.max_steps, key, teacher_sha))
            for spec, data, summary in it:
                atomic_write_bytes(cfg.out / spec.file, data)
                summary.update(_file_summary(data))
                results[(spec.split, spec.index)] = summary
                made += summary["examples"]
                bar.update(len(spec.scenes))
                bar.set_postfix(examples=made, ex_per_s=f"{made / (time.perf_counter() - t0):.0f}")
                _write_manifest()
        else:
            for spec in todo:
                summary = run_shard(spec, cfg.out, teacher, cfg.world, cfg.runs, cfg.max_steps, cfg.threads, key,
                                    teacher_sha)
                results[(spec.split, spec.index)] = summary
                made += summary["examples"] if not summary["skipped"] else 0
                bar.update(len(spec.scenes))
                bar.set_postfix(examples=made, ex_per_s=f"{made / (time.perf_counter() - t0):.0f}")
                _write_manifest()
    finally:
        bar.close()
    _write_manifest()
    wall = time.perf_counter() - t0
    this_run = {"examples": made, "wall_s": wall, "examples_per_s": made / wall if wall > 0 else 0.0,
                "ray": bool(use_ray or ray_address is not None), "replaced": replaced}
    manifest["last_run"] = this_run
    # Every invocation that generated shards, so a resume keeps the earlier throughput.
    manifest["generation_runs"] = previous_runs + ([this_run] if made else [])
    atomic_write_text(cfg.out / "manifest.json", json.dumps(manifest, indent=1))
    return manifest


def load_shard(path: Path) -> dict[str, np.ndarray]:
    """A shard's tensors (see docs/distill.md for the layout), after checking its content hash.

    Raises:
        ArtefactError: naming the file when it fails the check (see :func:`verified_shard`).
    """
    data, _ = verified_shard(Path(path))
    return load_bytes(data)
