"""Closed-loop comparison of planning predictors on held-out real scenes.

Draws ``--n`` scenes (seeded) from a folder of ``nudge.scenario/1`` files (default: the test-split
scenes the data pipeline writes, ``data/processed/scenes/test``), gives each a seeded target lane,
and runs the same lane changes with every ``--predictors`` entry planning while the shipped
teacher moves the other vehicles (``world = predictor``). Prints and writes a markdown table:
success, steps to target, collisions, planning time per step (median, p90: one planner call on
one thread; ``--threads`` runs go side by side), Z-update time, and the plan cost compared run by
run with the teacher planner's (same scene, same target).

    nudge-train closed-loop --n 120 --markdown docs/results/closed_loop.md
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

import nudge

from nudge_train import paths


def summarise(res: dict, dt: float) -> dict:
    """Per-predictor summary of one :func:`nudge.simulate` result."""
    runs, steps = res["runs"], res["steps"]
    ok = np.array([e is None for e in runs["error"]])
    n = int(ok.sum())
    succ = np.asarray(runs["success"])[ok]
    stt = np.asarray(runs["steps_to_target"])[ok]
    coll = np.asarray(runs["collision"])[ok]
    run_of = np.asarray(steps["run"])
    cost = np.asarray(steps["cost"])
    mean_cost = np.array([cost[run_of == r].mean() if (run_of == r).any() else np.nan for r in range(len(ok))])
    mpc = np.asarray(steps["mpc_s"]) * 1e3
    zs = np.asarray(steps["z_s"]) * 1e3
    zn = np.asarray(steps["z_updates"])
    z_per = zs[zn > 0] / zn[zn > 0]
    status = steps["status"]
    reached = stt[stt >= 0] * dt
    return {
        "runs": n,
        "agents_mean": float(np.asarray(runs["n_agents"])[ok].mean()) if n else float("nan"),
        "errors": int((~ok).sum()),
        "success": float(succ.mean()) if n else float("nan"),
        "collisions": int(coll.sum()),
        "time_to_target_s": (float(reached.mean()), float(reached.std())) if len(reached) else (np.nan, np.nan),
        "steps": len(mpc),
        "mpc_ms_median": float(np.median(mpc)),
        "mpc_ms_p90": float(np.percentile(mpc, 90)),
        "z_ms_median": float(np.median(z_per)) if len(z_per) else float("nan"),
        "z_total_ms_median": float(np.median(zs)),
        "min_b_negative_steps": int(np.sum(np.asarray(steps["min_b"]) < 0)),
        "status_counts": {s: int(c) for s, c in zip(*np.unique(np.asarray(status, dtype=str), return_counts=True))},
        "mean_cost_per_run": mean_cost,
        "ok": ok,
    }


def run(
    *,
    scenes: Path,
    n: int,
    seed: int,
    predictors: list[str],
    threads: int,
    settings: Path | None,
    abort_after: int,
    abort_hold: int,
    markdown: Path | None,
    json_path: Path | None,
) -> int:
    """``nudge-train closed-loop``: draws ``n`` scenes of the folder ``scenes`` with ``seed``,
    runs every planning predictor of ``predictors`` on them (``threads`` runs side by side,
    planner ``settings`` JSON or the defaults, lane-change aborts ``abort_after`` /
    ``abort_hold``), prints the table and writes it to ``markdown`` and the summaries to
    ``json_path`` when given. Returns the exit status (2 when ``scenes`` holds no scenario)."""
    scene_files = sorted(scenes.glob("*.safetensors"))
    if not scene_files:
        print(f"error: no scenario files in {scenes} (run `make distill` or `make data`)", file=sys.stderr)
        return 2
    rng = np.random.default_rng(seed)
    pick = sorted(rng.permutation(len(scene_files))[:n].tolist())
    chosen = [scene_files[i] for i in pick]
    scene_seeds = rng.integers(0, 2**31, size=len(chosen)).tolist()
    print(f"{len(chosen)} scenes from {scenes} (seed {seed}), world = shipped teacher")
    planner_settings = nudge.PlannerSettings.from_json(settings.read_text()) if settings else None
    summaries: dict[str, dict] = {}
    for pred in predictors:
        t0 = time.perf_counter()
        res = nudge.simulate(chosen, pred, world="teacher", world_predictor="teacher", scene_seeds=scene_seeds,
                             settings=planner_settings, abort_after=abort_after, abort_hold=abort_hold, runs=1,
                             threads=threads, on_error="skip")
        s = summarise(res, nudge.DT)
        s["wall_s"] = time.perf_counter() - t0
        summaries[pred] = s
        print(f"{pred}: {s['runs']} runs, success {100 * s['success']:.1f} %, collisions {s['collisions']}, "
              f"median step {s['mpc_ms_median']:.2f} ms ({s['wall_s']:.0f} s wall)")

    base = summaries.get("teacher")
    lines = [
        f"Closed loop on {len(chosen)} held-out real scenes (`{paths.repo_relative(scenes)}`, "
        f"drawn with seed {seed}; one run each, seeded target lane), the shipped teacher moving the other "
        f"vehicles, at most 30 steps of {nudge.DT} s. Times: one planner call on one thread "
        f"({threads} runs side by side on the {threads}-core machine).",
        "",
        "| planning predictor | runs (errors) | agents / scene | success | time to target (s) | collisions | steps with min b < 0 "
        "| planning ms / step, median | p90 | Z-update ms, median | mean cost / step | cost vs teacher (paired) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for pred, s in summaries.items():
        both = s["ok"] & (base["ok"] if base else s["ok"])
        mine = s["mean_cost_per_run"][both]
        paired = "-"
        if base is not None and pred != "teacher":
            ref = base["mean_cost_per_run"][both]
            good = np.isfinite(mine) & np.isfinite(ref)
            ratio = mine[good].sum() / ref[good].sum()
            paired = f"{100 * (ratio - 1):+.1f} % (sum over {int(good.sum())} runs)"
        tt = s["time_to_target_s"]
        lines.append(
            f"| {pred} | {s['runs']} ({s['errors']}) | {s['agents_mean']:.1f} | {100 * s['success']:.1f} % | {tt[0]:.2f} ± {tt[1]:.2f} | "
            f"{s['collisions']} | {s['min_b_negative_steps']} | {s['mpc_ms_median']:.2f} | {s['mpc_ms_p90']:.2f} | "
            f"{s['z_ms_median']:.3f} | {np.nanmean(s['mean_cost_per_run']):.1f} | {paired} |"
        )
    lines += ["", "Planner status per step: " + "; ".join(
        f"{pred}: " + ", ".join(f"{k} {v}" for k, v in s["status_counts"].items()) for pred, s in summaries.items())]
    text = "\n".join(lines)
    print(text)
    if markdown:
        markdown.parent.mkdir(parents=True, exist_ok=True)
        markdown.write_text(text + "\n")
    if json_path:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps({p: {k: v for k, v in s.items() if k not in ("mean_cost_per_run", "ok")}
                                         for p, s in summaries.items()}, indent=1))
    return 0

