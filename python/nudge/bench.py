"""Per-step planning time seen from Python vs the Rust planner's own time and the Rust
criterion bench (`cargo bench --bench planner`, group ``planner/step/<predictor>/<N>``).

Same problem as the bench: the densest shipped scene cut to its N nearest vehicles, target =
the lane left of the ego (right when there is none), a cold start per call. Run::

    python -m nudge.bench [--reps 30] [--ns 2 4 8 16] [--predictors student constant_velocity]

For every (predictor, N) it prints the median wall time of ``Planner.plan_scenario`` measured in
Python, the median of the planner's internal ``timings.total_s`` of the same calls (the Rust
time, measured inside the call), their ratio, and the criterion median when
``target/criterion/planner/step_<predictor>/<N>/new/estimates.json`` exists.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import nudge


def bench_scene(n: int) -> nudge.Scenario:
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


def criterion_median(repo: Path, name: str, n: int) -> float | None:
    p = repo / "target" / "criterion" / "planner" / f"step_{name}" / str(n) / "new" / "estimates.json"
    if not p.exists():
        return None
    return float(json.loads(p.read_text())["median"]["point_estimate"]) * 1e-9


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m nudge.bench", description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--ns", type=int, nargs="+", default=[2, 4, 8, 16])
    ap.add_argument("--predictors", nargs="+", default=["teacher", "student", "constant_velocity"])
    a = ap.parse_args(argv)
    repo = nudge.assets_dir().parent
    print("| predictor | N | Python wall (ms) | Rust in-call (ms) | Python / in-call | criterion (ms) | Python / criterion |")
    print("|---|---|---|---|---|---|---|")
    for name in a.predictors:
        pred = (nudge.Predictor.constant_velocity() if name == "constant_velocity"
                else nudge.Predictor.load(nudge.model_path(name)))
        for n in a.ns:
            sc = bench_scene(n)
            wall, inner = measure(pred, sc, a.reps)
            crit = criterion_median(repo, name, n)
            c = f"{crit * 1e3:.3f}" if crit else "-"
            cr = f"{wall / crit:.3f}" if crit else "-"
            print(f"| {name} | {n} | {wall * 1e3:.3f} | {inner * 1e3:.3f} | {wall / inner:.3f} | {c} | {cr} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
