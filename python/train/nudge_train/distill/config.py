"""Configuration of the distillation-data generator."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

from nudge_train import paths
from nudge_train.constants import DISTILL_SCHEMA, SPLITS

# Scenes per split of the size presets. "paper" aims at the paper's 568k / 113k / 116k examples:
# measured 368.7k / 73.5k / 50.8k examples from the first 213 / 40 / 37 scenes of the curvilinear-frame
# splits with the planner of 2026-11 (docs/distill.md), scaled, with ~4 % to spare.
# Sizes are nested (a prefix of the same seeded scene order), so "paper" extends "first".
# "all" uses every scene of every split.
SIZES: dict[str, dict[str, int | None]] = {
    "tiny": {"train": 4, "val": 2, "test": 2},
    "small": {"train": 32, "val": 8, "test": 8},
    "first": {"train": 120, "val": 24, "test": 24},
    "paper": {"train": 340, "val": 64, "test": 88},
    "all": {"train": None, "val": None, "test": None},
}


@dataclass(frozen=True)
class DistillConfig:
    """What to generate and where.

    ``max_scenes``: scenes per split (``None`` = every scene of the split); the subset is drawn
    with ``seed`` and is the same on every rerun. ``runs``: closed-loop runs per scene (run ``r``
    of a scene draws its target lane from the scene's seed + r). ``world``: how the other
    vehicles move (``"teacher"`` = the teacher's one-step interactive prediction,
    ``"log_replay"`` = the logged future). ``threads``: rayon threads per shard.
    """

    out: Path = field(default_factory=paths.distill)
    splits: tuple[str, ...] = SPLITS
    teacher: Path = field(default_factory=lambda: paths.model_weights("teacher"))
    scenes_root: Path = field(default_factory=lambda: paths.processed() / "scenes")
    processed: Path = field(default_factory=paths.processed)
    data_root: Path = field(default_factory=paths.ngsim)
    max_scenes: dict[str, int | None] = field(default_factory=lambda: dict(SIZES["paper"]))
    runs: int = 1
    seed: int = 0
    world: str = "teacher"
    max_steps: int = 30
    scenes_per_shard: int = 8
    threads: int | None = None
    progress: bool = True

    def __post_init__(self) -> None:
        for s in self.splits:
            if s not in SPLITS:
                raise ValueError(f"splits: unknown split {s!r} (expected one of {SPLITS})")
        if self.runs < 1:
            raise ValueError(f"runs: must be at least 1, got {self.runs}")
        if self.scenes_per_shard < 1:
            raise ValueError(f"scenes_per_shard: must be at least 1, got {self.scenes_per_shard}")
        if self.world not in ("teacher", "log_replay"):
            raise ValueError(f"world: expected 'teacher' or 'log_replay', got {self.world!r}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps: must be at least 1, got {self.max_steps}")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads: must be at least 1, got {self.threads}")
        for s, n in self.max_scenes.items():
            if n is not None and n < 1:
                raise ValueError(f"max_scenes[{s!r}]: must be at least 1 or None, got {n}")

    def content_key(self, teacher_sha256: str) -> str:
        """Hash of everything that determines shard contents (not paths, threads or progress)."""
        key = {
            "teacher": teacher_sha256,
            "runs": self.runs,
            "seed": self.seed,
            "world": self.world,
            "max_steps": self.max_steps,
            "scenes_per_shard": self.scenes_per_shard,
            "schema": DISTILL_SCHEMA,
        }
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]

    def to_json(self) -> dict:
        d = asdict(self)
        return {k: (str(v) if isinstance(v, Path) else list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


def parse_size(text: str) -> dict[str, int | None]:
    """Scenes per split from a preset name of :data:`SIZES` (tiny, small, first, paper, all) or
    ``train=N,val=N,test=N`` (N or ``all``; splits not named keep the ``paper`` size).

    Raises:
        ValueError: neither a preset nor ``split=N`` items.
    """
    if text in SIZES:
        return dict(SIZES[text])
    out: dict[str, int | None] = dict(SIZES["paper"])
    for part in text.split(","):
        k, sep, v = part.partition("=")
        if not sep or k.strip() not in SPLITS:
            raise ValueError(f"bad size {part!r}: expected a preset {sorted(SIZES)} or split=N")
        out[k.strip()] = None if v.strip() == "all" else int(v)
    return out
