"""The closed-loop report's statistics against hand-computed cases (and scipy's binomial test)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binomtest

from nudge_train.experiments.stats import cluster_bootstrap, mcnemar_exact, paired_bootstrap, stratum, terciles


def test_mcnemar_exact_by_hand() -> None:
    assert mcnemar_exact(0, 0) == 1.0
    assert mcnemar_exact(3, 3) == 1.0
    # Five discordant pairs all one way: 2 * 0.5^5.
    assert mcnemar_exact(0, 5) == pytest.approx(0.0625, abs=1e-15)
    assert mcnemar_exact(5, 0) == mcnemar_exact(0, 5)
    # 1 vs 9: 2 * (C(10,0) + C(10,1)) / 2^10 = 22 / 1024.
    assert mcnemar_exact(1, 9) == pytest.approx(22 / 1024, abs=1e-15)
    for a, b in [(2, 7), (4, 11), (13, 20), (30, 45)]:
        assert mcnemar_exact(a, b) == pytest.approx(binomtest(a, a + b, 0.5).pvalue, rel=1e-12)


def test_cluster_bootstrap_resamples_scenes_not_runs() -> None:
    # Two scenes: one where every run succeeds, one where none does. Resampled means are 0, 1/2
    # or 1 with probabilities 1/4, 1/2, 1/4, so the 95 % interval is [0, 1] whatever the number of
    # runs per scene; resampling runs instead would give a narrow interval around 3/4.
    values = np.array([1.0] * 30 + [0.0] * 10)
    scenes = np.array(["a"] * 30 + ["b"] * 10)
    est, lo, hi = cluster_bootstrap(values, scenes, n_boot=4000, seed=1)
    assert est == 0.75 and (lo, hi) == (0.0, 1.0)
    # One value per scene, all equal: a degenerate interval.
    assert cluster_bootstrap(np.full(5, 2.5), np.arange(5)) == (2.5, 2.5, 2.5)
    assert all(math.isnan(v) for v in cluster_bootstrap(np.array([]), np.array([])))
    # Seeded: the same interval twice.
    rng = np.random.default_rng(0)
    v, s = rng.normal(size=50), rng.integers(0, 10, size=50)
    assert cluster_bootstrap(v, s, seed=3) == cluster_bootstrap(v, s, seed=3)


def test_paired_bootstrap_is_the_mean_difference() -> None:
    a = np.array([10.0, 12.0, 9.0, 9.0])
    b = np.array([8.0, 12.0, 6.0, 6.0])
    est, lo, hi = paired_bootstrap(a, b, np.array(["x", "x", "y", "y"]), n_boot=4000, seed=2)
    # Scene x: differences (−2, 0), scene y: (−3, −3): resampled means −1, −2 or −3.
    assert est == -2.0 and (lo, hi) == (-3.0, -1.0)


def test_terciles_and_strata() -> None:
    v = np.arange(1.0, 10.0)
    cuts = terciles(v)
    assert cuts == pytest.approx((1 + 8 / 3, 1 + 16 / 3))
    names = stratum(v, cuts, ("dense", "medium", "sparse"))
    assert names.tolist() == ["dense"] * 3 + ["medium"] * 3 + ["sparse"] * 3
