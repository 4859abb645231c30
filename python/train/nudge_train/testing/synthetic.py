"""Seeded synthetic highway scenes for golden tests and benchmarks (not training data).

Road frame: x along travel (m), y lateral, positive left (m); lanes 3.7 m wide centred at
y ∈ {−7.4, −3.7, 0, 3.7, 7.4}. The ego (agent 0) drives in the middle lane and its last observed
position is within half a metre of the origin, so float32 positions keep ~1e-6 m resolution.
Every observed position is within ±60 m along x and ±8 m in y; the
others drive at 5–30 m/s (the ego at 12–25 m/s), with small lateral drift (a few change lanes
slowly). Candidates are plausible ego futures: keep speed, brake, accelerate, and
lane-change-like lateral motions.
"""

from __future__ import annotations

import numpy as np

from nudge_train.constants import DT, OBS_LEN, PRED_LEN

__all__ = ["LANE_WIDTH", "highway_candidates", "highway_history"]

LANE_WIDTH = 3.7
_LANES = np.array([-2.0, -1.0, 0.0, 1.0, 2.0]) * LANE_WIDTH
_MIN_GAP = 7.0  # m, same-lane spacing of sampled vehicles
_X_RANGE = 60.0
_Y_LIMIT = 8.0


def _sample_x_positions(
    rng: np.random.Generator, lower: np.ndarray, upper: float
) -> tuple[np.ndarray, np.ndarray]:
    """Last x (in ``[lower[k], upper]``) and lane index of the other agents, no two closer than
    ``_MIN_GAP`` in one lane (the gap shrinks only if a scene is too crowded to place a car)."""
    occupied: list[tuple[int, float]] = [(2, 0.0)]  # the ego: lane index 2 (y = 0), x ≈ 0
    n_others = int(lower.shape[0])
    xs = np.empty(n_others)
    lanes = np.empty(n_others, dtype=np.int64)
    gap = _MIN_GAP
    for k in range(n_others):
        lane, x = 0, 0.0
        for attempt in range(2000):
            lane = int(rng.integers(0, len(_LANES)))
            x = float(rng.uniform(lower[k], upper))
            if all(lane != ln or abs(x - ox) >= gap for ln, ox in occupied):
                break
            if attempt % 200 == 199:  # very crowded: accept a tighter gap rather than loop forever
                gap *= 0.8
        occupied.append((lane, x))
        xs[k] = x
        lanes[k] = lane
    return xs, lanes


def highway_history(rng: np.random.Generator, n: int, obs_len: int = OBS_LEN, dt: float = DT) -> np.ndarray:
    """History ``[n, obs_len, 2]`` float32 (m) of one scene; agent 0 is the ego.

    Each agent moves with constant longitudinal acceleration and constant lateral speed over the
    window, plus 2 cm of position noise; the last observed step is index ``obs_len − 1``.
    """
    if n < 1:
        raise ValueError(f"n: need at least the ego, got {n}")
    t = (np.arange(obs_len) - (obs_len - 1)) * dt  # [-2.1, ..., 0] s
    span = (obs_len - 1) * dt
    speed = rng.uniform(5.0, 30.0, size=n)
    speed[0] = rng.uniform(12.0, 25.0)
    accel = rng.uniform(-1.5, 1.5, size=n)
    x_last = np.empty(n)
    y_last = np.empty(n)
    x_last[0] = rng.uniform(-0.5, 0.5)
    y_last[0] = rng.uniform(-0.3, 0.3)
    if n > 1:
        # The whole observed window stays within ±_X_RANGE: x(−span) = x_last − v·span + a·span²/2.
        lower = -_X_RANGE + 0.2 + speed[1:] * span + 0.5 * np.abs(accel[1:]) * span**2
        xs, lanes = _sample_x_positions(rng, np.minimum(lower, _X_RANGE - 1.0), _X_RANGE - 0.2)
        x_last[1:] = xs
        y_last[1:] = _LANES[lanes] + rng.uniform(-0.4, 0.4, size=n - 1)
    lateral = rng.normal(0.0, 0.1, size=n)
    changers = rng.uniform(size=n) < 0.2
    lateral[changers] = rng.choice([-1.0, 1.0], size=int(changers.sum())) * rng.uniform(0.4, 1.0, size=int(changers.sum()))
    x = x_last[:, None] + speed[:, None] * t[None, :] + 0.5 * accel[:, None] * t[None, :] ** 2
    y = y_last[:, None] + lateral[:, None] * t[None, :]
    pos = np.stack([x, y], axis=-1) + rng.normal(0.0, 0.02, size=(n, obs_len, 2))
    pos[:, :, 1] = np.clip(pos[:, :, 1], -_Y_LIMIT, _Y_LIMIT)
    return pos.astype(np.float32)


def highway_candidates(
    rng: np.random.Generator, ego_history: np.ndarray, count: int, t_plan: int = PRED_LEN, dt: float = DT
) -> np.ndarray:
    """``count`` ego candidate futures ``[count, t_plan, 2]`` float32 (m) from ``ego_history``
    ``[obs_len, 2]``.

    Candidate k cycles through keep-speed, brake, lane change left, lane change right (with an
    acceleration) for k mod 4, each jittered; lane changes follow a smooth-step lateral profile
    that covers part of a 3.7 m lane change within the horizon.
    """
    last = ego_history[-1].astype(np.float64)
    vel = (ego_history[-1].astype(np.float64) - ego_history[-2].astype(np.float64)) / dt
    tau = np.arange(1, t_plan + 1) * dt  # s after the last observed step
    out = np.empty((count, t_plan, 2))
    for k in range(count):
        kind = k % 4
        accel = {0: rng.uniform(-0.3, 0.3), 1: rng.uniform(-3.0, -1.0), 2: rng.uniform(-0.5, 0.5), 3: rng.uniform(0.5, 2.0)}[kind]
        side = {0: 0.0, 1: 0.0, 2: 1.0, 3: -1.0}[kind]
        duration = rng.uniform(2.5, 5.0)  # s for a full lane change
        s = np.clip(tau / duration, 0.0, 1.0)
        smooth = s * s * (3.0 - 2.0 * s)
        speed = max(vel[0], 1.0)
        x = last[0] + speed * tau + 0.5 * accel * tau**2
        x = np.maximum.accumulate(np.maximum(x, last[0]))  # never reverse
        y = last[1] + vel[1] * tau * 0.5 + side * LANE_WIDTH * smooth + rng.normal(0.0, 0.02, size=t_plan)
        out[k, :, 0] = x
        out[k, :, 1] = y
    return out.astype(np.float32)
