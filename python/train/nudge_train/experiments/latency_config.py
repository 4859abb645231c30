"""The arguments of ``nudge-train bench latency`` (:mod:`nudge_train.experiments.bench_latency`):
standard library only, so that the command line parses without numpy."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

__all__ = ["N_EDGES", "WORLDS", "LatencyConfig"]

N_EDGES = (8, 16, 24)
"""Upper bounds (inclusive) of the agent-count buckets: N <= 8, 9-16, 17-24, >= 25."""
WORLDS = ("teacher", "idm", "log_replay")
"""The worlds a closed loop can run in."""


@dataclass(frozen=True)
class LatencyConfig:
    """What to run (the ``nudge-train bench latency`` arguments)."""

    scenes: Path
    n: int | None = 120
    seed: int = 0
    runs: int = 1
    predictors: tuple[str, ...] = ("student", "teacher", "constant_velocity")
    world: str = "teacher"
    budget_ms: float | None = None
    teacher_n: int | None = None
    n_edges: tuple[int, ...] = N_EDGES
    chunk: int = 20
    progress: bool = True
    horizons: tuple[int, ...] = ()
    """When given, every predictor runs at each of these horizons (steps; settings ``horizon``)."""

    def validate(self) -> None:
        """Raise ValueError naming the first bad argument."""
        if self.n is not None and self.n < 1:
            raise ValueError(f"--n must be >= 1, got {self.n}")
        if self.runs < 1:
            raise ValueError(f"--runs must be >= 1, got {self.runs}")
        if self.teacher_n is not None and self.teacher_n < 1:
            raise ValueError(f"--teacher-n must be >= 1, got {self.teacher_n}")
        if self.chunk < 1:
            raise ValueError(f"--chunk must be >= 1, got {self.chunk}")
        if any(h < 1 for h in self.horizons) or len(set(self.horizons)) != len(self.horizons):
            raise ValueError(f"--horizons must be distinct positive step counts, got {list(self.horizons)}")
        if not self.predictors:
            raise ValueError("--predictors needs at least one entry")
        if len(set(self.predictors)) != len(self.predictors):
            raise ValueError(f"--predictors lists a predictor twice: {list(self.predictors)}")
        if self.world not in WORLDS:
            raise ValueError(f"--world: unknown world {self.world!r} ({', '.join(WORLDS)})")
        if self.budget_ms is not None and not (math.isfinite(self.budget_ms) and self.budget_ms > 0):
            raise ValueError(f"--budget-ms must be a positive number of milliseconds, got {self.budget_ms}")
        if not self.n_edges or any(e < 1 for e in self.n_edges) or list(self.n_edges) != sorted(set(self.n_edges)):
            raise ValueError(f"--n-edges must be increasing positive agent counts, got {list(self.n_edges)}")
