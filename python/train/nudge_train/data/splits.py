"""Seeded train/val/test assignment of independent groups (US-101 overlap groups, I-80 blocks).

Never by window: every window inherits the split of its group, so vehicles cannot leak.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DataError

EXCLUDED_SCENES = ("USA_US101-3_5_T-1",)
"""Scenes never used: 3_5 was altered by CommonRoad's criticality optimisation (PROVENANCE.md)."""


@dataclass(frozen=True)
class SplitConfig:
    """Fractions follow the paper: test = test_frac of all, val = val_frac of the rest."""

    seed: int = 0
    test_frac: float = 0.2
    val_frac: float = 0.1
    i80_block_s: float = 60.0
    tries: int = 2000


def read_overlap_groups(path: Path) -> dict[int, int]:
    """Scene number -> overlap_group from commonroad_us101_scene_overlap_groups.csv.

    Raises:
        DataError: naming the file (and row) when it is missing, unreadable, lacks the columns,
        holds a non-integer value, or lists one scene twice with different groups.
    """
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataError(path, f"cannot read: {exc}") from exc
    if not rows:
        raise DataError(path, "empty file")
    head = rows[0]
    for col in ("scene", "overlap_group"):
        if col not in head:
            raise DataError(path, f"missing column {col!r} (have {head})", row=1)
    si, gi = head.index("scene"), head.index("overlap_group")
    out: dict[int, int] = {}
    for r, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        try:
            scene, group = int(row[si]), int(row[gi])
        except (ValueError, IndexError) as exc:
            raise DataError(path, f"bad scene/overlap_group value: {row}", row=r) from exc
        if scene in out and out[scene] != group:
            raise DataError(path, f"scene {scene} listed twice (overlap groups {out[scene]} and {group})", row=r,
                            field="overlap_group")
        out[scene] = group
    return out


MIN_GROUPS = 3
"""A train/val/test split needs at least this many independent groups."""

TOO_FEW_GROUPS = "too_few_groups"
"""Rule name of the decision taken for fewer than MIN_GROUPS groups: every unit to test."""


def assign_or_test(weights: dict[str, float], cfg: SplitConfig, salt: int, what: str) -> tuple[dict[str, str], str]:
    """:func:`assign` when there are at least :data:`MIN_GROUPS` groups; otherwise every group to
    ``test`` (nothing of this family is trained on, so nothing can leak) and the decision as a
    sentence naming ``what`` (e.g. "US-101 overlap group"); the note is "" when split normally."""
    if len(weights) >= MIN_GROUPS:
        return assign(weights, cfg, salt), ""
    note = (f"only {len(weights)} {what}(s): every unit to test "
            f"(a train/val/test split needs at least {MIN_GROUPS} independent groups)")
    return {k: "test" for k in weights}, note


SCENE_RE = re.compile(r"USA_US101-(\d+)_(\d+)")


def scene_number(benchmark_id: str) -> tuple[int, int]:
    """(scene, variant) of a CommonRoad US-101 benchmark id, e.g. USA_US101-22_1_T-1 -> (22, 1)."""
    m = SCENE_RE.search(benchmark_id)
    if m is None:
        raise ValueError(f"not a US-101 benchmark id: {benchmark_id!r}")
    return int(m.group(1)), int(m.group(2))


def assign(weights: dict[str, float], cfg: SplitConfig, salt: int) -> dict[str, str]:
    """Assign groups (key -> weight, e.g. window count) to train/val/test.

    Deterministic: ``cfg.tries`` seeded permutations of the sorted keys; in each, a prefix goes to
    test, the next run to val, the rest to train; the permutation whose weight fractions are
    closest to (test_frac, val_frac of the rest) wins (first one on ties).
    """
    keys = sorted(weights)
    if len(keys) < MIN_GROUPS:
        raise ValueError(f"need at least {MIN_GROUPS} groups to split, got {len(keys)}")
    w = np.asarray([weights[k] for k in keys], dtype=np.float64)
    if not (np.all(np.isfinite(w)) and np.all(w >= 0)):
        raise ValueError(f"group weights must be finite and non-negative, got {w.tolist()}")
    total = float(w.sum())
    if total <= 0:  # every group empty: split by count
        w = np.ones_like(w)
        total = float(w.sum())
    target_test = cfg.test_frac
    target_val = cfg.val_frac * (1.0 - cfg.test_frac)
    rng = np.random.default_rng([cfg.seed, salt])
    best: tuple[float, np.ndarray, int, int] | None = None
    for _ in range(cfg.tries):
        perm = rng.permutation(len(keys))
        cum = np.cumsum(w[perm]) / total
        for nt in range(1, len(keys) - 1):
            ft = cum[nt - 1]
            for nv in range(1, len(keys) - nt):
                fv = cum[nt + nv - 1] - ft
                err = abs(ft - target_test) + abs(fv - target_val)
                if best is None or err < best[0] - 1e-12:
                    best = (err, perm.copy(), nt, nv)
    assert best is not None
    _, perm, nt, nv = best
    out = {}
    for rank, i in enumerate(perm):
        out[keys[i]] = "test" if rank < nt else ("val" if rank < nt + nv else "train")
    return out
