"""Reader for the official raw NGSIM trajectory layouts (feet, front-centre positions).

Layouts (detected from the header, or from the column count when there is no header as in the
official whitespace-separated ``trajectories-*.txt`` files):

* 18 columns (I-80, US-101 period files): Vehicle_ID, Frame_ID, Total_Frames, Global_Time,
  Local_X, Local_Y, Global_X, Global_Y, v_Length, v_Width, v_Class, v_Vel, v_Acc, Lane_ID,
  Preceding, Following, Space_Headway, Time_Headway;
* 25 columns (data.transportation.gov combined export): adds O_Zone, D_Zone, Int_ID, Section_ID,
  Direction, Movement and ``Location``.

Cleaning, every step counted in ``TrackTable.notes``:

* feet -> metres (positions, sizes), ft/s -> m/s;
* front-centre -> centre: Local_Y minus half the length along the direction of travel;
* road frame: x = longitudinal position along travel, y = -Local_X (Local_X is measured from the
  left edge, so y is positive left); for traffic moving towards -Local_Y (arterials) the frame is
  turned by 180 degrees;
* periods: raw vehicle ids repeat across periods; rows are grouped by the recording period
  identified by Global_Time - 100 ms * Frame_ID (so a repeated (Vehicle_ID, Frame_ID) key from
  another period is a different vehicle, not a duplicate); within a period, duplicate
  (Vehicle_ID, Frame_ID) keys are dropped (first row kept) and counted;
* Global_Time with 10 digits (the combined export truncates the epoch-ms value) is accepted and
  counted: time is taken from Frame_ID (0.1 s), Global_Time only identifies the period;
* rows are sorted by (vehicle, frame);
* Lane_ID flicker: a run of another lane shorter than ``flicker_s`` between two runs of the same
  lane is replaced by that lane (rows changed counted).
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DataError, read_source
from .tracks import LaneMap, TrackTable

FT = 0.3048
"""Metres per foot."""

LAYOUT_18 = ("Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "Local_X", "Local_Y",
             "Global_X", "Global_Y", "v_Length", "v_Width", "v_Class", "v_Vel", "v_Acc", "Lane_ID",
             "Preceding", "Following", "Space_Headway", "Time_Headway")
LAYOUT_25 = ("Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "Local_X", "Local_Y",
             "Global_X", "Global_Y", "v_length", "v_Width", "v_Class", "v_Vel", "v_Acc", "Lane_ID",
             "O_Zone", "D_Zone", "Int_ID", "Section_ID", "Direction", "Movement", "Preceding",
             "Following", "Space_Headway", "Time_Headway", "Location")
REQUIRED = ("vehicle_id", "frame_id", "global_time", "local_x", "local_y", "v_length", "v_width",
            "v_vel", "lane_id")


@dataclass(frozen=True)
class RawConfig:
    """Cleaning parameters: Lane_ID flicker run length (s), frame period (s), period jump (ms)."""

    flicker_s: float = 1.0
    dt: float = 0.1
    period_jump_ms: int = 1000


def _read_text(path: Path) -> str:
    data = read_source(path)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise DataError(path, f"not UTF-8 text (byte {exc.start})", row=line) from None


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def read_rows(path: Path) -> tuple[list[str], list[list[str]], int, str]:
    """Header (column names), data rows, file line number of the first data row, layout name."""
    text = _read_text(path)
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines or not lines[0].strip():
        raise DataError(path, "empty file")
    first = lines[0]
    delim_comma = "," in first
    if "\x00" in text:
        line = text.count("\n", 0, text.index("\x00")) + 1
        raise DataError(path, "NUL byte in a text file (binary or corrupted data)", row=line)
    if delim_comma:
        try:
            rows = list(csv.reader(io.StringIO("\n".join(lines))))
        except csv.Error as exc:
            raise DataError(path, f"not a CSV table: {exc}") from None
    else:
        rows = [ln.split() for ln in lines]
    if not rows or not rows[0]:
        raise DataError(path, "empty first row", row=1)
    if _is_number(rows[0][0].strip()):
        header_row = None
        n = len(rows[0])
        if n == 18:
            header = list(LAYOUT_18)
        elif n == 25:
            header = list(LAYOUT_25)
        else:
            raise DataError(path, f"unknown layout: {n} columns and no header (expected 18 or 25)", row=1)
        data, first_line = rows, 1
    else:
        header_row = rows[0]
        header = [h.strip() for h in header_row]
        data, first_line = rows[1:], 2
    if not data:
        raise DataError(path, "no data rows (header only)")
    low = [h.lower() for h in header]
    missing = [c for c in REQUIRED if c not in low]
    if missing:
        raise DataError(path, f"missing columns {missing} (found {header}); not an NGSIM raw layout", row=1)
    layout = "25-column combined export" if "location" in low else (
        "18-column" if len(header) == 18 else f"{len(header)}-column (NGSIM names)")
    return header, data, first_line, layout


@dataclass(frozen=True)
class FieldRule:
    """Accepted values of one column, in the file's unit: ``lo`` .. ``hi`` (``lo`` excluded when
    ``lo_open``); ``integer`` columns must hold non-negative whole numbers."""

    lo: float
    hi: float
    unit: str = ""
    integer: bool = False
    lo_open: bool = False

    def problem(self, label: str, tok: str, v: float) -> str | None:
        """Why ``v`` (written ``tok``) of the field ``label`` is refused, or None when accepted."""
        if self.integer and (v < 0 or v != math.floor(v)):
            return f"{label} = {tok} is not a non-negative integer"
        below = v <= self.lo if self.lo_open else v < self.lo
        if below or v > self.hi:
            interval = ("(" if self.lo_open else "[") + f"{self.lo:g}, {self.hi:g}]"
            return f"{label} = {v:g} outside {interval}" + (f" {self.unit}" if self.unit else "")
        return None


RAW_RULES: dict[str, FieldRule] = {
    "vehicle_id": FieldRule(0, 1e9, integer=True),
    "frame_id": FieldRule(0, 1e9, integer=True),
    "global_time": FieldRule(0, 1e14, "ms", integer=True),
    "local_x": FieldRule(-1e5, 1e5, "ft"),
    "local_y": FieldRule(-1e5, 1e5, "ft"),
    "v_length": FieldRule(0, 1000, "ft", lo_open=True),
    "v_width": FieldRule(0, 1000, "ft", lo_open=True),
    "v_vel": FieldRule(-1000, 1000, "ft/s"),
    "v_acc": FieldRule(-1000, 1000, "ft/s^2"),
    "lane_id": FieldRule(0, 1e4, integer=True),
    "direction": FieldRule(0, 1e4, integer=True),
}
"""What the raw reader accepts per column (docs/data_schema.md, section 3). A value outside is a
DataError naming file, row and column: such a value is a corrupted or foreign file, not noise."""

_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")


def number(tok: str) -> float | None:
    """A plain decimal number (or a NaN/inf spelling, returned as such); None for anything else
    (words, hex, digit separators, empty)."""
    if _NUMBER.fullmatch(tok):
        return float(tok)
    try:
        v = float(tok)
    except ValueError:
        return None
    return None if math.isfinite(v) else v


def _columns(path: Path, header: list[str], data: list[list[str]], first_line: int,
             rules: dict[str, FieldRule] = RAW_RULES) -> tuple[dict[str, np.ndarray], list[str]]:
    low = [h.lower() for h in header]
    idx = {c: low.index(c) for c in REQUIRED}
    extra = {c: low.index(c) for c in ("direction", "v_acc") if c in low}
    loc_i = low.index("location") if "location" in low else None
    cols = {c: np.empty(len(data), dtype=np.float64) for c in list(idx) + list(extra)}
    locs: list[str] = []
    ncol = len(header)
    for r, row in enumerate(data):
        if len(row) != ncol:
            raise DataError(path, f"{len(row)} fields, expected {ncol}", row=first_line + r)
        for c, i in list(idx.items()) + list(extra.items()):
            tok = row[i].strip()
            v = number(tok)
            if v is None:
                raise DataError(path, f"column {header[i]} is not a number: {tok!r}", row=first_line + r,
                                field=header[i])
            if not math.isfinite(v):
                raise DataError(path, f"column {header[i]} is {tok!r} (NaN/inf)", row=first_line + r, field=header[i])
            why = rules[c].problem(f"column {header[i]}", tok, v)
            if why is not None:
                raise DataError(path, why, row=first_line + r, field=header[i])
            cols[c][r] = v
        locs.append(row[loc_i].strip() if loc_i is not None else "")
    return cols, locs


def smooth_flicker(lane: np.ndarray, max_run: int) -> tuple[np.ndarray, int]:
    """Replace runs shorter than ``max_run`` samples that sit between two runs of the same value.

    lane [T] (one track, time order). Returns the smoothed copy and the number of changed samples.
    """
    out = lane.copy()
    if out.shape[0] < 3:
        return out, 0
    while True:
        starts = np.flatnonzero(np.concatenate([[True], out[1:] != out[:-1]]))
        ends = np.concatenate([starts[1:], [out.shape[0]]])
        done = True
        for k in range(1, len(starts) - 1):
            if ends[k] - starts[k] < max_run and out[starts[k - 1]] == out[starts[k + 1]]:
                out[starts[k]:ends[k]] = out[starts[k - 1]]
                done = False
                break
        if done:
            return out, int(np.sum(out != lane))


def heading_from_path(x: np.ndarray, y: np.ndarray, veh: np.ndarray, half: int = 5) -> np.ndarray:
    """Heading (rad) from centred differences over +-half samples within each track (rows sorted
    by vehicle, time); 0 where the vehicle moves less than 5 cm over the span."""
    h = np.zeros(x.shape[0])
    starts = np.flatnonzero(np.concatenate([[True], veh[1:] != veh[:-1]]))
    ends = np.concatenate([starts[1:], [x.shape[0]]])
    for s, e in zip(starts, ends):
        n = e - s
        i = np.arange(n)
        lo = np.clip(i - half, 0, n - 1) + s
        hi = np.clip(i + half, 0, n - 1) + s
        dx, dy = x[hi] - x[lo], y[hi] - y[lo]
        ok = np.hypot(dx, dy) > 0.05
        h[s:e] = np.where(ok, np.arctan2(dy, dx), 0.0)
    return h


def read_raw_ngsim(path: Path | str, cfg: RawConfig = RawConfig()) -> list[TrackTable]:
    """Read an official raw NGSIM file; one TrackTable per (location, period, direction of travel).

    Raises DataError naming the file (and row) for an empty file, unknown layout, missing columns,
    non-numeric or NaN values, a Global_Time inconsistent with Frame_ID inside a track
    (non-monotonic time), or a file where no vehicle has two states.
    """
    path = Path(path)
    header, data, first_line, layout = read_rows(path)
    cols, locs = _columns(path, header, data, first_line)
    n = len(data)
    veh = cols["vehicle_id"].astype(np.int64)
    frame = cols["frame_id"].astype(np.int64)
    gtime = cols["global_time"].astype(np.int64)
    ten_digit = int(np.sum((gtime > 0) & (gtime < 10**12)))
    offset = np.where(gtime > 0, gtime - 100 * frame, 0)
    loc_names = sorted(set(locs))
    loc_id = np.asarray([loc_names.index(v) for v in locs], dtype=np.int64)
    direction = cols["direction"].astype(np.int64) if "direction" in cols else np.zeros(n, dtype=np.int64)

    # Period labels: offsets of one location clustered by gaps > period_jump_ms.
    period = np.zeros(n, dtype=np.int64)
    for li in range(len(loc_names)):
        m = np.flatnonzero(loc_id == li)
        uniq = np.unique(offset[m])
        labels = np.concatenate([[0], np.cumsum(np.diff(uniq) > cfg.period_jump_ms)])
        period[m] = labels[np.searchsorted(uniq, offset[m])]
    key_order = np.lexsort((frame, veh, period, loc_id))
    same = (loc_id[key_order[1:]] == loc_id[key_order[:-1]]) & (period[key_order[1:]] == period[key_order[:-1]]) & (
        veh[key_order[1:]] == veh[key_order[:-1]])
    bad_off = same & (offset[key_order[1:]] != offset[key_order[:-1]])
    if bad_off.any():
        r = int(key_order[1:][np.flatnonzero(bad_off)[0]])
        raise DataError(path, f"non-monotonic time: Global_Time {gtime[r]} does not match Frame_ID {frame[r]} "
                        f"of vehicle {veh[r]} (offset differs from the rest of its track)", row=first_line + r)
    # Duplicate keys.
    dup_any = int(n - np.unique(np.stack([veh, frame], axis=1), axis=0).shape[0])
    sorted_keys = np.stack([loc_id, period, veh, frame], axis=1)[key_order]
    is_dup = np.concatenate([[False], np.all(sorted_keys[1:] == sorted_keys[:-1], axis=1)])
    # Keep the first row in file order: lexsort is stable, so file order breaks ties.
    keep_rows = key_order[~is_dup]
    dropped_dups = int(is_dup.sum())

    tables: list[TrackTable] = []
    groups = sorted(set(zip(loc_id[keep_rows].tolist(), period[keep_rows].tolist(), direction[keep_rows].tolist())))
    for li, pi, di in groups:
        rows = keep_rows[(loc_id[keep_rows] == li) & (period[keep_rows] == pi) & (direction[keep_rows] == di)]
        v = veh[rows]
        f = frame[rows]
        length = cols["v_length"][rows] * FT
        width = cols["v_width"][rows] * FT
        ly = cols["local_y"][rows] * FT
        lx = cols["local_x"][rows] * FT
        # Direction of travel: sign of the median per-vehicle displacement.
        starts = np.flatnonzero(np.concatenate([[True], v[1:] != v[:-1]]))
        ends = np.concatenate([starts[1:], [v.shape[0]]])
        disp = ly[ends - 1] - ly[starts]
        moving = disp[np.abs(disp) > 1.0]
        sign = -1.0 if moving.size and np.median(moving) < 0 else 1.0
        x = sign * (ly - sign * 0.5 * length)
        y = -sign * lx
        lane_raw = cols["lane_id"][rows].astype(np.int64)
        lane_s = lane_raw.copy()
        flicker = 0
        max_run = int(round(cfg.flicker_s / cfg.dt))
        for s, e in zip(starts, ends):
            lane_s[s:e], c = smooth_flicker(lane_raw[s:e], max_run)
            flicker += c
        # Lane map from the data: median lateral position of each Lane_ID.
        lane_ids = np.unique(lane_s)
        centres = np.asarray([np.median(y[lane_s == k]) for k in lane_ids])
        order = np.argsort(centres)
        c_sorted = centres[order]
        if c_sorted.shape[0] >= 2:
            mids = 0.5 * (c_sorted[1:] + c_sorted[:-1])
            w0 = c_sorted[1] - c_sorted[0]
            w1 = c_sorted[-1] - c_sorted[-2]
            bounds = np.concatenate([[c_sorted[0] - 0.5 * w0], mids, [c_sorted[-1] + 0.5 * w1]])
        else:
            bounds = np.asarray([c_sorted[0] - 12 * FT / 2, c_sorted[0] + 12 * FT / 2])
        # Lane index from the left: rank of the Lane_ID's centre counted from the largest y.
        rank_from_left = {int(lane_ids[order][k]): c_sorted.shape[0] - 1 - k for k in range(c_sorted.shape[0])}
        lane = np.asarray([rank_from_left[int(k)] for k in lane_s], dtype=np.int64)
        speed = cols["v_vel"][rows] * FT
        heading = heading_from_path(x, y, v)
        name = loc_names[li] or path.name.split(".")[0]
        scene = f"{name}-p{pi}" + (f"-dir{di}" if "direction" in cols else "")
        notes = {
            "rows_read": n, "rows_in_scene": int(rows.shape[0]),
            "duplicate_keys_in_file": dup_any, "duplicate_rows_dropped": dropped_dups,
            "global_time_10_digit_rows": ten_digit, "lane_flicker_rows_smoothed": flicker,
            "periods_in_file": int(period.max() + 1), "travel_sign": int(sign),
        }
        tables.append(TrackTable(
            scene=scene, source=path.name, vehicle=v, t=f.astype(np.float64) * cfg.dt, x=x, y=y,
            heading=heading, speed=speed, length=length, width=width, lane=lane,
            flags=np.zeros(v.shape[0], dtype=np.int64),
            lanes=LaneMap(bounds=bounds, x_range=(float(x.min()), float(x.max()))), dt=cfg.dt, notes=notes))
    if not any(len(np.unique(t.vehicle)) < len(t) for t in tables):
        raise DataError(path, "no vehicle has more than one state")
    return tables
