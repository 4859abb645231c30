"""Per-step planning time seen from Python vs the Rust planner's own time and the Rust
criterion bench (`cargo bench --bench planner`, group ``planner/step/<predictor>/<N>``).

Same problem as the bench: the densest shipped scene cut to its N nearest vehicles, target =
the lane left of the ego (right when there is none), a cold start per call. Run::

    nudge-train bench python [--reps 30] [--ns 2 4 8 16] [--predictors student constant_velocity]

For every (predictor, N) it prints the median wall time of ``Planner.plan_scenario`` measured in
Python, the median of the planner's internal ``timings.total_s`` of the same calls (the Rust
time, measured inside the call), their ratio, and the criterion median when
``target/criterion/planner/step_<predictor>/<N>/new/estimates.json`` exists.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import nudge

from nudge_train.experiments.criterion import median_ms


def bench_scene(n: int) -> nudge.Scenario:
    """The densest shipped scene cut to its ``n`` nearest vehicles (ego included)."""
    scenes = [nudge.Scenario.load(p) for p in nudge.scene_paths()]
    big = max(scenes, key=lambda s: (s.n_agents, s.name))
    return big.nearest(n - 1)


def measure(pred: nudge.Predictor, sc: nudge.Scenario, reps: int) -> tuple[float, float]:
    """Median Python wall time of (new planner + one cold-start plan), as the criterion bench
    times it, and median Rust-internal time (s) of the plan call itself."""
    lane = sc.ego_lane + 1 if sc.ego_lane + 1 < len(sc.lane_centres) else sc.ego_lane - 1
    settings = nudge.PlannerSettings.default()
    nudge.Planner(settings, pred).plan_scenario(sc, target_lane=lane)  # warm-up
    wall, inner = [], []
    for _ in range(reps):
        t0 = time.perf_counter()
        plan = nudge.Planner(settings, pred).plan_scenario(sc, target_lane=lane)
        wall.append(time.perf_counter() - t0)
        inner.append(plan["timings"]["total_s"])
    return float(np.median(wall)), float(np.median(inner))


def run(*, reps: int, ns: list[int], predictors: list[str], criterion: Path) -> int:
    """``nudge-train bench python``: prints the table for every predictor of ``predictors`` and
    agent count of ``ns``, ``reps`` timed calls each, beside criterion's ``planner/step`` medians
    read below ``criterion`` (``target/criterion``)."""
    print("| predictor | N | Python wall (ms) | Rust in-call (ms) | Python / in-call | criterion (ms) | Python / criterion |")
    print("|---|---|---|---|---|---|---|")
    for name in predictors:
        pred = (nudge.Predictor.constant_velocity() if name == "constant_velocity"
                else nudge.Predictor.load(nudge.model_path(name)))
        for n in ns:
            sc = bench_scene(n)
            wall, inner = measure(pred, sc, reps)
            crit = median_ms(criterion, "planner", f"step_{name}", str(n))
            c = f"{crit:.3f}" if crit else "-"
            cr = f"{wall * 1e3 / crit:.3f}" if crit else "-"
            print(f"| {name} | {n} | {wall * 1e3:.3f} | {inner * 1e3:.3f} | {wall / inner:.3f} | {c} | {cr} |")
    return 0
