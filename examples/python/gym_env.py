"""nudge as a Gymnasium environment (docs/env.md): a rule-based agent and nudge's own planner,
each driving the ego through `nudge/LaneChange-v0` on the same seeded episodes in the three
worlds.

Run from the repository root (needs the `env` extra: pip install "nudge-planner[env]"):

    python examples/python/gym_env.py
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

import nudge.env

EPISODES = 4


class LaneKeeper:
    """Steers towards the target lane's centre and tracks nudge's reference speed, braking for a
    vehicle close ahead in its lane: a plain proportional controller on the observation, its
    commands kept within the action space by the agent itself (the env never clamps)."""

    def __init__(self, action_space: gym.spaces.Box) -> None:
        self.low, self.high = action_space.low, action_space.high

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        _, _, psi, v = obs["ego"]
        dy, v_ref = obs["target"][0], obs["target"][1]
        delta = 0.02 * dy - 0.5 * psi
        accel = 0.5 * (v_ref - v)
        for (dx, ddy, vx, _vy, length, _w), present in zip(obs["neighbours"], obs["neighbours_mask"]):
            ahead = present and 0.0 < dx < 8.0 + 1.5 * v and abs(ddy) < 1.8
            if ahead:
                accel = min(accel, 0.8 * (vx - v) - 1.0)
        return np.clip(np.array([delta, accel]), self.low, self.high)


def play(env: gym.Env, act, seeds: range) -> dict[str, float]:
    runs, steps, t0 = [], 0, time.perf_counter()
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(act(obs))
            steps += 1
            done = terminated or truncated
        runs.append(info["run"])
    return {
        "success": np.mean([r["success"] for r in runs]),
        "at_fault": sum(r["collisions_at_fault"] for r in runs),
        "score": np.mean([r["score"] for r in runs]),
        "ms_per_step": 1000 * (time.perf_counter() - t0) / steps,
    }


def main() -> None:
    print(f"{EPISODES} seeded episodes per world and agent (shipped scenes, student predictor)")
    print(f"{'world':<11} {'agent':<11} {'success':>8} {'at-fault':>9} {'score':>6} {'ms/step':>8}")
    for world in ("teacher", "idm", "log_replay"):
        env = gym.make(nudge.env.ENV_ID, world=world, action_mode="control")
        agents = {
            "lane-keeper": LaneKeeper(env.action_space).act,
            "nudge": nudge.env.NudgeAgent(env).act,
        }
        for name, act in agents.items():
            r = play(env, act, range(EPISODES))
            print(
                f"{world:<11} {name:<11} {r['success']:>8.0%} {r['at_fault']:>9d} {r['score']:>6.2f} "
                f"{r['ms_per_step']:>8.1f}"
            )
        env.close()


if __name__ == "__main__":
    main()
