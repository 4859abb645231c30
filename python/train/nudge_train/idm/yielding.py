"""The IDM world's intrusion rule, fitted to the real cut-ins.

Rule: a follower treats an intruding vehicle as its leader once the intruder's nearest edge is
more than ``threshold`` (m) inside the follower's lane (negative: before it reaches the line);
with probability ``1 - p_yield`` the follower does not yield early and reacts only once the
intruder is entirely inside the lane (far edge across the line). Before that it follows its
previous leader (free road if none).

Fit: every US-101 cut-in of the TRAIN split is replayed with IDM followers (drivers drawn, seeded,
from the train population) behind the real old leader and the real intruder; the expected
simulated fall-back curve of each event (mean over draws, mixed over p_yield) is compared with the
real one, and (threshold, p_yield) minimise the squared distance between the median simulated and
the median real curves at tau = 0.3 ... 4.2 s. The held-out events (val + test) report the result.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .cutins import TAUS, CutIn, Tracks, fall_back, overlap_series
from .model import simulate_follower


@dataclass(frozen=True)
class YieldConfig:
    """Grid and sampling of the rule fit (the one source of their defaults)."""

    thresholds: tuple[float, ...] = tuple(float(v) for v in np.round(np.arange(-0.8, 2.01, 0.1), 2))
    p_yield: tuple[float, ...] = tuple(float(v) for v in np.round(np.arange(0.0, 1.001, 0.1), 2))
    draws: int = 32
    seed: int = 0
    lead_in_s: float = 2.0


@dataclass
class EventSim:
    """Simulated fall-back curves of one event: ``by_threshold`` [n_thresholds, len(TAUS)] (mean
    over drivers; NaN past the follower's observed horizon) and ``late`` [len(TAUS)] (react only
    at full entry); ``real`` [len(TAUS)]; ``switch_s`` [n_thresholds] (switch time relative to the
    centre crossing, NaN if never reached); ``pos_err`` [n_thresholds, len(TAUS)] and
    ``pos_err_late`` [len(TAUS)]: mean over drivers of simulated minus real follower position (m)
    at t_centre + tau (the simulation starts ``lead_in_s`` before the edge crossing)."""

    event: CutIn
    by_threshold: np.ndarray
    late: np.ndarray
    real: np.ndarray
    switch_s: np.ndarray
    pos_err: np.ndarray
    pos_err_late: np.ndarray


def _series(tr: Tracks, vid: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rear position, speed) [len(t)] of ``vid``; NaN where it is not observed."""
    return tr.series(vid, "x", t) - 0.5 * tr.series(vid, "length", t), tr.series(vid, "speed", t)


def simulate_event(tr: Tracks, e: CutIn, drivers: np.ndarray, thresholds: np.ndarray, cfg: YieldConfig,
                   delta: float = 4.0) -> EventSim:
    """Replay one cut-in with IDM followers ``drivers`` [D, 5] for every threshold."""
    dt = tr.dt
    t_ref = e.t_edge if e.t_edge is not None else e.t_centre
    t_s = max(t_ref - cfg.lead_in_s, e.t_centre - e.follower_before_s)
    n = int(np.floor((e.t_centre + e.follower_after_s - t_s) / dt + 1e-9)) + 1
    t = t_s + np.arange(n) * dt
    xf = tr.series(e.follower, "x", t) + 0.5 * tr.series(e.follower, "length", t)
    vf = tr.series(e.follower, "speed", t)
    v_ref = float(np.max(tr.table.speed[tr.rows[e.follower]]))
    if e.old_leader >= 0:
        old_r, old_v = _series(tr, e.old_leader, t)
    else:
        old_r, old_v = np.full(n, np.nan), np.zeros(n)
    int_r, int_v = _series(tr, e.intruder, t)
    if e.source == "us101":
        centre, edge = overlap_series(tr, e.intruder, t, e.lane_from, e.lane_to)
        far = 2.0 * centre - edge
    else:  # longitudinal only: the lane-ID jump is the only lateral event
        edge = np.where(t >= e.t_centre - 1e-9, np.inf, -np.inf)
        far = edge
    taus_t = e.t_centre + TAUS
    valid = TAUS <= e.follower_after_s + 1e-9

    x_real = tr.series(e.follower, "x", taus_t) + 0.5 * tr.series(e.follower, "length", taus_t)

    def curve(switch: int | None) -> tuple[np.ndarray, np.ndarray]:
        lr, lv = old_r.copy(), np.nan_to_num(old_v)
        if switch is not None:
            ir = int_r[switch:]
            use = np.isfinite(ir) & (~np.isfinite(lr[switch:]) | (ir < lr[switch:]))
            lr[switch:] = np.where(use, ir, lr[switch:])
            lv[switch:] = np.where(use, np.nan_to_num(int_v[switch:]), lv[switch:])
        sim = simulate_follower(xf[0], vf[0], lr, lv, drivers[:, :4], drivers[:, 4] * v_ref, dt, delta)
        x = np.stack([np.interp(taus_t, t, row) for row in sim.x])
        v_c = np.array([np.interp(e.t_centre, t, row) for row in sim.v])
        fb = x - (x[:, :1] + v_c[:, None] * TAUS[None, :])
        out = fb.mean(axis=0)
        err = (x - x_real[None, :]).mean(axis=0)
        return np.where(valid, out, np.nan), np.where(valid, err, np.nan)

    cache: dict[int | None, tuple[np.ndarray, np.ndarray]] = {}

    def first(mask: np.ndarray) -> int | None:
        idx = np.flatnonzero(np.nan_to_num(mask, nan=0).astype(bool))
        return int(idx[0]) if idx.shape[0] else None

    rows, errs, sw = [], [], []
    for th in thresholds:
        k = first(edge >= th)
        if k not in cache:
            cache[k] = curve(k)
        rows.append(cache[k][0])
        errs.append(cache[k][1])
        sw.append(np.nan if k is None else t[k] - e.t_centre)
    k_late = first(far >= 0.0)
    late, err_late = cache[k_late] if k_late in cache else curve(k_late)
    real = np.where(valid, fall_back(tr, e.follower, e.t_centre), np.nan)
    return EventSim(event=e, by_threshold=np.stack(rows), late=late, real=real, switch_s=np.asarray(sw),
                    pos_err=np.stack(errs), pos_err_late=err_late)


def mixed_pos_err(sims: list[EventSim], i_threshold: int, p: float) -> np.ndarray:
    """Expected simulated-minus-real follower position [E, len(TAUS)] (m) for a rule."""
    return np.stack([p * s.pos_err[i_threshold] + (1.0 - p) * s.pos_err_late for s in sims])


def mixed(sims: list[EventSim], i_threshold: int, p: float) -> np.ndarray:
    """Expected simulated curves [E, len(TAUS)] for threshold index and yield probability."""
    return np.stack([p * s.by_threshold[i_threshold] + (1.0 - p) * s.late for s in sims])


def curve_loss(sim: np.ndarray, real: np.ndarray) -> float:
    """Squared distance (m^2) between the median curves over tau = 0.3 ... 4.2 s."""
    ms = np.nanmedian(sim, axis=0)[1:]
    mr = np.nanmedian(real, axis=0)[1:]
    return float(np.nansum((ms - mr) ** 2))


@dataclass
class RuleFit:
    """Grid losses [n_thresholds, n_p] on the train events and the chosen rule."""

    thresholds: np.ndarray
    p_yield: np.ndarray
    loss: np.ndarray
    threshold: float
    p: float
    notes: dict = field(default_factory=dict)


def fit_rule(sims: list[EventSim], cfg: YieldConfig) -> RuleFit:
    """Grid search of (threshold, p_yield) on ``sims`` (first minimum in grid order)."""
    th = np.asarray(cfg.thresholds)
    ps = np.asarray(cfg.p_yield)
    real = np.stack([s.real for s in sims])
    loss = np.array([[curve_loss(mixed(sims, i, p), real) for p in ps] for i in range(th.shape[0])])
    i, j = np.unravel_index(int(np.argmin(loss)), loss.shape)
    return RuleFit(thresholds=th, p_yield=ps, loss=loss, threshold=float(th[i]), p=float(ps[j]))


def sample_drivers(population: np.ndarray, cfg: YieldConfig) -> np.ndarray:
    """``cfg.draws`` drivers [D, 5] drawn with replacement (seeded) from ``population`` [N, 5]."""
    rng = np.random.default_rng([cfg.seed, 15])
    return population[rng.integers(0, population.shape[0], size=cfg.draws)]
