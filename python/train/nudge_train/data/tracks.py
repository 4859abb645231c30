"""The tidy track table shared by every reader, and the straight-lane map of a scene.

Frame convention (every reader produces it): x along the direction of travel (m), y lateral,
positive to the LEFT (m), origin arbitrary per scene; time in seconds; positions are vehicle
centres; heading in rad (0 = +x); speed in m/s; length/width in m.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Per-track flags (bit field stored in TrackTable.flags, constant within a track).
FLAG_LATERAL_SYNTHETIC = 1
"""Lateral position derived from lane centres (Coifman & Li I-80), not measured."""
FLAG_SIZE_ASSUMED = 2
"""Length/width not in the source; a default passenger-car size is used."""


@dataclass(frozen=True)
class FrenetLane:
    """Where one lane lies on the carriageway in the curvilinear frame (see
    :mod:`nudge_train.data.frenet`): from ``s_begin`` to ``s_end`` (m); ``begins`` / ``ends``: the
    lane starts (an on-ramp joining) or stops (an acceleration lane merging, an exit lane leaving)
    inside the scene. ``left``, ``right`` [K, 2]: its boundaries (s, d) over the extent (m)."""

    s_begin: float
    s_end: float
    begins: bool
    ends: bool
    left: np.ndarray
    right: np.ndarray

    def contains(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Whether points (s [N], d [N]) (m) lie in the lane's extent and lateral interval."""
        s = np.asarray(s, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        if self.left.shape[0] == 0:
            return np.zeros(s.shape, dtype=bool)
        inside = (s >= self.s_begin) & (s <= self.s_end)
        dl = np.interp(s, self.left[:, 0], self.left[:, 1])
        dr = np.interp(s, self.right[:, 0], self.right[:, 1])
        return inside & (d >= dr) & (d < dl)


@dataclass(frozen=True)
class LaneMap:
    """Straight lanes of one scene in the road frame (lanes are lines y = const).

    ``bounds`` [L+1] ascending lateral boundaries (m), first/last = road edges;
    lane i (0 = rightmost) lies between bounds[i] and bounds[i+1].
    ``x_range`` (xmin, xmax): longitudinal extent the map is valid over (m).
    ``straightness_m``: worst deviation of a lane boundary from y = const over the scene (m).
    """

    bounds: np.ndarray
    x_range: tuple[float, float]
    straightness_m: float = 0.0
    # Optional per-x lane structure (CommonRoad lanelets with ramps): list of (x0, x1, bounds).
    pieces: tuple[tuple[float, float, np.ndarray], ...] = ()
    # Lanelet boundary polylines in the road frame ([P, 2] each, x ascending), for local checks.
    polylines: tuple[np.ndarray, ...] = ()
    # Curvilinear frame only: every lane with its extent along s (empty in the straightened frame).
    lanes: tuple[FrenetLane, ...] = ()

    def ending_lane(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether points (x [N], y [N]) (m) lie in a lane that ends inside the scene ahead of
        them (an acceleration or exit lane: a merge must happen before its end). All False in
        the straightened frame, which has no lane extents."""
        x = np.asarray(x, dtype=np.float64)
        out = np.zeros(x.shape, dtype=bool)
        for lane in self.lanes:
            if lane.ends:
                out |= lane.contains(x, y) & (x < lane.s_end)
        return out

    def local_deviation(self, x: float, half_range: float = 100.0) -> float:
        """Worst deviation (m) of a boundary covering ``x`` from y = y(x) within ``x`` +- half_range.

        0.0 for maps without polylines (lanes defined as straight by construction).
        """
        worst = 0.0
        for p in self.polylines:
            if not (p[0, 0] <= x <= p[-1, 0]):
                continue
            y0 = float(np.interp(x, p[:, 0], p[:, 1]))
            m = np.abs(p[:, 0] - x) <= half_range
            # Include interpolated points at the window ends for sparse polylines.
            xs = np.concatenate([p[m, 0], np.clip([x - half_range, x + half_range], p[0, 0], p[-1, 0])])
            ys = np.interp(xs, p[:, 0], p[:, 1])
            worst = max(worst, float(np.max(np.abs(ys - y0))))
        return worst

    def bounds_at(self, x: float) -> np.ndarray:
        """Ascending lane boundaries [L+1] (m) that exist at longitudinal position ``x`` (m)."""
        for x0, x1, b in self.pieces:
            if x0 <= x <= x1:
                return b
        if self.pieces:
            # Outside every piece: nearest piece.
            d = [min(abs(x - x0), abs(x - x1)) for x0, x1, _ in self.pieces]
            return self.pieces[int(np.argmin(d))][2]
        return self.bounds

    def centres_at(self, x: float) -> np.ndarray:
        """Ascending lane centres [L] (m) at ``x`` (m)."""
        b = self.bounds_at(x)
        return 0.5 * (b[:-1] + b[1:])


@dataclass
class TrackTable:
    """One tidy table of vehicle states (all columns have the same length N, one row per state).

    Rows are sorted by (vehicle, time). Columns:
    ``vehicle`` I64 [N] vehicle id within the scene; ``t`` F64 [N] time (s);
    ``x``, ``y`` F64 [N] centre (m, road frame); ``heading`` F64 [N] (rad);
    ``speed`` F64 [N] (m/s); ``length``, ``width`` F64 [N] (m);
    ``lane`` I64 [N] lane index counted from the LEFT road edge (0 = leftmost, -1 = off-road);
    ``flags`` I64 [N] FLAG_* bits.
    """

    scene: str
    source: str
    vehicle: np.ndarray
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    length: np.ndarray
    width: np.ndarray
    lane: np.ndarray
    flags: np.ndarray
    lanes: LaneMap
    dt: float = 0.1
    notes: dict[str, int] = field(default_factory=dict)

    COLUMNS = ("vehicle", "t", "x", "y", "heading", "speed", "length", "width", "lane", "flags")

    def __len__(self) -> int:
        return int(self.vehicle.shape[0])

    def vehicle_ids(self) -> np.ndarray:
        """Sorted unique vehicle ids."""
        return np.unique(self.vehicle)

    def frame(self) -> np.ndarray:
        """Integer frame index (round(t / dt)) of every row."""
        return np.rint(self.t / self.dt).astype(np.int64)

    def select(self, mask: np.ndarray) -> TrackTable:
        """A copy holding only the rows where ``mask`` is true."""
        kw = {c: getattr(self, c)[mask] for c in self.COLUMNS}
        return TrackTable(scene=self.scene, source=self.source, lanes=self.lanes, dt=self.dt,
                          notes=dict(self.notes), **kw)


def lane_index_from_left(y: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Lane index counted from the left edge (0 = leftmost) for lateral positions ``y`` [N] (m).

    ``bounds`` [L+1] ascending. Positions outside the road get the nearest edge lane.
    """
    n_lanes = bounds.shape[0] - 1
    right_idx = np.searchsorted(bounds, y, side="right") - 1  # 0 = rightmost
    right_idx = np.clip(right_idx, 0, n_lanes - 1)
    return (n_lanes - 1 - right_idx).astype(np.int64)


def sort_and_check(table: TrackTable) -> TrackTable:
    """Sort rows by (vehicle, t); the caller guarantees no duplicate (vehicle, frame) keys."""
    order = np.lexsort((table.t, table.vehicle))
    return table.select(order)
