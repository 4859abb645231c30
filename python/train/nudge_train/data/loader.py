"""Training windows in memory: the processed shards of one split, batched into scenes.

The build side (:mod:`nudge_train.data.windows`) cuts windows out of the NGSIM tracks and
:mod:`nudge_train.data.build` writes them as shards; this module reads them back for training
and evaluation. A :class:`WindowSet` holds every window of one split as flat arrays (the layout
of the processed shards, docs/data_schema.md): ``positions`` ``[A, 14, 2]`` (m, road frame, 0.3 s
steps, 8 observed + 6 future), ``offsets`` ``[W + 1]`` (window ``w`` = agents
``offsets[w]:offsets[w+1]``, its first agent is its ego), ``interactive`` ``[W]``. The
distillation set (``nudge.distill/1``) is read into the same layout. Batches are translated so
that every window's ego sits at the origin at its last observed step: the networks are
translation invariant and float32 keeps more precision near 0.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nudge_train.constants import DISTILL_SCHEMA, OBS_LEN, PRED_LEN
from nudge_train.jsonio import load_json

from .st_io import load_verified_shard

__all__ = ["Batch", "WindowSet", "load_distill_split", "load_split"]


@dataclass(frozen=True)
class Batch:
    """One batch of scenes, ready for the generator.

    ``obs`` ``[8, A, 2]`` and ``fut`` ``[6, A, 2]`` positions (m), ``seq_start_end`` ``[S, 2]``,
    ``interactive`` ``[S]`` bool, ``window`` ``[S]`` indices into the :class:`WindowSet`.
    """

    obs: torch.Tensor
    fut: torch.Tensor
    seq_start_end: torch.Tensor
    interactive: torch.Tensor
    window: np.ndarray

    def to(self, device: torch.device | str) -> Batch:
        """The batch on ``device``."""
        return Batch(
            self.obs.to(device),
            self.fut.to(device),
            self.seq_start_end.to(device),
            self.interactive.to(device),
            self.window,
        )


@dataclass
class WindowSet:
    """All windows of one split (see module doc for the layout)."""

    positions: np.ndarray
    offsets: np.ndarray
    interactive: np.ndarray
    pred_len: int = PRED_LEN
    """Future steps per window (the build's ``window.n_fut``; 6 unless built longer)."""

    def __post_init__(self) -> None:
        steps = OBS_LEN + self.pred_len
        if self.pred_len < 1 or self.positions.ndim != 3 or self.positions.shape[1:] != (steps, 2):
            raise ValueError(f"positions: expected [A, {steps}, 2], got {list(self.positions.shape)}")
        if self.offsets.ndim != 1 or self.offsets[0] != 0 or self.offsets[-1] != len(self.positions):
            raise ValueError("offsets: must start at 0 and end at the agent count")
        if np.any(np.diff(self.offsets) <= 0):
            raise ValueError("offsets: every window needs at least one agent")
        if len(self.interactive) != len(self):
            raise ValueError("interactive: one flag per window expected")
        if not np.all(np.isfinite(self.positions)):
            raise ValueError("positions: non-finite values")

    def __len__(self) -> int:
        return len(self.offsets) - 1

    @property
    def n_agents(self) -> int:
        """Total agents over all windows."""
        return int(self.offsets[-1])

    def subset(self, windows: np.ndarray) -> WindowSet:
        """The windows at the given indices, in that order."""
        parts = [self.positions[self.offsets[w] : self.offsets[w + 1]] for w in windows]
        sizes = np.array([len(p) for p in parts], dtype=np.int64)
        return WindowSet(
            positions=np.concatenate(parts) if parts else np.zeros((0, OBS_LEN + self.pred_len, 2), np.float32),
            offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
            interactive=self.interactive[windows].copy(),
            pred_len=self.pred_len,
        )

    def batch(self, windows: np.ndarray) -> Batch:
        """Scenes ``windows`` as one :class:`Batch`, each translated so its ego ends at (0, 0)."""
        parts = []
        sse = []
        start = 0
        for w in windows:
            p = self.positions[self.offsets[w] : self.offsets[w + 1]].astype(np.float32)
            p = p - p[0, OBS_LEN - 1]
            parts.append(p)
            sse.append((start, start + len(p)))
            start += len(p)
        traj = torch.from_numpy(np.concatenate(parts)).transpose(0, 1).contiguous()  # [14, A, 2]
        return Batch(
            obs=traj[:OBS_LEN].contiguous(),
            fut=traj[OBS_LEN:].contiguous(),
            seq_start_end=torch.tensor(sse, dtype=torch.int64),
            interactive=torch.from_numpy(self.interactive[windows].astype(bool)),
            window=np.asarray(windows),
        )

    def batches(
        self, batch_size: int, shuffle: bool, generator: torch.Generator | None = None, limit: int | None = None
    ) -> Iterator[Batch]:
        """Batches of ``batch_size`` scenes (the last may be smaller); seeded shuffle. ``limit``:
        only the first ``limit`` windows of the (shuffled) order, a random subset per call."""
        order = (
            torch.randperm(len(self), generator=generator).numpy() if shuffle else np.arange(len(self))
        )
        if limit is not None:
            order = order[:limit]
        for i in range(0, len(order), batch_size):
            yield self.batch(order[i : i + batch_size])


def load_split(manifest_path: Path, split: str, max_windows: int | None = None) -> WindowSet:
    """Reads every shard of ``split`` listed in the processed-data manifest (``nudge.dataset/1``)
    or in a distillation-set manifest (``nudge.distill/1``, see :func:`load_distill_split`).
    Every shard is checked against the sha256 the manifest records for it before it is used.

    Raises:
        FileNotFoundError: the manifest or a shard is missing (the path is in the message).
        ArtefactError: a shard's sha256 differs from the manifest's (modified or damaged), none is
            recorded, or the shard cannot be parsed (naming the shard).
        ConfigError: the manifest is not valid JSON or repeats a key.
        ValueError: the manifest has no such split or a shard is malformed.
    """
    manifest_path = Path(manifest_path)
    if manifest_path.is_dir():
        manifest_path = manifest_path / "manifest.json"
    if not manifest_path.exists():
        raise FileNotFoundError(f"processed-data manifest not found: {manifest_path} (run `make data`)")
    manifest = load_json(manifest_path)
    if not isinstance(manifest, dict):
        raise ValueError(f"{manifest_path}: not a manifest (expected a JSON object)")
    if manifest.get("schema") == DISTILL_SCHEMA:
        ws = load_distill_split(manifest_path, manifest, split)
        if max_windows is not None and len(ws) > max_windows:
            ws = ws.subset(np.arange(max_windows))
        return ws
    shards = _shards_of(manifest, split, manifest_path)
    pos, offs, inter = [], [np.zeros(1, np.int64)], []
    base = 0
    for entry in shards:
        path, t = load_verified_shard(manifest_path, entry)
        for key in ("positions", "offsets", "interactive"):
            if key not in t:
                raise ValueError(f"{path}: missing tensor {key!r}")
        pos.append(t["positions"].astype(np.float32))
        offs.append(t["offsets"][1:].astype(np.int64) + base)
        inter.append(t["interactive"].astype(np.uint8))
        base += len(t["positions"])
    if not pos:
        raise ValueError(f"{manifest_path}: split {split!r} has no shards")
    window = manifest.get("config", {}).get("window", {})
    pred_len = int(window.get("n_fut", PRED_LEN)) if isinstance(window, dict) else PRED_LEN
    ws = WindowSet(np.concatenate(pos), np.concatenate(offs), np.concatenate(inter), pred_len)
    if max_windows is not None and len(ws) > max_windows:
        ws = ws.subset(np.arange(max_windows))
    return ws


def _shards_of(manifest: dict, split: str, path: Path) -> list[dict]:
    splits = manifest.get("splits")
    if not isinstance(splits, dict):
        raise ValueError(f"{path}: no 'splits' table (not a nudge processed-data manifest?)")
    if split not in splits:
        raise ValueError(f"{path}: no split {split!r} (has {sorted(splits)})")
    entries = splits[split].get("shards", []) if isinstance(splits[split], dict) else None
    ok = isinstance(entries, list) and all(isinstance(e, dict) and isinstance(e.get("file"), str) for e in entries)
    if not ok:
        raise ValueError(f"{path}: split {split!r}: 'shards' must be a list of {{file, sha256, ...}} entries")
    return entries


def load_distill_split(manifest_path: Path, manifest: dict, split: str) -> WindowSet:
    """The distillation examples of ``split`` as windows (docs/distill.md).

    Example ``e`` of context ``c`` becomes one window of the context's agents (ego first):
    observed = the context's ``history`` ``[n, 8, 2]``; "future" = the ego candidate (row 0) and
    the teacher's prediction of the other ``n - 1`` agents under it. A student trained on these
    windows with the ego imposed (``ego_future`` = the candidate) learns the teacher's reaction.
    ``interactive`` is the flag of the example's scene. Only the shards listed as complete in the
    manifest are read, each checked against the sha256 the manifest records for it.

    Raises:
        FileNotFoundError: a listed shard is missing. ArtefactError: a shard fails its sha256
        check. ValueError: the split is absent or empty, or a shard's tensors are inconsistent.
    """
    shards = _shards_of(manifest, split, manifest_path)
    parts: list[np.ndarray] = []
    offs: list[np.ndarray] = [np.zeros(1, np.int64)]
    inter: list[np.ndarray] = []
    base = 0
    for entry in shards:
        path, t = load_verified_shard(manifest_path, entry)
        need = ("history", "context_offsets", "context_run", "example_context", "candidate", "prediction",
                "prediction_offsets", "run_scene", "scene_interactive")
        for key in need:
            if key not in t:
                raise ValueError(f"{path}: missing tensor {key!r}")
        if len(t["example_context"]) == 0:
            continue
        hist, coff = t["history"].astype(np.float32), t["context_offsets"].astype(np.int64)
        ex_ctx, poff = t["example_context"].astype(np.int64), t["prediction_offsets"].astype(np.int64)
        n_ctx = coff[1:] - coff[:-1]  # agents per context
        n_ex = n_ctx[ex_ctx]  # agents per example
        if not np.array_equal(poff[1:] - poff[:-1], n_ex - 1):
            raise ValueError(f"{path}: prediction_offsets do not match the context sizes")
        # Row r of the output = agent (r - start of its example) of the example's context.
        starts = np.concatenate([[0], np.cumsum(n_ex)])
        ex_of_row = np.repeat(np.arange(len(ex_ctx)), n_ex)
        local = np.arange(starts[-1]) - starts[ex_of_row]
        pos = np.empty((starts[-1], OBS_LEN + PRED_LEN, 2), np.float32)
        pos[:, :OBS_LEN] = hist[coff[ex_ctx][ex_of_row] + local]
        ego = local == 0
        pos[ego, OBS_LEN:] = t["candidate"].astype(np.float32)
        pos[~ego, OBS_LEN:] = t["prediction"].astype(np.float32)[poff[ex_of_row[~ego]] + local[~ego] - 1]
        parts.append(pos)
        offs.append(starts[1:] + base)
        scene = t["run_scene"][t["context_run"][ex_ctx]]
        inter.append(t["scene_interactive"][scene].astype(np.uint8))
        base += starts[-1]
    if not parts:
        raise ValueError(f"{manifest_path}: split {split!r} has no examples yet")
    return WindowSet(np.concatenate(parts), np.concatenate(offs), np.concatenate(inter))
