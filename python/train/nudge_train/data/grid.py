"""Dense per-scene grids (vehicles x frames) built from a TrackTable, for windowing."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .tracks import TrackTable


@dataclass
class Grid:
    """Dense states of V vehicles over F frames (frame spacing ``dt`` s, first frame ``f0``).

    ``ids`` I64 [V]; ``present`` bool [V, F]; ``pos`` F64 [V, F, 2] (m, road frame, NaN where
    absent); ``heading``, ``speed`` F64 [V, F]; ``lane`` I64 [V, F] (from left, -1 absent);
    ``size`` F64 [V, 2] (length, width, m; median over the track); ``flags`` I64 [V].
    """

    ids: np.ndarray
    present: np.ndarray
    pos: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    lane: np.ndarray
    size: np.ndarray
    flags: np.ndarray
    f0: int
    dt: float

    @property
    def n_frames(self) -> int:
        return int(self.present.shape[1])


def build_grid(table: TrackTable, frame_lo: int | None = None, frame_hi: int | None = None) -> Grid:
    """Grid of the rows with frame in [frame_lo, frame_hi) (whole table when None)."""
    fr = table.frame()
    lo = int(fr.min()) if frame_lo is None else frame_lo
    hi = int(fr.max()) + 1 if frame_hi is None else frame_hi
    m = (fr >= lo) & (fr < hi)
    veh = table.vehicle[m]
    ids, vi = np.unique(veh, return_inverse=True)
    v_n, f_n = ids.shape[0], max(hi - lo, 0)
    fi = fr[m] - lo
    present = np.zeros((v_n, f_n), dtype=bool)
    present[vi, fi] = True
    pos = np.full((v_n, f_n, 2), np.nan)
    pos[vi, fi, 0] = table.x[m]
    pos[vi, fi, 1] = table.y[m]
    heading = np.full((v_n, f_n), np.nan)
    heading[vi, fi] = table.heading[m]
    speed = np.full((v_n, f_n), np.nan)
    speed[vi, fi] = table.speed[m]
    lane = np.full((v_n, f_n), -1, dtype=np.int64)
    lane[vi, fi] = table.lane[m]
    size = np.zeros((v_n, 2))
    flags = np.zeros(v_n, dtype=np.int64)
    length, width, fl = table.length[m], table.width[m], table.flags[m]
    for k in range(v_n):
        sel = vi == k
        size[k, 0] = float(np.median(length[sel]))
        size[k, 1] = float(np.median(width[sel]))
        flags[k] = int(np.bitwise_or.reduce(fl[sel]))
    return Grid(ids=ids, present=present, pos=pos, heading=heading, speed=speed, lane=lane,
                size=size, flags=flags, f0=lo, dt=table.dt)
