"""The distillation set grouped by planner call (context): one scene history, every candidate the
planner evaluated for it, the teacher's prediction under each, and the lanes of the scene.

:func:`nudge_train.data.loader.load_distill_split` flattens the set into windows (one per
example) for position training; the reaction measures and the reaction loss need the grouping
back, because a reaction is a difference between two candidates of the SAME history.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from safetensors import safe_open

from nudge_train.data.loader import _shards_of
from nudge_train.data.st_io import load_verified_shard
from nudge_train.jsonio import load_json, loads_json

__all__ = ["Context", "load_contexts"]


@dataclass(frozen=True)
class Context:
    """One planner call of the distillation set (positions in the scene's road frame, metres,
    0.3 s steps; x along the road, y to the left).

    ``history`` ``[N, 8, 2]`` (row 0 = ego), ``candidates`` ``[M, 6, 2]`` (ego positions at steps
    1..6), ``teacher`` ``[M, N - 1, 6, 2]`` (the teacher's prediction of rows 1..N-1 under each
    candidate), ``lane_bounds`` ``[L + 1]`` ascending lateral lane boundaries (m), ``target_lane``
    index into the lanes (0 = lowest y), ``scene`` the scene file's name, ``interactive`` the
    scene's flag (a logged vehicle changes lane).
    """

    history: np.ndarray
    candidates: np.ndarray
    teacher: np.ndarray
    lane_bounds: np.ndarray
    target_lane: int
    scene: str
    interactive: bool


def _lane_bounds(scenes_root: Path, split: str, name: str, cache: dict[str, np.ndarray]) -> np.ndarray:
    if name not in cache:
        import nudge

        path = scenes_root / split / f"{name}.safetensors"
        cache[name] = np.asarray(nudge.Scenario.load(path).lane_bounds, dtype=np.float64)
    return cache[name]


def load_contexts(distill_dir: Path, split: str, scenes_root: Path, max_contexts: int | None = None) -> list[Context]:
    """Every context of ``split`` of the distillation set at ``distill_dir`` (shards checked
    against the manifest's sha256), with the lane bounds of its scene read from
    ``scenes_root/<split>/<scene>.safetensors``. ``max_contexts``: only the first ones (shard order).

    Raises:
        FileNotFoundError: the manifest, a shard or a scene file is missing.
        ArtefactError: a shard fails its sha256 check.
        ValueError: the split is absent or a shard's tensors are inconsistent (naming the shard).
    """
    manifest_path = Path(distill_dir) / "manifest.json"
    manifest = load_json(manifest_path)
    out: list[Context] = []
    lanes: dict[str, np.ndarray] = {}
    for entry in _shards_of(manifest, split, manifest_path):
        path, t = load_verified_shard(manifest_path, entry)
        with safe_open(str(path), "np") as f:
            names = loads_json(f.metadata().get("scenes", "null"), f"{path}: scenes")
        if not isinstance(names, list):
            raise ValueError(f"{path}: no 'scenes' list in the metadata")
        coff = t["context_offsets"].astype(np.int64)
        ex_ctx = t["example_context"].astype(np.int64)
        poff = t["prediction_offsets"].astype(np.int64)
        run_of = t["context_run"].astype(np.int64)
        if len(ex_ctx) and np.any(np.diff(ex_ctx) < 0):
            raise ValueError(f"{path}: examples are not grouped by context")
        starts = np.searchsorted(ex_ctx, np.arange(len(coff)))  # first example of each context
        for c in range(len(coff) - 1):
            e0, e1 = int(starts[c]), int(starts[c + 1])
            if e1 == e0:
                continue
            n = int(coff[c + 1] - coff[c])
            pred = t["prediction"][poff[e0] : poff[e1]].astype(np.float32)
            if pred.shape[0] != (e1 - e0) * (n - 1):
                raise ValueError(f"{path}: context {c}: {pred.shape[0]} prediction rows, expected {(e1 - e0) * (n - 1)}")
            run = int(run_of[c])
            scene_i = int(t["run_scene"][run])
            name = str(names[scene_i])
            out.append(Context(
                history=t["history"][coff[c] : coff[c + 1]].astype(np.float32),
                candidates=t["candidate"][e0:e1].astype(np.float32),
                teacher=pred.reshape(e1 - e0, n - 1, 6, 2),
                lane_bounds=_lane_bounds(Path(scenes_root), split, name, lanes),
                target_lane=int(t["run_target_lane"][run]),
                scene=name,
                interactive=bool(t["scene_interactive"][scene_i]),
            ))
            if max_contexts is not None and len(out) >= max_contexts:
                return out
    return out
