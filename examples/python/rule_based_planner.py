"""Your own planner in nudge's worlds and metrics: a rule-based lane changer (IDM car following
with a MOBIL-style safety check on the target lane) driving the ego of ``nudge.simulate(...,
planner=obj)``, compared with nudge's own planner on the same scenes, seeds and worlds.

Run from the repository root after ``make develop``::

    .venv/bin/python examples/python/rule_based_planner.py              # the shipped scenes
    .venv/bin/python examples/python/rule_based_planner.py --scenes DIR --n 100 --markdown out.md

The planner sees what nudge's planner sees (``docs/python_planner.md``: the ego's state, every
vehicle's last 8 observed positions and size, the lanes, the target lane's centre) and returns
steering and acceleration over the 6-step horizon; nudge applies the first pair, moves the
others with the world and judges the run with the same metrics as its own.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import nudge

WORLDS = ("teacher", "idm", "log_replay")


class RuleBasedPlanner:
    """IDM along the road; changes lanes when the gap in the target lane passes a MOBIL-style
    safety check (the new follower would not brake harder than ``b_safe``, the new leader is not
    closer than the IDM's standstill gap), else keeps its lane and follows its leader.

    IDM parameters: desired time gap ``T`` (s), standstill gap ``s0`` (m), comfortable
    acceleration ``a`` and deceleration ``b`` (m/s²); lateral control: aim the heading at the
    lateral goal with time constant ``tau_y`` (s), steer the heading there in ``tau_psi`` (s)."""

    def __init__(self, T: float = 1.2, s0: float = 2.0, a: float = 1.5, b: float = 2.0,  # noqa: N803
                 b_safe: float = 3.0, tau_y: float = 2.5, tau_psi: float = 0.6, psi_max: float = 0.12) -> None:
        self.T, self.s0, self.a, self.b, self.b_safe = T, s0, a, b, b_safe
        self.tau_y, self.tau_psi, self.psi_max = tau_y, tau_psi, psi_max
        self.wheelbase = 2.8  # nudge's default l_f + l_r (m)

    def reset(self) -> None:
        """Nothing is carried between runs."""

    def _idm(self, v: float, v0: float, gap: float, dv: float) -> float:
        """IDM acceleration at speed v (m/s), desired speed v0, bumper gap to the leader (m) and
        approach rate dv = v - v_leader (m/s); gap = inf without a leader."""
        free = 1.0 - (v / max(v0, 0.1)) ** 4
        if not math.isfinite(gap):
            return self.a * free
        s_star = self.s0 + max(0.0, v * self.T + v * dv / (2.0 * math.sqrt(self.a * self.b)))
        return self.a * (free - (s_star / max(gap, 0.1)) ** 2)

    @staticmethod
    def _lane_of(y: float, bounds: np.ndarray) -> int:
        k = int(np.searchsorted(bounds, y)) - 1
        return min(max(k, 0), len(bounds) - 2)

    def _neighbours(self, obs: dict, x: float, lane: int) -> tuple[tuple | None, tuple | None]:
        """The nearest vehicle ahead and behind the ego's x in ``lane``: (bumper gap m, speed m/s)."""
        hist, sizes, dt = obs["history"], obs["sizes"], obs["dt"]
        ahead = behind = None
        for i in range(1, len(hist)):
            px, py = hist[i, -1]
            if self._lane_of(py, obs["lane_bounds"]) != lane:
                continue
            v = float(np.hypot(*(hist[i, -1] - hist[i, -2]))) / dt
            gap = abs(px - x) - (sizes[i, 0] + sizes[0, 0]) / 2.0
            if px >= x and (ahead is None or gap < ahead[0]):
                ahead = (gap, v)
            elif px < x and (behind is None or gap < behind[0]):
                behind = (gap, v)
        return ahead, behind

    def plan(self, obs: dict) -> dict:
        x, y, psi, v = (float(c) for c in obs["ego"])
        bounds, dt, horizon = obs["lane_bounds"], obs["dt"], obs["horizon"]
        lim = obs["bounds"]
        own = self._lane_of(y, bounds)
        target = self._lane_of(obs["y_target"], bounds)
        v0 = max(obs["v_ref"], v)
        # The target lane's gap: MOBIL's safety criterion for the new follower, and room ahead.
        ahead_t, behind_t = self._neighbours(obs, x, target)
        safe = True
        if behind_t is not None:
            gap_b, v_b = behind_t
            a_follower = self._idm(v_b, v_b, gap_b, v_b - v)
            safe = a_follower >= -self.b_safe and gap_b > self.s0
        if ahead_t is not None:
            safe = safe and ahead_t[0] > self.s0
        changing = target != own and safe
        y_aim = obs["y_target"] if changing or target == own else obs["lane_centres"][own]
        # Follow the nearer leader of the ego's lane and, when changing, of the target lane.
        leaders = [self._neighbours(obs, x, own)[0]] + ([ahead_t] if changing else [])
        delta, accel = [], []
        for _ in range(horizon):
            gaps = [(g - 0.0, vl) for g, vl in (lead for lead in leaders if lead is not None)]
            acc = min((self._idm(v, v0, g, v - vl) for g, vl in gaps), default=self._idm(v, v0, math.inf, 0.0))
            acc = float(np.clip(acc, lim["a_min"], lim["a_max"]))
            psi_des = float(np.clip((y_aim - y) / (self.tau_y * max(v, 1.0)), -self.psi_max, self.psi_max))
            d = (psi_des - psi) * self.wheelbase / (max(v, 1.0) * self.tau_psi)
            d = float(np.clip(d, -lim["delta_max"], lim["delta_max"]))
            delta.append(d)
            accel.append(acc)
            # Roll the plan forward (kinematic bicycle, centre of gravity midway) and the
            # leaders at constant speed.
            beta = math.atan(0.5 * math.tan(d))
            x += v * math.cos(psi + beta) * dt
            y += v * math.sin(psi + beta) * dt
            psi += v / (self.wheelbase / 2.0) * math.sin(beta) * dt
            v = max(0.0, v + acc * dt)
            leaders = [None if lead is None else (lead[0] + (lead[1] - v) * dt, lead[1]) for lead in leaders]
        return {"delta": delta, "accel": accel}


def summary(runs: dict) -> dict:
    """The table's numbers of one batch's run columns."""
    ok = np.array([e is None for e in runs["error"]])
    steps = np.where(runs["steps_to_target"] >= 0, runs["steps_to_target"], np.nan)[ok]
    return {
        "runs": int(ok.sum()),
        "success": float(np.mean(runs["success"][ok])),
        "at_fault": int(runs["collisions_at_fault"][ok].sum()),
        "not_at_fault": int(runs["collisions_not_at_fault"][ok].sum()),
        "time_s": float(np.nanmean(steps) * nudge.DT) if np.isfinite(steps).any() else float("nan"),
        "off_road": int(runs["off_road_steps"][ok].sum()),
        "score": float(np.mean(runs["score"][ok])),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=Path, default=None, help="folder of scenario files (default: the shipped ones)")
    ap.add_argument("--n", type=int, default=None, help="the first N scenes of the folder (default: all)")
    ap.add_argument("--seed", type=int, default=0, help="base seed (run of scene i draws seed + i)")
    ap.add_argument("--threads", type=int, default=2, help="threads of nudge's own runs")
    ap.add_argument("--markdown", type=Path, default=None, help="also write the table here")
    a = ap.parse_args()
    scenes = nudge.scene_paths(a.scenes)[: a.n]
    rows = []
    for world in WORLDS:
        for name, kw in (("nudge (student)", {"threads": a.threads}),
                         ("rule-based (IDM + MOBIL)", {"planner": RuleBasedPlanner(), "threads": 1})):
            r = nudge.simulate(scenes, "student", seed=a.seed, world=world, on_error="skip", **kw)
            rows.append((world, name, summary(r["runs"])))
    head = ("| world | planner | runs | success | collisions at fault | not at fault | time to target (s) | "
            "off-road steps | score |")
    lines = [head, "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for world, name, s in rows:
        lines.append(f"| {world} | {name} | {s['runs']} | {s['success']:.0%} | {s['at_fault']} | "
                     f"{s['not_at_fault']} | {s['time_s']:.1f} | {s['off_road']} | {s['score']:.3f} |")
    table = "\n".join(lines)
    print(f"{len(scenes)} scenes, seed {a.seed}, one run each\n{table}")
    if a.markdown is not None:
        a.markdown.write_text(table + "\n")
        print(f"wrote {a.markdown}")


if __name__ == "__main__":
    main()
