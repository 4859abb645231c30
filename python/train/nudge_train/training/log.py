"""The per-epoch log of a training run: ``<out_dir>/metrics.jsonl``, one JSON object per epoch
(``epoch``, ``loss_var``, ``loss_adv``, ``loss_d``, ``val_ade``, ``best_val_ade``, ``lr``,
``seconds``), rewritten (temp-then-rename) by :func:`nudge_train.training.loop.train` after each
epoch's checkpoint from the rows that checkpoint holds, and read by the experiment reports and
the training-curve figures (no torch needed to read it)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from nudge_train.errors import ConfigError
from nudge_train.jsonio import loads_json

__all__ = ["METRICS_FILE", "metrics_text", "read_metrics"]

METRICS_FILE = "metrics.jsonl"
"""File name of the log inside a run's ``out_dir``."""


def metrics_text(rows: list[dict[str, Any]]) -> str:
    """The file content for ``rows``: one compact JSON object per line."""
    return "".join(json.dumps(r) + "\n" for r in rows)


def read_metrics(out: Path) -> list[dict[str, Any]]:
    """Every epoch row of the training run in ``out``.

    Raises:
        ConfigError: a line is not a JSON object or repeats a key (naming file and row).
    """
    path = Path(out) / METRICS_FILE
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        if not line:
            continue
        try:
            row = loads_json(line, path)
        except ConfigError as err:
            raise ConfigError(path, err.message, key=err.key, row=n) from None
        if not isinstance(row, dict):
            raise ConfigError(path, "not a JSON object", row=n)
        rows.append(row)
    return rows
