"""Training windows cut from the tracks: 10 Hz -> 0.3 s resampling, 8 observed + 6 future steps,
filters, labels. :mod:`nudge_train.data.build` writes them as shards; :mod:`nudge_train.data.loader`
reads the shards back for training."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from nudge_train.constants import DT, OBS_LEN, PRED_LEN

from .grid import Grid
from .tracks import LaneMap


@dataclass(frozen=True)
class WindowConfig:
    """Window extraction parameters (units: s, m, m/s, m/s^2, m/s^3)."""

    step_s: float = DT
    n_obs: int = OBS_LEN
    n_fut: int = PRED_LEN
    phases: tuple[int, ...] = (0, 1, 2)
    max_agents: int = 47
    neighbour_range_m: float = 60.0
    max_speed: float = 45.0
    min_forward_speed: float = -1.0
    max_accel: float = 8.0
    max_jerk: float = 40.0
    overlap_shrink: float = 0.8
    lane_change_min_dy: float = 1.0

    @property
    def n_steps(self) -> int:
        return self.n_obs + self.n_fut


RULES = ("speed", "accel", "jerk", "overlap")


@dataclass
class WindowStats:
    """Counters: candidate windows, kept windows, drops per rule (windows and agents)."""

    candidates: int = 0
    kept: int = 0
    agents_kept: int = 0
    windows_dropped: Counter = field(default_factory=Counter)
    agents_dropped: Counter = field(default_factory=Counter)

    def merge(self, other: "WindowStats") -> None:
        self.candidates += other.candidates
        self.kept += other.kept
        self.agents_kept += other.agents_kept
        self.windows_dropped.update(other.windows_dropped)
        self.agents_dropped.update(other.agents_dropped)


@dataclass
class Window:
    """One training window. ``positions`` F64 [n, 14, 2] (m, road frame, relative to the ego at
    the last observed step), agent 0 = ego; ``size`` [n, 2]; ``lane_change`` bool [n];
    ``ids`` I64 [n]; ``t0`` time of the last observed step (s); ``origin`` [2] ego position (m)."""

    positions: np.ndarray
    size: np.ndarray
    lane_change: np.ndarray
    ids: np.ndarray
    flags: np.ndarray
    t0: float
    phase: int
    origin: np.ndarray

    @property
    def interactive(self) -> bool:
        return bool(self.lane_change.any())


def is_merge_window(window: Window, lanes: LaneMap, n_obs: int = OBS_LEN) -> bool:
    """Whether a window of a table with lane map ``lanes`` is a *merge window*: at least one of
    its agents is, at the last observed step (index ``n_obs - 1``), in a lane that ends ahead
    inside the scene (:meth:`~nudge_train.data.tracks.LaneMap.ending_lane`). Always False in a
    frame without lane extents (the straightened frame, I-80)."""
    if not lanes.lanes:
        return False
    last = window.positions[:, n_obs - 1] + window.origin
    return bool(lanes.ending_lane(last[:, 0], last[:, 1]).any())


def kinematic_violations(pos: np.ndarray, dt: float, cfg: WindowConfig) -> dict[str, np.ndarray]:
    """Per-agent rule violations for positions [n, T, 2] sampled every dt s: rule -> bool [n]."""
    v = np.diff(pos, axis=1) / dt  # [n, T-1, 2]
    a = np.diff(v, axis=1) / dt
    j = np.diff(a, axis=1) / dt
    speed = np.linalg.norm(v, axis=2)
    return {
        "speed": (speed > cfg.max_speed).any(axis=1) | (v[..., 0] < cfg.min_forward_speed).any(axis=1),
        "accel": (np.linalg.norm(a, axis=2) > cfg.max_accel).any(axis=1),
        "jerk": (np.linalg.norm(j, axis=2) > cfg.max_jerk).any(axis=1),
    }


def overlapping_pairs(pos: np.ndarray, size: np.ndarray, shrink: float) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, whose boxes (road-frame aligned, shrunk by ``shrink``) overlap at
    any step. pos [n, T, 2] (m), size [n, 2] (length, width, m)."""
    n = pos.shape[0]
    if n < 2:
        return []
    dx = np.abs(pos[:, None, :, 0] - pos[None, :, :, 0])
    dy = np.abs(pos[:, None, :, 1] - pos[None, :, :, 1])
    lx = shrink * 0.5 * (size[:, None, 0] + size[None, :, 0])
    ly = shrink * 0.5 * (size[:, None, 1] + size[None, :, 1])
    hit = ((dx < lx[..., None]) & (dy < ly[..., None])).any(axis=2)
    iu, ju = np.nonzero(np.triu(hit, k=1))
    return list(zip(iu.tolist(), ju.tolist()))


def choose_ego(pos_last: np.ndarray, range_m: float) -> int:
    """Index of the agent with the most neighbours within range_m at the last observed step
    (ties: lowest index). pos_last [n, 2]."""
    d = np.linalg.norm(pos_last[:, None, :] - pos_last[None, :, :], axis=2)
    counts = (d < range_m).sum(axis=1)
    return int(np.argmax(counts))


def extract_windows(grid: Grid, cfg: WindowConfig, t_offset: float = 0.0,
                    stats: WindowStats | None = None) -> list[Window]:
    """All windows of a grid (10 Hz frames). Window starts every ``step_s`` in each phase of
    ``cfg.phases`` (phase p starts at frame p, p+3, ...). Keeps agents present in all 14 steps,
    drops implausible agents (rules in RULES; a window with < 2 agents left is dropped and the
    rule that removed the last neighbour or the ego is counted), caps at ``max_agents`` nearest
    to the ego. Lane change label: lane index differs between the first and last step and the
    agent moved at least ``lane_change_min_dy`` laterally (so boundary jitter does not count).
    """
    st = stats if stats is not None else WindowStats()
    stride = int(round(cfg.step_s / grid.dt))
    span = stride * (cfg.n_steps - 1)
    out: list[Window] = []
    for phase in cfg.phases:
        for s in range(phase, grid.n_frames - span, stride):
            frames = s + stride * np.arange(cfg.n_steps)
            full = grid.present[:, frames].all(axis=1)
            idx = np.flatnonzero(full)
            st.candidates += 1
            if idx.shape[0] < 2:
                st.windows_dropped["fewer_than_2_agents"] += 1
                continue
            pos = grid.pos[idx][:, frames]
            viol = kinematic_violations(pos, cfg.step_s, cfg)
            bad = np.zeros(idx.shape[0], dtype=bool)
            for rule in ("speed", "accel", "jerk"):
                newly = viol[rule] & ~bad
                st.agents_dropped[rule] += int(newly.sum())
                bad |= viol[rule]
            keep = ~bad
            idx, pos = idx[keep], pos[keep]
            if idx.shape[0] < 2:
                st.windows_dropped["kinematics_left_lt_2_agents"] += 1
                continue
            ego = choose_ego(pos[:, cfg.n_obs - 1], cfg.neighbour_range_m)
            d = np.linalg.norm(pos[:, cfg.n_obs - 1] - pos[ego, cfg.n_obs - 1], axis=1)
            order = np.lexsort((grid.ids[idx], d))  # ego first (d = 0)
            order = np.concatenate([[ego], order[order != ego]])
            idx, pos, d = idx[order], pos[order], d[order]
            size = grid.size[idx]
            drop = np.zeros(idx.shape[0], dtype=bool)
            for i, j in overlapping_pairs(pos, size, cfg.overlap_shrink):
                if not drop[i] and not drop[j]:
                    drop[max(i, j)] = True  # the one farther from the ego (ego is index 0)
            st.agents_dropped["overlap"] += int(drop.sum())
            idx, pos = idx[~drop], pos[~drop]
            if idx.shape[0] < 2:
                st.windows_dropped["overlap_left_lt_2_agents"] += 1
                continue
            if idx.shape[0] > cfg.max_agents:
                st.agents_dropped["beyond_max_agents"] += idx.shape[0] - cfg.max_agents
                idx, pos = idx[: cfg.max_agents], pos[: cfg.max_agents]
            lanes = grid.lane[idx][:, frames]
            dy = np.abs(pos[:, -1, 1] - pos[:, 0, 1])
            lane_change = ((lanes[:, 0] != lanes[:, -1]) & (lanes[:, 0] >= 0) & (lanes[:, -1] >= 0)
                           & (dy >= cfg.lane_change_min_dy))
            origin = pos[0, cfg.n_obs - 1].copy()
            out.append(Window(
                positions=pos - origin, size=grid.size[idx], lane_change=lane_change,
                ids=grid.ids[idx], flags=grid.flags[idx],
                t0=t_offset + (grid.f0 + frames[cfg.n_obs - 1]) * grid.dt, phase=phase, origin=origin))
            st.kept += 1
            st.agents_kept += idx.shape[0]
    return out
