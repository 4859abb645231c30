"""nudge as the controller of the ego in highway-env (nudge.adapters.highway,
docs/highway_env.md), beside two baselines on the same seeds: highway-env's own IDM + MOBIL
driver in the ego's place, and a constant action (no steering, no acceleration).

Run from the repository root after ``make develop`` (the venv has highway-env)::

    .venv/bin/python examples/python/highway_env_episodes.py                      # 2 short episodes
    .venv/bin/python examples/python/highway_env_episodes.py --episodes 20 --duration 40 --arms nudge idm constant

Per arm: episodes, collisions (the ego crashed), lane changes (changes of highway-env's lane
index, all episodes), mean speed (m/s, over every step), ms per step (planning and highway-env's
simulation; the planning share beside it), steps, actions nudge sent outside [-1, 1] and the
steps at which nudge's ego started with its centre beyond a road edge.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections import Counter

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import numpy as np  # noqa: E402
from highway_env.vehicle.behavior import IDMVehicle  # noqa: E402

from nudge.adapters.highway import (  # noqa: E402
    EpisodeResult,
    NudgeHighwayController,
    action_from_inputs,
    make_env,
    planner_settings,
    run_episode,
)

ARMS = ("nudge", "idm", "constant")


class IdmEgo:
    """highway-env's IDMVehicle (IDM along the lane, MOBIL lane changes) put in the ego's place
    at reset, with the desired speed ``v_ref``; the env's action is then ignored by it."""

    def __init__(self, env, v_ref: float) -> None:
        self.u = env.unwrapped
        self.v_ref = v_ref
        self.idle = action_from_inputs(0.0, 0.0, planner_settings().bounds)

    def reset(self) -> None:
        old = self.u.vehicle
        ego = IDMVehicle(self.u.road, old.position.copy(), old.heading, old.speed, target_speed=self.v_ref)
        self.u.road.vehicles[self.u.road.vehicles.index(old)] = ego
        self.u.vehicle = ego

    def act(self) -> np.ndarray:
        return self.idle


class ConstantAction:
    """No steering, no acceleration."""

    def __init__(self) -> None:
        self.action = action_from_inputs(0.0, 0.0, planner_settings().bounds)

    def reset(self) -> None:
        pass

    def act(self) -> np.ndarray:
        return self.action


def summarise(arm: str, results: list[EpisodeResult], speeds: list[float]) -> dict:
    steps = sum(r.steps for r in results)
    return {
        "arm": arm,
        "episodes": len(results),
        "collisions": sum(r.crashed for r in results),
        "lane_changes": sum(r.lane_changes for r in results),
        "mean_speed": statistics.fmean(speeds),
        "ms_per_step": sum(r.ms_per_step * r.steps for r in results) / steps,
        "plan_ms": statistics.median(r.plan_ms for r in results) if arm == "nudge" else float("nan"),
        "steps": steps,
        "out_of_range": sum(r.out_of_range for r in results),
        "off_road": sum(r.off_road for r in results),
        "statuses": sum((Counter(r.statuses) for r in results), Counter()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="highway-v0", help="highway-v0, highway-fast-v0 or merge-v0")
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0, help="the first episode's seed (then +1 each)")
    ap.add_argument("--duration", type=float, default=9.0, help="episode length (s; highway-v0's own is 40)")
    ap.add_argument("--vehicles", type=int, default=None, help="vehicles_count (default: the env's)")
    ap.add_argument("--predictor", default="student")
    ap.add_argument("--v-ref", type=float, default=None, help="desired speed (m/s; default: the lanes' speed limit)")
    ap.add_argument("--arms", nargs="+", choices=ARMS, default=["nudge", "constant"])
    ap.add_argument("--markdown", default=None, help="also write the table to this file")
    args = ap.parse_args(argv)

    config: dict = {"duration": args.duration}
    if args.vehicles is not None:
        config["vehicles_count"] = args.vehicles
    env = make_env(args.env, config=config)
    seeds = list(range(args.seed, args.seed + args.episodes))
    rows = []
    for arm in args.arms:
        if arm == "nudge":
            ctrl = NudgeHighwayController(env, predictor=args.predictor, v_ref=args.v_ref)
        elif arm == "idm":
            ctrl = IdmEgo(env, args.v_ref if args.v_ref is not None else 30.0)
        else:
            ctrl = ConstantAction()
        results, speeds = [], []
        t0 = time.perf_counter()
        for seed in seeds:
            r = run_episode(env, ctrl, seed)
            results.append(r)
            speeds.extend([r.mean_speed] * r.steps)
            print(
                f"{arm:8s} seed {seed:3d}: {r.steps:3d} steps, crashed {r.crashed!s:5s}, "
                f"lane changes {r.lane_changes}, mean speed {r.mean_speed:5.2f} m/s, {r.ms_per_step:6.1f} ms/step, "
                f"off road {r.off_road}",
                flush=True,
            )
        rows.append(summarise(arm, results, speeds))
        print(f"{arm}: {time.perf_counter() - t0:.1f} s", flush=True)

    head = "| arm | episodes | collisions | lane changes | mean speed (m/s) | ms per step | nudge plan ms (median) | steps | actions outside [-1, 1] | steps off the road |"
    lines = [
        f"{args.env}, seeds {seeds[0]}..{seeds[-1]}, {args.duration:g} s episodes, predictor {args.predictor}",
        "",
        head,
        "|" + "---|" * head.count(" | ") + "---|",
    ]
    for r in rows:
        plan = "" if r["arm"] != "nudge" else f"{r['plan_ms']:.1f}"
        oor = f"{r['out_of_range']} | {r['off_road']}" if r["arm"] == "nudge" else " | "
        lines.append(
            f"| {r['arm']} | {r['episodes']} | {r['collisions']} | {r['lane_changes']} | {r['mean_speed']:.2f} | "
            f"{r['ms_per_step']:.1f} | {plan} | {r['steps']} | {oor} |"
        )
    for r in rows:
        if r["statuses"]:
            lines.append("")
            lines.append(f"{r['arm']} plan statuses: " + ", ".join(f"{k} {v}" for k, v in sorted(r["statuses"].items())))
    table = "\n".join(lines)
    print(table)
    if args.markdown:
        with open(args.markdown, "w") as f:
            f.write(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
