"""Paired closed-loop arms of the ADMM convergence rules, with the steps' statuses split by how
the ADMM loop ended (the measurements behind the convergence section of
``docs/results/latency.md`` and the ``nudge_planner::Planner`` docs).

    python -m nudge_train.experiments.convergence_arms --planner student --world teacher
    python -m nudge_train.experiments.convergence_arms --planner teacher --world teacher --teacher-n 60

Arms (planner settings, closed-loop settings): ``main`` (the defaults), ``rules`` (``z_safe_step``,
``z_rollout_trial``, ``relinearise``, ``plan_buffer`` 0.03, with the stalled-change abort
``stall_progress`` 0.05), ``rules_no_stall`` (the rules, no stalled-change abort), ``stall`` (the
default planner with the stalled-change abort), ``rules_proj`` (the rules with the Z-update's
projection onto the linearised safe set, ``z_cuts`` 3, and the safe start ``safe_start``),
``rules_cuts`` and ``rules_start`` (the rules with one of the two), ``proj`` (the safe step with
the projection and the safe start, no other rule, no stalled-change abort), ``rules_proj_rt``
(``rules_proj`` with two re-tightenings of the Z-update's threshold, ``z_retighten`` 2). Every arm runs the same (scene, seed) pairs:
the scenes and seeds of ``nudge-train closed-loop --seed 0`` (one run per scene; with
``--teacher-n`` its seeded subset), so the arms are paired; success is compared with McNemar's
exact test. Each step is classified by its status and by whether the loop stopped at
``max_iter`` (``iterations`` = ``max_iter``): ``Converged`` and ``MaxIterations`` are the steps
whose ADMM roll-out was admissible, every other status a step whose roll-out was not. Runs are
cached under ``runs/convergence/``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

import nudge

from nudge_train import paths
from nudge_train.experiments.closed_loop import choose
from nudge_train.experiments.stats import mcnemar_exact

RULES = {"z_safe_step": True, "z_rollout_trial": True, "relinearise": True, "plan_buffer": 0.03}
PROJECTION = {"z_cuts": 3, "safe_start": True}
ARMS: dict[str, tuple[dict, dict]] = {
    "main": ({}, {}),
    "rules": (RULES, {"stall_progress": 0.05}),
    "rules_no_stall": (RULES, {}),
    "stall": ({}, {"stall_progress": 0.05}),
    "rules_proj": ({**RULES, **PROJECTION}, {"stall_progress": 0.05}),
    "rules_cuts": ({**RULES, "z_cuts": PROJECTION["z_cuts"]}, {"stall_progress": 0.05}),
    "rules_start": ({**RULES, "safe_start": True}, {"stall_progress": 0.05}),
    "proj": ({"z_safe_step": True, **PROJECTION}, {}),
    "rules_proj_rt": ({**RULES, **PROJECTION, "z_retighten": 2}, {"stall_progress": 0.05}),
}
STATUSES = ("Converged", "MaxIterations", "Refined", "Backtracked", "Fallback", "Unsafe", "BudgetExhausted",
            "SolverFailed")


def scenes_and_seeds(split: str, n: int | None, teacher_n: int | None, seed: int = 0) -> tuple[list[Path], list[int]]:
    """The scenes and scene seeds of ``nudge-train closed-loop --seed`` (the teacher planner's
    subset when ``teacher_n`` is given)."""
    cfg = SimpleNamespace(scenes=paths.repo() / "data" / "processed" / "scenes" / split, seed=seed, n=n,
                          teacher_n=teacher_n or 0)
    scenes, seeds, subset = choose(cfg)
    if teacher_n is not None:
        return [scenes[i] for i in subset], [seeds[i] for i in subset]
    return scenes, seeds


def run_arm(planner: str, world: str, arm: str, split: str, n: int | None, teacher_n: int | None,
            threads: int, cache: Path) -> dict:
    """One arm's per-run and per-step columns (cached by its inputs)."""
    file = cache / f"{split}-{planner}-{world}-{arm}-{n}-{teacher_n}.json"
    if file.is_file():
        return json.loads(file.read_text())
    planner_settings, sim = ARMS[arm]
    settings = nudge.PlannerSettings.from_json(json.dumps(planner_settings)) if planner_settings \
        else nudge.PlannerSettings.default()
    scenes, seeds = scenes_and_seeds(split, n, teacher_n)
    t0 = time.perf_counter()
    res = nudge.simulate(scenes, planner, scene_seeds=seeds, runs=1, threads=threads, settings=settings, world=world,
                         on_error="skip", **sim)
    runs, steps = res["runs"], res["steps"]
    data = {"wall_s": time.perf_counter() - t0, "max_iter": settings.max_iter,
            "scenario": [str(s) for s in runs["scenario"]],
            "success": np.asarray(runs["success"], bool).tolist(),
            "at_fault": np.asarray(runs["collisions_at_fault"], int).tolist(),
            "not_at_fault": np.asarray(runs["collisions_not_at_fault"], int).tolist(),
            "aborts": np.asarray(runs["aborts"], int).tolist(),
            "errors": sum(1 for e in runs["error"] if e),
            "status": [str(s) for s in steps["status"]],
            "iterations": np.asarray(steps["iterations"], int).tolist(),
            "mpc_s": np.asarray(steps["mpc_s"], float).tolist()}
    cache.mkdir(parents=True, exist_ok=True)
    file.write_text(json.dumps(data))
    return data


def summary(d: dict) -> dict:
    """Status shares (% of steps), the loop-end classes, success, collisions and step times."""
    status, capped = np.array(d["status"]), np.array(d["iterations"]) >= d["max_iter"]
    admissible = np.isin(status, ["Converged", "MaxIterations"])
    ms = np.array(d["mpc_s"]) * 1e3
    pct = lambda m: round(100.0 * float(np.mean(m)), 1)  # noqa: E731
    return {"steps": len(status), **{s: pct(status == s) for s in STATUSES},
            "capped, roll-out inadmissible": pct(capped & ~admissible),
            "converged, roll-out inadmissible": pct(~capped & ~admissible),
            "capped, roll-out admissible": pct(capped & admissible),
            "success": int(sum(d["success"])), "runs": len(d["success"]), "errors": d["errors"],
            "at-fault events": int(sum(d["at_fault"])), "not-at-fault events": int(sum(d["not_at_fault"])),
            "aborts": int(sum(d["aborts"])), "p50 ms": round(float(np.percentile(ms, 50)), 1),
            "p99 ms": round(float(np.percentile(ms, 99)), 1)}


def paired(a: dict, b: dict) -> dict:
    """Success of arm ``b`` against arm ``a`` on the same runs: lost, gained, McNemar's p."""
    if a["scenario"] != b["scenario"]:
        raise ValueError("the arms ran different scenes")
    sa, sb = np.array(a["success"], bool), np.array(b["success"], bool)
    lost, gained = int(np.sum(sa & ~sb)), int(np.sum(~sa & sb))
    return {"lost": lost, "gained": gained, "p": round(mcnemar_exact(lost, gained), 3)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--planner", default="student", help="planning predictor (default: student)")
    ap.add_argument("--world", default="teacher", choices=["teacher", "idm", "log_replay"])
    ap.add_argument("--split", default="val", choices=["train", "val", "test"])
    ap.add_argument("--n", type=int, default=None, help="scenes drawn (seeded; default all)")
    ap.add_argument("--teacher-n", type=int, default=None, help="run the teacher planner's seeded subset")
    ap.add_argument("--arms", nargs="+", default=["main", "rules"], choices=list(ARMS),
                    help="arms; the first is the reference of the paired comparisons")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=paths.repo() / "runs" / "convergence")
    args = ap.parse_args(argv)
    res = {a: run_arm(args.planner, args.world, a, args.split, args.n, args.teacher_n, args.threads, args.cache)
           for a in args.arms}
    for a in args.arms:
        print(f"{args.planner} / {args.world} / {a}: {json.dumps(summary(res[a]))}")
    for a in args.arms[1:]:
        print(f"{args.planner} / {args.world} / {args.arms[0]} -> {a}: {paired(res[args.arms[0]], res[a])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
