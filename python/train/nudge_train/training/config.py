"""Training configuration: the ``[model]`` and ``[train]`` tables of a TOML training config.

A config file (``python/train/configs/*.toml``) has a ``[model]`` table (``kind`` picks the teacher
or student defaults of :mod:`nudge_train.models.config`, any other :class:`ModelConfig` field
overrides them) and a ``[train]`` table (:class:`TrainConfig`); unknown tables or keys and
impossible values are refused. ``nudge-train train --config FILE`` trains one.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from nudge_train.constants import PRED_LEN
from nudge_train.models.config import ModelConfig, student_config, teacher_config

__all__ = ["TrainConfig", "load_config"]


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings of one training run."""

    data: str = "data/processed"
    """Processed-data directory (holds manifest.json) or the manifest itself."""
    out_dir: str = "runs/teacher"
    """Where checkpoints, metrics and the exported weights go."""
    k_var: float = 1.0
    """Weight of the variety loss."""
    i_adv: int = 0
    """1 = add the adversarial loss (trains a discriminator), 0 = regression only."""
    k_samples: int = 20
    """Draws of z per scene in the best-of-k variety loss (1 for a noise-free student)."""
    lr: float = 1e-3
    """Adam learning rate of the generator (and discriminator) at the first epoch."""
    lr_schedule: str = "cosine"
    """``"cosine"``: lr decays over ``epochs`` to ``lr_final_fraction`` · lr; ``"constant"``."""
    lr_final_fraction: float = 0.05
    """Final lr as a fraction of ``lr`` for the cosine schedule."""
    batch_size: int = 64
    """Scenes per batch."""
    epochs: int = 60
    """Maximum epochs."""
    patience: int = 10
    """Early stopping: epochs without a validation-ADE improvement."""
    train_steps: int = PRED_LEN
    """Future steps decoded (and supervised) per training call."""
    val_metric: str = "ade"
    """Early-stopping / selection metric on the validation split: ``"ade"`` (single-sample ADE
    over ``train_steps`` decoded steps) or ``"recursive_fde"`` (single-sample FDE at 1.8 s of the
    planner's recursive use: 6 one-step calls, egos on their logged future)."""
    clip_grad: float = 1.0
    """Gradient-norm clipping threshold (0 = off)."""
    seed: int = 0
    """Seed of shuffling, noise and initialisation offsets."""
    device: str = "auto"
    """``"auto"`` (CUDA when present, else CPU), ``"cpu"``, ``"cuda"``, ``"cuda:1"``, ..."""
    max_train_windows: int = 0
    """Use only the first N training windows (0 = all): for smoke runs."""
    max_val_windows: int = 0
    """Validate on N evenly spaced validation windows (0 = all)."""
    samples_per_epoch: int = 0
    """Windows drawn (seeded, without replacement) per epoch; 0 = every training window. For sets
    of many near-duplicate windows such as the distillation set (~100 candidates per context)."""
    threads: int = 0
    """torch CPU threads (0 = torch default)."""

    def validate(self) -> TrainConfig:
        """Raises ValueError naming the first impossible field."""
        checks = [
            ("k_var", self.k_var >= 0 and math.isfinite(self.k_var)),
            ("i_adv", self.i_adv in (0, 1)),
            ("k_samples", self.k_samples >= 1),
            ("lr", self.lr > 0 and math.isfinite(self.lr)),
            ("lr_schedule", self.lr_schedule in ("cosine", "constant")),
            ("lr_final_fraction", 0 < self.lr_final_fraction <= 1),
            ("batch_size", self.batch_size >= 1),
            ("epochs", self.epochs >= 1),
            ("patience", self.patience >= 1),
            ("train_steps", 1 <= self.train_steps <= PRED_LEN),
            ("clip_grad", self.clip_grad >= 0),
            ("val_metric", self.val_metric in ("ade", "recursive_fde")),
            ("max_train_windows", self.max_train_windows >= 0),
            ("max_val_windows", self.max_val_windows >= 0),
            ("samples_per_epoch", self.samples_per_epoch >= 0),
            ("threads", self.threads >= 0),
        ]
        for name, ok in checks:
            if not ok:
                raise ValueError(f"train.{name}: impossible value {getattr(self, name)!r}")
        if self.k_var == 0 and self.i_adv == 0:
            raise ValueError("train: k_var = 0 and i_adv = 0 leave nothing to minimise")
        return self


def load_config(path: Path) -> tuple[ModelConfig, TrainConfig]:
    """Reads a TOML training config: ``[model]`` (``kind`` picks the teacher/student defaults,
    other keys override sizes) and ``[train]``. Unknown tables or keys raise ValueError."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"training config not found: {path}") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{path}: invalid TOML: {err}") from None
    unknown = set(raw) - {"model", "train"}
    if unknown:
        raise ValueError(f"{path}: unknown table(s) {sorted(unknown)} (expected [model] and [train])")
    model = dict(raw.get("model", {}))
    kind = model.pop("kind", "teacher")
    base = {"teacher": teacher_config, "student": student_config}.get(kind)
    if base is None:
        raise ValueError(f"{path}: model.kind must be 'teacher' or 'student', got {kind!r}")
    fields = {f.name for f in dataclasses.fields(ModelConfig)}
    bad = set(model) - fields
    if bad:
        raise ValueError(f"{path}: unknown [model] key(s) {sorted(bad)}")
    try:
        mcfg = base().replace(**model).validate()
    except (TypeError, ValueError) as err:
        raise ValueError(f"{path}: [model]: {err}") from None
    train_raw = raw.get("train", {})
    tfields = {f.name for f in dataclasses.fields(TrainConfig)}
    bad = set(train_raw) - tfields
    if bad:
        raise ValueError(f"{path}: unknown [train] key(s) {sorted(bad)}")
    try:
        tcfg = TrainConfig(**train_raw).validate()
    except (TypeError, ValueError) as err:
        raise ValueError(f"{path}: [train]: {err}") from None
    return mcfg, tcfg
