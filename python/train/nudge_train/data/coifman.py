"""Reader for the Coifman & Li (2017) I-80 re-extraction (longitudinal only).

The file uses the official 18-column layout in feet, but only Vehicle_ID, Frame_ID, Local_Y,
v_Vel, v_Acc, Lane_ID, Preceding, Following are filled. What this reader derives, and flags:

* x = Local_Y (ft -> m) minus half an ASSUMED length (front-centre -> centre); length 4.5 m and
  width 1.8 m are assumed for every vehicle (FLAG_SIZE_ASSUMED);
* y from the lane: I-80 lanes are 12 ft wide, lane 1 is the leftmost (HOV) lane, so the centre of
  lane k is y = -(k - 0.5) * 12 ft; the file's lane 9 (vehicles right of lane 6, on-ramp) is
  treated as lane 7 (FLAG_LATERAL_SYNTHETIC on every track);
* a lane change (Lane_ID jump k -> k') becomes a smooth lateral move (cubic smoothstep) of
  duration ``lc_duration_s`` (default 4 s, a typical highway lane-change duration) centred on
  the first frame of the new lane, shortened to half the gap when two changes are closer than
  that; tracks with at least one change carry FLAG_LC_INTERPOLATED;
* heading = atan2(dy/dt, speed), speed = v_Vel (ft/s -> m/s).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DataError
from .raw import FT, RAW_RULES, FieldRule, _columns, read_rows, smooth_flicker
from .tracks import FLAG_LATERAL_SYNTHETIC, FLAG_SIZE_ASSUMED, LaneMap, TrackTable

FLAG_LC_INTERPOLATED = 4
"""Track has a lane change whose lateral motion was interpolated (Coifman & Li I-80)."""

LANE_W = 12 * FT

COIFMAN_RULES: dict[str, FieldRule] = {
    **RAW_RULES,
    "v_length": FieldRule(0, 1000, "ft"),  # not filled in this file (0): sizes are assumed
    "v_width": FieldRule(0, 1000, "ft"),
}
"""Accepted values per column (as the raw reader, except the unused, zero, vehicle sizes)."""


@dataclass(frozen=True)
class CoifmanConfig:
    """Derivation parameters (s, m)."""

    lc_duration_s: float = 4.0
    length_m: float = 4.5
    width_m: float = 1.8
    dt: float = 0.1
    flicker_s: float = 1.0


def lateral_path(t: np.ndarray, lane: np.ndarray, duration: float) -> np.ndarray:
    """Lateral position y [T] (m) for one track with times t [T] (s) and lane numbers lane [T]
    (1 = leftmost); lane changes are smoothsteps of ``duration`` s centred on the change."""
    centre = -(lane.astype(np.float64) - 0.5) * LANE_W
    y = np.full(t.shape[0], centre[0])
    ch = np.flatnonzero(lane[1:] != lane[:-1]) + 1
    tc = t[ch]
    for k, i in enumerate(ch):
        gap_prev = tc[k] - tc[k - 1] if k > 0 else np.inf
        gap_next = tc[k + 1] - tc[k] if k + 1 < len(ch) else np.inf
        half = min(duration / 2, gap_prev / 2, gap_next / 2)
        delta = centre[i] - centre[i - 1]
        u = np.clip((t - (tc[k] - half)) / (2 * half), 0.0, 1.0)
        y += delta * (3 * u**2 - 2 * u**3)
    return y


def read_coifman(path: Path | str, cfg: CoifmanConfig = CoifmanConfig()) -> TrackTable:
    """Read the Coifman & Li I-80 CSV into one TrackTable (scene "i80-coifman-li-2017").

    Raises DataError (file, row) for empty files, missing columns, NaN values, duplicate
    (Vehicle_ID, Frame_ID) keys or non-monotonic frames within a vehicle, unknown lane ids.
    """
    path = Path(path)
    header, data, first_line, _ = read_rows(path)
    cols, _ = _columns(path, header, data, first_line, COIFMAN_RULES)
    veh = cols["vehicle_id"].astype(np.int64)
    frame = cols["frame_id"].astype(np.int64)
    # File order must be time order within each vehicle.
    same = veh[1:] == veh[:-1]
    bad = same & (frame[1:] <= frame[:-1])
    if bad.any():
        r = int(np.flatnonzero(bad)[0]) + 1
        what = "duplicate frame" if frame[r] == frame[r - 1] else "non-monotonic time"
        raise DataError(path, f"{what}: vehicle {veh[r]} frame {frame[r]} after frame {frame[r - 1]}",
                        row=first_line + r)
    lane_raw = cols["lane_id"].astype(np.int64)
    ok = ((lane_raw >= 1) & (lane_raw <= 7)) | (lane_raw == 9)
    if not ok.all():
        r = int(np.flatnonzero(~ok)[0])
        raise DataError(path, f"unknown Lane_ID {lane_raw[r]} (expected 1-7 or 9)", row=first_line + r)
    lane_num = np.where(lane_raw == 9, 7, lane_raw)
    order = np.lexsort((frame, veh))
    # A vehicle whose rows are split in the file may repeat a frame across the split.
    dup = (veh[order][1:] == veh[order][:-1]) & (frame[order][1:] == frame[order][:-1])
    if dup.any():
        k = int(np.flatnonzero(dup)[0])
        r = int(max(order[k], order[k + 1]))
        raise DataError(path, f"duplicate frame: vehicle {veh[r]} frame {frame[r]} appears twice", row=first_line + r)
    veh, frame, lane_num = veh[order], frame[order], lane_num[order]
    local_y = cols["local_y"][order] * FT
    speed = cols["v_vel"][order] * FT
    t = frame.astype(np.float64) * cfg.dt
    starts = np.flatnonzero(np.concatenate([[True], veh[1:] != veh[:-1]]))
    ends = np.concatenate([starts[1:], [veh.shape[0]]])
    y = np.empty_like(t)
    flags = np.full(veh.shape[0], FLAG_LATERAL_SYNTHETIC | FLAG_SIZE_ASSUMED, dtype=np.int64)
    lane_s = lane_num.copy()
    flicker = 0
    n_lc = 0
    n_gap_tracks = 0
    max_run = int(round(cfg.flicker_s / cfg.dt))
    for s, e in zip(starts, ends):
        lane_s[s:e], c = smooth_flicker(lane_num[s:e], max_run)
        flicker += c
        if np.any(np.diff(frame[s:e]) != 1):
            n_gap_tracks += 1
        y[s:e] = lateral_path(t[s:e], lane_s[s:e], cfg.lc_duration_s)
        k = int(np.sum(lane_s[s + 1:e] != lane_s[s:e - 1]))
        if k:
            flags[s:e] |= FLAG_LC_INTERPOLATED
            n_lc += k
    x = local_y - 0.5 * cfg.length_m
    # dy/dt by centred differences within tracks.
    dy = np.zeros_like(y)
    for s, e in zip(starts, ends):
        if e - s >= 2:
            dy[s:e] = np.gradient(y[s:e], t[s:e])
    heading = np.arctan2(dy, np.maximum(speed, 0.1))
    bounds = -np.arange(7, -1, -1, dtype=np.float64) * LANE_W  # 7 lanes, rightmost first
    notes = {"rows_read": len(data), "lane_changes": n_lc, "lane_flicker_rows_smoothed": flicker,
             "tracks_with_frame_gaps": n_gap_tracks, "lane9_rows_as_lane7": int(np.sum(lane_raw == 9))}
    return TrackTable(
        scene="i80-coifman-li-2017", source=path.name, vehicle=veh, t=t, x=x, y=y, heading=heading,
        speed=speed, length=np.full(veh.shape[0], cfg.length_m), width=np.full(veh.shape[0], cfg.width_m),
        lane=(lane_s - 1).astype(np.int64), flags=flags,
        lanes=LaneMap(bounds=bounds, x_range=(float(x.min()), float(x.max()))), dt=cfg.dt, notes=notes)
