"""Scenario source of the generator: the planner scenarios ("nudge.scenario/1") of each split,
written by the data pipeline's scenario writer (:func:`nudge_train.data.scene_cmd.write_scenes`)
with the split assignment of the processed dataset, plus a per-scene interactive flag."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numpy as np
from safetensors import safe_open
from safetensors.numpy import load_file

from ..constants import SPLITS
from ..data.windows import WindowConfig
from ..jsonio import load_json
from .config import DistillConfig

SCENES_DONE = ".complete"


def _split_config(processed: Path) -> object:
    """The SplitConfig the processed dataset was built with (so scene splits match its windows)."""
    from ..data.splits import SplitConfig

    manifest = processed / "manifest.json"
    if not manifest.exists():
        return SplitConfig()
    cfg = load_json(manifest).get("config", {}).get("split", {})
    known = set(SplitConfig.__dataclass_fields__)
    return SplitConfig(**{k: v for k, v in cfg.items() if k in known})


def ensure_scenes(cfg: DistillConfig, split: str) -> Path:
    """The scenario folder of ``split`` (``cfg.scenes_root/<split>``), written by the data
    pipeline if missing. Writing goes to a temporary folder renamed when complete."""
    out = cfg.scenes_root / split
    if out.is_dir() and any(out.glob("*.safetensors")):
        return out
    from ..data.scene_cmd import ScenesConfig, write_scenes

    tmp = cfg.scenes_root / f".{split}.tmp-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    write_scenes(cfg.data_root, tmp, ScenesConfig(split=split), _split_config(cfg.processed),  # type: ignore[arg-type]
                 progress=cfg.progress)
    (tmp / SCENES_DONE).write_text("")
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    return out


def scene_split(path: Path) -> str:
    """The split recorded in a scenario file's metadata."""
    with safe_open(str(path), "numpy") as f:
        return (f.metadata() or {}).get("split", "")


def split_scenes(cfg: DistillConfig, split: str) -> list[Path]:
    """The scenes of ``split`` the generator uses, in a seeded random order (a permutation of the
    name-sorted files drawn with ``cfg.seed``), cut to ``cfg.max_scenes[split]`` if set. Sizes are
    nested: a larger size extends a smaller one, so its shards stay valid.

    Raises:
        ValueError: a scene file's metadata names another split (the folder is stale).
    """
    folder = ensure_scenes(cfg, split)
    paths = sorted(folder.glob("*.safetensors"))
    order = np.random.default_rng([cfg.seed, SPLITS.index(split)]).permutation(len(paths))
    paths = [paths[i] for i in order]
    n = cfg.max_scenes.get(split)
    if n is not None:
        paths = paths[:n]
    for p in paths:
        s = scene_split(p)
        if s != split:
            raise ValueError(f"{p}: scenario of split {s!r} found in the {split!r} folder (rebuild the scenes)")
    return paths


def scene_seed(seed: int, split: str, stem: str) -> int:
    """The target-lane seed of one scene: a 63-bit hash of (seed, split, file stem), so it does not
    depend on which shard or subset the scene lands in."""
    h = hashlib.sha256(f"{seed}:{split}:{stem}".encode()).digest()
    return int.from_bytes(h[:8], "little") >> 1


def scene_interactive(path: Path, cfg: WindowConfig = WindowConfig()) -> bool:
    """The processed-window notion of an interactive scene, on a scenario file: some vehicle
    (ego included) changes lane between its first observed step and its last valid step of
    the first ``n_fut`` logged future steps, moving at least ``lane_change_min_dy`` laterally."""
    t = load_file(str(path))
    hist = t["history"]
    fut = t["future"][:, : cfg.n_fut]
    valid = t["future_valid"][:, : cfg.n_fut].astype(bool)
    bounds = t["lane_bounds"]
    y0 = hist[:, 0, 1]
    last_valid = np.where(valid.any(axis=1), valid.shape[1] - 1 - np.argmax(valid[:, ::-1], axis=1), -1)
    y1 = np.where(last_valid >= 0, fut[np.arange(len(fut)), np.maximum(last_valid, 0), 1], hist[:, -1, 1])
    lane0 = np.searchsorted(bounds, y0, side="right") - 1
    lane1 = np.searchsorted(bounds, y1, side="right") - 1
    inside = (lane0 >= 0) & (lane0 < len(bounds) - 1) & (lane1 >= 0) & (lane1 < len(bounds) - 1)
    change = inside & (lane0 != lane1) & (np.abs(y1 - y0) >= cfg.lane_change_min_dy)
    return bool(change.any())
