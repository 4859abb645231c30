"""Training configuration: the ``[model]`` and ``[train]`` tables of a TOML training config.

A config file (``python/train/configs/*.toml``) has a ``[model]`` table (``kind`` picks the teacher
or student defaults of :mod:`nudge_train.models.config`, any other :class:`ModelConfig` field
overrides them) and a ``[train]`` table (:class:`TrainConfig`); unknown tables or keys and
impossible values are refused, and so are duplicate keys and tables (naming the key and its
line). ``nudge-train train --config FILE`` trains one.
"""

from __future__ import annotations

import ast
import dataclasses
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from nudge_train.constants import PRED_LEN
from nudge_train.errors import ConfigError
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


_TOML_POS = re.compile(r"\(at line (\d+), column (\d+)\)")
_TOML_TWICE = re.compile(r"Cannot declare (\(.*\)) twice")


def _toml_error(path: Path, text: str, err: tomllib.TOMLDecodeError) -> ConfigError:
    """A ConfigError naming the file, line and, for a duplicate, the key (tomllib's own message
    names neither the key nor, before Python 3.14, offers the line as data)."""
    msg = str(err)
    pos = _TOML_POS.search(msg)
    row = int(pos.group(1)) if pos else None
    twice = _TOML_TWICE.search(msg)
    if twice:
        try:
            key = ".".join(str(k) for k in ast.literal_eval(twice.group(1)))
        except (ValueError, SyntaxError):
            key = twice.group(1)
        return ConfigError(path, f"duplicate key {key!r} (a table declared twice)", key=key, row=row)
    if msg.startswith("Cannot overwrite a value") and row is not None:
        line = text.splitlines()[row - 1] if row - 1 < len(text.splitlines()) else ""
        key = ".".join(part.strip().strip('"').strip("'") for part in line.split("=", 1)[0].split("."))
        return ConfigError(path, f"duplicate key {key!r}", key=key, row=row)
    return ConfigError(path, f"invalid TOML: {_TOML_POS.sub('', msg).strip()}", row=row)


def load_config(path: Path) -> tuple[ModelConfig, TrainConfig]:
    """Reads a TOML training config: ``[model]`` (``kind`` picks the teacher/student defaults,
    other keys override sizes) and ``[train]``.

    Raises:
        FileNotFoundError: no such file.
        ConfigError (a ValueError): invalid TOML, a duplicate key or table (naming it and its
            line), unknown tables or keys, or a value its dataclass refuses.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise FileNotFoundError(f"training config not found: {path}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(path, f"cannot read: {err}") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise _toml_error(path, text, err) from None
    for table in ("model", "train"):
        if not isinstance(raw.get(table, {}), dict):
            raise ConfigError(path, f"{table} must be a table ([{table}])", key=table)
    unknown = set(raw) - {"model", "train"}
    if unknown:
        raise ConfigError(path, f"unknown table(s) {sorted(unknown)} (expected [model] and [train])",
                          key=sorted(unknown)[0])
    model = dict(raw.get("model", {}))
    kind = model.pop("kind", "teacher")
    base = {"teacher": teacher_config, "student": student_config}.get(kind)
    if base is None:
        raise ConfigError(path, f"model.kind must be 'teacher' or 'student', got {kind!r}", key="kind")
    fields = {f.name for f in dataclasses.fields(ModelConfig)}
    bad = set(model) - fields
    if bad:
        raise ConfigError(path, f"unknown [model] key(s) {sorted(bad)}", key=sorted(bad)[0])
    try:
        mcfg = base().replace(**model).validate()
    except (TypeError, ValueError) as err:
        raise ConfigError(path, f"[model]: {err}") from None
    train_raw = raw.get("train", {})
    tfields = {f.name for f in dataclasses.fields(TrainConfig)}
    bad = set(train_raw) - tfields
    if bad:
        raise ConfigError(path, f"unknown [train] key(s) {sorted(bad)}", key=sorted(bad)[0])
    try:
        tcfg = TrainConfig(**train_raw).validate()
    except (TypeError, ValueError) as err:
        raise ConfigError(path, f"[train]: {err}") from None
    return mcfg, tcfg
