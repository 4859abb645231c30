"""Reader for the partial US-101 vehicle set in metres (``chenshimao_us101_partial_per_vehicle_metric``).

370 whole US-101 trajectories (7:50–8:35 am, 10 Hz) of the official data converted to metres,
without lane ids, vehicle sizes or most neighbours (PROVENANCE.md). Columns used:
``Vehicle_ID``, ``Frame_ID``, ``Global_Time`` (ms), ``local_x(m)`` (lateral, from the left edge of
the road, of the vehicle's FRONT centre), ``local_y(m)`` (longitudinal, of the front centre),
``v_Vel(m)`` (m/s). Frame_ID restarts with each 15-minute period, so time comes from Global_Time.
Vehicle ids repeat across periods in NGSIM: a track is one (Vehicle_ID, period) pair, split where
consecutive rows are more than one frame apart in Global_Time.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DataError, read_source

__all__ = ["PartialTracks", "read_chenshimao"]

COLUMNS = ("Vehicle_ID", "Frame_ID", "Global_Time", "local_x(m)", "local_y(m)", "v_Vel(m)")
"""The columns the reader needs (the file has more)."""

DT_MS = 100
"""Sampling interval of the file (ms)."""


@dataclass(frozen=True)
class PartialTracks:
    """Rows sorted by (track, time), all columns [N]: ``track`` I64 (one per vehicle and
    period, numbered from 0), ``vehicle`` I64 (the file's Vehicle_ID), ``t`` F64 (s since the
    first row of the file), ``s`` F64 (m, along the road, front centre), ``lateral_from_left``
    F64 (m, from the left edge of the road, front centre), ``speed`` F64 (m/s, the file's v_Vel)."""

    source: str
    track: np.ndarray
    vehicle: np.ndarray
    t: np.ndarray
    s: np.ndarray
    lateral_from_left: np.ndarray
    speed: np.ndarray
    dt: float = DT_MS / 1000.0

    def bounds(self) -> list[tuple[int, int]]:
        """[start, end) row ranges of every track."""
        starts = np.flatnonzero(np.concatenate([[True], self.track[1:] != self.track[:-1]]))
        ends = np.concatenate([starts[1:], [self.track.shape[0]]])
        return [(int(a), int(b)) for a, b in zip(starts, ends)]


def read_chenshimao(path: Path | str) -> PartialTracks:
    """Read the file into :class:`PartialTracks`.

    Raises:
        DataError: naming the file (and row, field) when it is missing or unreadable, lacks a
        column of :data:`COLUMNS`, holds a value that is not a finite number, a duplicate
        (Vehicle_ID, Global_Time) key, or a Global_Time off the 100 ms grid.
    """
    path = Path(path)
    try:
        text = read_source(path).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(path, f"not UTF-8 text: {exc}") from None
    first = text.split("\n", 1)[0]
    head = [h.strip() for h in next(csv.reader([first]), [])]
    if not head or head == [""]:
        raise DataError(path, "empty file")
    missing = [c for c in COLUMNS if c not in head]
    if missing:
        raise DataError(path, f"missing columns {missing} (found {head})", row=1)
    idx = [head.index(c) for c in COLUMNS]
    try:  # the fast path; any problem is located by the slow one below
        vals = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, usecols=idx, ndmin=2, dtype=np.float64)
        fast = vals.shape[0] > 0 and bool(np.all(np.isfinite(vals)))
    except ValueError:
        fast = False
    if not fast:
        vals = _slow_values(path, text, idx)
    return _tracks(path, vals)


def _slow_values(path: Path, text: str, idx: list[int]) -> np.ndarray:
    """The values of the columns ``idx``, row by row, or the DataError naming the first bad one."""
    try:
        rows = list(csv.reader(io.StringIO(text)))
    except csv.Error as exc:
        raise DataError(path, f"not a CSV table: {exc}") from None
    data = [(line, r) for line, r in enumerate(rows[1:], start=2) if r]
    if not data:
        raise DataError(path, "no data rows (header only)")
    vals = np.empty((len(data), len(COLUMNS)))
    for n, (line, row) in enumerate(data):
        for k, i in enumerate(idx):
            try:
                v = float(row[i])
            except (ValueError, IndexError):
                raise DataError(path, f"{COLUMNS[k]} is not a number: {row[i] if i < len(row) else ''!r}",
                                row=line, field=COLUMNS[k]) from None
            if not math.isfinite(v):
                raise DataError(path, f"{COLUMNS[k]} is not finite: {row[i]!r}", row=line, field=COLUMNS[k])
            vals[n, k] = v
    return vals


def _tracks(path: Path, vals: np.ndarray) -> PartialTracks:
    """Tracks from the values [N, len(COLUMNS)] in file order."""
    vehicle = vals[:, 0].astype(np.int64)
    gt = vals[:, 2].astype(np.int64)
    off = gt % DT_MS
    if np.any(off != off[0]):
        r = int(np.flatnonzero(off != off[0])[0])
        raise DataError(path, f"Global_Time {gt[r]} is off the {DT_MS} ms grid of the first row", row=r + 2,
                        field="Global_Time")
    order = np.lexsort((gt, vehicle))
    dup = (vehicle[order][1:] == vehicle[order][:-1]) & (gt[order][1:] == gt[order][:-1])
    if dup.any():
        r = int(max(order[np.flatnonzero(dup)[0]], order[np.flatnonzero(dup)[0] + 1]))
        raise DataError(path, f"duplicate row: vehicle {vehicle[r]} at Global_Time {gt[r]}", row=r + 2,
                        field="Global_Time")
    vals, vehicle, gt = vals[order], vehicle[order], gt[order]
    new_track = np.concatenate([[True], (vehicle[1:] != vehicle[:-1]) | (np.diff(gt) != DT_MS)])
    track = np.cumsum(new_track) - 1
    return PartialTracks(source=path.name, track=track.astype(np.int64), vehicle=vehicle,
                         t=(gt - gt.min()).astype(np.float64) / 1000.0, s=vals[:, 4], lateral_from_left=vals[:, 3],
                         speed=vals[:, 5])
