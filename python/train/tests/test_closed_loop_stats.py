"""The closed-loop report's statistics against hand-computed cases (and scipy's binomial test)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binomtest

from nudge_train.experiments import closed_loop
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


def _summary(success: float, at_fault: int, off_road: int) -> dict:
    return {"runs": 9, "success": [success, success - 0.1, success + 0.05], "at_fault": [at_fault, at_fault],
            "not_at_fault": [0, 0], "off_road": [off_road * 3, off_road], "slow": [0, 0], "slow_planned": [2, 1],
            "heading": [0.19, 0.2], "overshoot": [0.3, 0], "score": [0.88, 0.8, 0.9], "mpc_ms": [5.0, 12.0]}


def test_before_after_marks_what_changed_and_lists_missing_arms() -> None:
    before = {"teacher/student/default": _summary(0.8, 2, 3), "idm/teacher/default": _summary(0.9, 0, 0)}
    after = {"teacher/student/default": _summary(0.9, 0, 0), "log_replay/student/default": _summary(0.7, 1, 0)}
    # Only the newer summary counts plans ending slow on a free road; the older one shows "-".
    after["teacher/student/default"]["slow_planned_free"] = [0, 0]
    text = closed_loop.before_after(before, after, "the planner at commit abc")
    rows = {line.split(" | ")[0] + "/" + line.split(" | ")[1]: line for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| world")}
    assert "the planner at commit abc" in text
    row = rows["| teacher/student"]
    assert "80.0 [70.0, 85.0] → **90.0 [80.0, 95.0]**" in row
    assert "2 (2) → **0 (0)**" in row and "3 → **0**" in row
    assert "0 (1; -) → **0 (1; 0)**" in row
    assert "| 9 |" in row and "0.88" in row and "→ **0.88" not in row  # unchanged cells are written once
    assert "(no before)" in rows["| log_replay/student"]
    assert "(before only)" in rows["| idm/teacher"]
