"""The per-epoch log of a training run: ``<out_dir>/metrics.jsonl``, one JSON object per epoch
(``epoch``, ``loss_var``, ``loss_adv``, ``loss_d``, ``val_ade``, ``best_val_ade``, ``lr``,
``seconds``), appended by :func:`nudge_train.training.loop.train` and read by the experiment
reports and the training-curve figures (no torch needed to read it)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["METRICS_FILE", "read_metrics"]

METRICS_FILE = "metrics.jsonl"
"""File name of the log inside a run's ``out_dir``."""


def read_metrics(out: Path) -> list[dict[str, Any]]:
    """Every epoch row of the training run in ``out``."""
    return [json.loads(line) for line in (Path(out) / METRICS_FILE).read_text().splitlines() if line]
