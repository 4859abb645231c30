"""Leader-follower pairs for the IDM calibration.

* I-80: the EMD-smoothed car-following pairs (one pair per follower, lanes 1-3, no lane changers).
  Follower front = ``local_y``; leader rear = ``preceding_local_y - preceding_length`` (NGSIM
  positions are front centres).
* US-101: extracted from the CommonRoad tracks (road frame, vehicle centres): at every frame a
  vehicle's leader is the nearest vehicle ahead in the same lane; a pair is a run of consecutive
  frames with the same leader, both in one lane, at least ``min_s`` long. Vehicles repeated across
  scenes of one overlap group (same traffic re-cut) are found by their speed profiles and kept
  once (the longer run).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nudge_train.data.errors import DataError, read_source
from nudge_train.data.tracks import TrackTable

from .sources import SceneSource, Sources


@dataclass
class Pair:
    """One follower behind one leader over K consecutive samples ``dt`` apart.

    ``xf`` [K] follower front (m), ``vf`` [K] follower speed (m/s), ``lead_rear`` [K] leader rear
    (m), ``vl`` [K] leader speed (m/s); ``t0`` time of the first sample (s); ``frame0`` its frame.
    """

    source: str
    scene: str
    group: str
    split: str
    follower: int
    leader: int
    frame0: int
    dt: float
    xf: np.ndarray
    vf: np.ndarray
    lead_rear: np.ndarray
    vl: np.ndarray

    @property
    def key(self) -> str:
        """Unique id ``source:scene:follower:leader:frame0``."""
        return f"{self.source}:{self.scene}:{self.follower}:{self.leader}:{self.frame0}"

    @property
    def gap(self) -> np.ndarray:
        """Bumper-to-bumper gap [K] (m)."""
        return self.lead_rear - self.xf

    @property
    def duration(self) -> float:
        """Length of the record (s)."""
        return (self.xf.shape[0] - 1) * self.dt


@dataclass
class PairStats:
    """What the extraction kept and dropped (reason -> count)."""

    kept: int = 0
    dropped: dict[str, int] = field(default_factory=dict)

    def drop(self, reason: str, n: int = 1) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + n


I80_COLUMNS = ("pair_id", "vehicle_id", "frame_id", "local_y", "v_vel", "preceding", "preceding_local_y",
               "preceding_length", "preceding_vel", "lane_id")


def read_i80_pairs(path: Path, sources: Sources | None, stats: PairStats | None = None,
                   min_s: float = 5.0) -> list[Pair]:
    """Read the I-80 car-following pairs; split = the pipeline's I-80 time block of the pair's
    middle frame (``sources=None``: every pair ``train``). Pairs with a gap <= 0 anywhere
    (overlapping vehicles: a tracking error), a frame gap, or shorter than ``min_s`` are dropped
    and counted in ``stats``."""
    path = Path(path)
    stats = stats if stats is not None else PairStats()
    try:
        rows = list(csv.reader(io.StringIO(read_source(path).decode("utf-8"), newline="")))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DataError(path, f"cannot read: {exc}") from exc
    if len(rows) < 2:
        raise DataError(path, "no data rows")
    head = rows[0]
    missing = [c for c in I80_COLUMNS if c not in head]
    if missing:
        raise DataError(path, f"missing columns {missing}", row=1)
    idx = {c: head.index(c) for c in I80_COLUMNS}
    pid = [r[idx["pair_id"]] if len(r) == len(head) else None for r in rows[1:]]
    for i, p in enumerate(pid):
        if p is None:
            raise DataError(path, f"expected {len(head)} fields, got {len(rows[i + 1])}", row=i + 2)
    num_cols = [c for c in I80_COLUMNS if c != "pair_id"]
    vals = np.empty((len(rows) - 1, len(num_cols)))
    for j, c in enumerate(num_cols):
        k = idx[c]
        try:
            vals[:, j] = [float(r[k]) for r in rows[1:]]
        except ValueError as exc:
            raise DataError(path, f"column {c!r}: non-numeric value ({exc})") from exc
    bad = ~np.isfinite(vals)
    if bad.any():
        r, j = np.argwhere(bad)[0]
        raise DataError(path, f"column {num_cols[j]!r} is not finite", row=int(r) + 2)
    col = {c: vals[:, j] for j, c in enumerate(num_cols)}
    out: list[Pair] = []
    order = sorted(set(pid), key=lambda p: (int(p.split("-")[0]) if p.split("-")[0].isdigit() else 0, p))
    rows_of: dict[str, list[int]] = {}
    for i, p in enumerate(pid):
        rows_of.setdefault(p, []).append(i)
    for p in order:
        ii = np.asarray(rows_of[p])
        ii = ii[np.argsort(col["frame_id"][ii], kind="stable")]
        fr = col["frame_id"][ii].astype(np.int64)
        if len(set(col["vehicle_id"][ii])) != 1 or len(set(col["preceding"][ii])) != 1:
            raise DataError(path, f"pair {p}: more than one follower or leader", row=int(ii[0]) + 2)
        if np.any(np.diff(fr) != 1):
            stats.drop("frame gap or duplicate frame")
            continue
        xf = col["local_y"][ii]
        lead_rear = col["preceding_local_y"][ii] - col["preceding_length"][ii]
        if (len(ii) - 1) * 0.1 < min_s - 1e-9:
            stats.drop(f"shorter than {min_s:g} s")
            continue
        if np.any(lead_rear - xf <= 0.0):
            stats.drop("gap <= 0 (overlapping vehicles)")
            continue
        mid = 0.5 * (fr[0] + fr[-1])
        split = sources.i80_split(mid) if sources is not None else "train"
        out.append(Pair(source="i80", scene="i80-0400-0415", group="i80", split=split,
                        follower=int(col["vehicle_id"][ii[0]]), leader=int(col["preceding"][ii[0]]),
                        frame0=int(fr[0]), dt=0.1, xf=xf, vf=col["v_vel"][ii], lead_rear=lead_rear,
                        vl=col["preceding_vel"][ii]))
        stats.kept += 1
    return out


@dataclass
class Grid:
    """A scene's tracks on a (vehicle, frame) grid: ``ids`` [V]; ``frames`` [F]; ``x``, ``y``,
    ``v``, ``length``, ``width``, ``heading`` [V, F] (NaN where absent); ``lane`` [V, F] (-1 absent)."""

    ids: np.ndarray
    frames: np.ndarray
    x: np.ndarray
    y: np.ndarray
    v: np.ndarray
    length: np.ndarray
    width: np.ndarray
    heading: np.ndarray
    lane: np.ndarray
    dt: float


def to_grid(table: TrackTable) -> Grid:
    """Lay a track table on a dense (vehicle, frame) grid."""
    fr = table.frame()
    ids, vi = np.unique(table.vehicle, return_inverse=True)
    f0 = int(fr.min())
    frames = np.arange(f0, int(fr.max()) + 1)
    fi = fr - f0
    shape = (ids.shape[0], frames.shape[0])

    def lay(values: np.ndarray) -> np.ndarray:
        g = np.full(shape, np.nan)
        g[vi, fi] = values
        return g

    lane = np.full(shape, -1, dtype=np.int64)
    lane[vi, fi] = table.lane
    return Grid(ids=ids, frames=frames, x=lay(table.x), y=lay(table.y), v=lay(table.speed),
                length=lay(table.length), width=lay(table.width), heading=lay(table.heading), lane=lane,
                dt=table.dt)


def leaders(grid: Grid) -> np.ndarray:
    """Index [V, F] of each vehicle's leader (nearest centre ahead in the same lane), -1 if none."""
    lead = np.full(grid.lane.shape, -1, dtype=np.int64)
    for f in range(grid.frames.shape[0]):
        present = np.flatnonzero(grid.lane[:, f] >= 0)
        for ln in np.unique(grid.lane[present, f]):
            vs = present[grid.lane[present, f] == ln]
            vs = vs[np.argsort(grid.x[vs, f], kind="stable")]
            lead[vs[:-1], f] = vs[1:]
    return lead


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open [start, end) runs of True in a 1-D boolean array."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def scene_pairs(scene: SceneSource, min_s: float, stats: PairStats) -> list[Pair]:
    """Leader-follower runs of one US-101 scene (before de-duplication across scenes)."""
    g = to_grid(scene.table)
    lead = leaders(g)
    min_len = int(round(min_s / g.dt)) + 1
    out = []
    for v in range(g.ids.shape[0]):
        lv = lead[v]
        # Change points: leader or own lane changes.
        key = np.where(lv >= 0, lv * 100 + np.maximum(g.lane[v], 0), -1)
        start = 0
        n = key.shape[0]
        while start < n:
            end = start
            while end < n and key[end] == key[start]:
                end += 1
            if key[start] >= 0:
                if end - start >= min_len:
                    li = int(lv[start])
                    sl = slice(start, end)
                    xf = g.x[v, sl] + 0.5 * g.length[v, sl]
                    lr = g.x[li, sl] - 0.5 * g.length[li, sl]
                    if np.any(lr - xf <= 0.0):
                        stats.drop("gap <= 0 (overlapping boxes)")
                    else:
                        out.append(Pair(source="us101", scene=scene.name, group=scene.group, split=scene.split,
                                        follower=int(g.ids[v]), leader=int(g.ids[li]),
                                        frame0=int(g.frames[start]), dt=g.dt, xf=xf, vf=g.v[v, sl].copy(),
                                        lead_rear=lr, vl=g.v[li, sl].copy()))
                else:
                    stats.drop(f"run shorter than {min_s:g} s")
            start = end
    return out


def _signatures(p: Pair, width: int = 20) -> set[bytes]:
    """Speed-profile fingerprints of a pair (follower and leader speeds, mm/s, ``width`` samples)."""
    fv = np.rint(p.vf * 1000).astype(np.int64)
    lv = np.rint(p.vl * 1000).astype(np.int64)
    return {fv[i:i + width].tobytes() + lv[i:i + width].tobytes() for i in range(0, fv.shape[0] - width + 1)}


def dedupe(pairs: list[Pair], stats: PairStats) -> list[Pair]:
    """Keep one copy of a (follower, leader) run repeated in several scenes of one overlap group
    (identical speed profiles over 2 s); the longer run wins, the earlier scene on ties."""
    order = sorted(range(len(pairs)), key=lambda i: (-pairs[i].xf.shape[0], i))
    seen: dict[str, set[bytes]] = {}
    keep = []
    for i in order:
        p = pairs[i]
        sig = _signatures(p)
        grp = seen.setdefault(p.group, set())
        if sig & grp:
            stats.drop("repeated in another scene of the overlap group")
            continue
        grp |= sig
        keep.append(i)
    return [pairs[i] for i in sorted(keep)]


def us101_pairs(sources: Sources, min_s: float = 5.0, stats: PairStats | None = None) -> list[Pair]:
    """Every US-101 leader-follower pair of at least ``min_s`` seconds, de-duplicated."""
    stats = stats if stats is not None else PairStats()
    raw: list[Pair] = []
    for sc in sources.us101:
        raw += scene_pairs(sc, min_s, stats)
    out = dedupe(raw, stats)
    stats.kept += len(out)
    return out
