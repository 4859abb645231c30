"""Reading the Rust benches' results: criterion's saved estimates under ``target/criterion``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from nudge_train.jsonio import load_json

__all__ = ["median_ms"]


def median_ms(criterion_dir: Path, *bench_id: str) -> float | None:
    """Criterion's median (ms) of the bench whose directory below ``criterion_dir`` is
    ``bench_id`` (e.g. ``"predictor", "student", "8"``), read from ``new/estimates.json``
    (``median.point_estimate``, ns); ``None`` when that bench has not been run. An unreadable
    file is reported on stderr and counts as not run."""
    path = Path(criterion_dir).joinpath(*bench_id, "new", "estimates.json")
    if not path.is_file():
        return None
    try:
        return float(load_json(path)["median"]["point_estimate"]) / 1e6
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        print(f"warning: cannot read {path}: {err}", file=sys.stderr)
        return None
