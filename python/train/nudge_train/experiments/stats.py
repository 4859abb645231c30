"""The statistics of the closed-loop report, small and tested on hand-computed cases.

* :func:`cluster_bootstrap`: a statistic of runs with a percentile interval from resampling
  SCENES with replacement (runs of one scene share the scene: they are not independent);
* :func:`mcnemar_exact`: the exact two-sided McNemar test of paired successes (binomial test on
  the discordant pairs);
* :func:`paired_bootstrap`: the mean paired difference with a percentile interval from
  resampling scenes;
* :func:`terciles`: the two cut points splitting values into three equal-count strata.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = ["cluster_bootstrap", "mcnemar_exact", "paired_bootstrap", "stratum", "terciles"]

BOOTSTRAP = 2000
"""Resamples of every bootstrap interval in the report."""


def _scene_index(scenes: np.ndarray) -> tuple[np.ndarray, int]:
    """Scene labels -> (dense index [n], number of scenes)."""
    _, idx = np.unique(np.asarray(scenes), return_inverse=True)
    return idx, int(idx.max()) + 1 if idx.size else 0


def cluster_bootstrap(values: np.ndarray, scenes: np.ndarray, stat: Callable[[np.ndarray], float] = np.mean,
                      n_boot: int = BOOTSTRAP, seed: int = 0, level: float = 0.95) -> tuple[float, float, float]:
    """``stat(values)`` and its ``level`` percentile interval from ``n_boot`` resamples of the
    scenes (each resample draws as many scenes as there are, with replacement, and keeps every run
    of each drawn scene). ``values`` [n] per run, ``scenes`` [n] scene labels. NaN for no runs."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        return (math.nan, math.nan, math.nan)
    idx, k = _scene_index(scenes)
    groups = [values[idx == s] for s in range(k)]
    rng = np.random.default_rng(seed)
    boots = np.empty(n_boot)
    for b in range(n_boot):
        pick = rng.integers(0, k, size=k)
        boots[b] = stat(np.concatenate([groups[s] for s in pick]))
    alpha = (1.0 - level) / 2.0
    return (float(stat(values)), float(np.quantile(boots, alpha)), float(np.quantile(boots, 1.0 - alpha)))


def mcnemar_exact(only_a: int, only_b: int) -> float:
    """Two-sided exact McNemar p-value for ``only_a`` pairs where only arm A succeeded and
    ``only_b`` where only B did: 2 * P(X <= min) for X ~ Binomial(only_a + only_b, 1/2), capped
    at 1 (1 when there is no discordant pair)."""
    n = only_a + only_b
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(only_a, only_b) + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


def paired_bootstrap(a: np.ndarray, b: np.ndarray, scenes: np.ndarray, n_boot: int = BOOTSTRAP, seed: int = 0,
                     level: float = 0.95) -> tuple[float, float, float]:
    """Mean of ``b - a`` over pairs and its percentile interval from resampling scenes
    (:func:`cluster_bootstrap` of the differences)."""
    d = np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64)
    return cluster_bootstrap(d, scenes, np.mean, n_boot, seed, level)


def terciles(values: np.ndarray) -> tuple[float, float]:
    """The 1/3 and 2/3 quantiles (linear interpolation) of ``values``."""
    v = np.asarray(values, dtype=np.float64)
    return (float(np.quantile(v, 1.0 / 3.0)), float(np.quantile(v, 2.0 / 3.0)))


def stratum(values: np.ndarray, cuts: tuple[float, float], names: tuple[str, str, str]) -> np.ndarray:
    """The stratum name of every value: ``names[0]`` up to the first cut (inclusive),
    ``names[1]`` up to the second, ``names[2]`` above."""
    v = np.asarray(values, dtype=np.float64)
    return np.where(v <= cuts[0], names[0], np.where(v <= cuts[1], names[1], names[2]))
