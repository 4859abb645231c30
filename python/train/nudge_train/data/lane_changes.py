"""Lane changes of one real trajectory: where the lane line is crossed, where the lateral motion
starts and ends, and the kinematics in between.

The rule (:func:`extract_lane_changes`, parameters :class:`LaneChangeRule`):

1. Smooth: the longitudinal position s and the lateral position d (m, positive to the left) are
   smoothed with the symmetric exponential moving average of Thiemann, Treiber & Kesting (2008)
   and differentiated (:func:`nudge_train.data.smoothing.smooth_derivatives`, widths
   :class:`~nudge_train.data.smoothing.SmoothingWidths`): speeds, accelerations and jerks along
   and across the road.
2. Lanes: every sample's lane is counted from the left from the SMOOTHED lateral position and
   the mainline lane lines at its s (``lines`` [N, M]: column m is the line on the right of
   mainline lane m, 0 = the leftmost lane); lane M means right of the mainline (an auxiliary lane,
   a ramp, the shoulder).
3. Candidates: every sample where the lane differs from the previous sample's.
4. Accepted when: both lanes are mainline lanes (< M) and adjacent; the vehicle was in the old
   lane for ``dwell_before_s`` before the change and stays in the new lane for ``dwell_after_s``
   after it (no return, no other change); neither window, nor the searches below, runs off the
   trajectory (else the event is truncated and rejected).
5. Crossing time: the linear interpolation between the two samples where the smoothed lateral
   position passes the line; the lateral speed there must reach ``v_still`` (else a drift over
   the line: ``no_lateral_motion``).
6. Start / end of the lateral motion: the last sample before the crossing, and the first after
   it, at which the smoothed lateral speed |v_d| is below ``v_still`` m/s, searched at most
   ``max_search_s`` seconds from the crossing (else rejected: ``no_start`` / ``no_end``); the
   lateral motion must not contain another lane change.
7. Quantities over [start, end] (both included): duration, peak |lateral acceleration|, peak
   |lateral jerk|, peak |longitudinal jerk|, peak |yaw rate| (heading = atan2(v_d, v_s) of the
   smoothed velocity relative to the road; undefined, NaN, when the speed falls below
   ``min_speed_heading`` in the window), and at the crossing: lateral speed and speed.

Every rejection is counted under its reason (:data:`REJECT_REASONS`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .smoothing import SmoothingWidths, smooth_derivatives, tte_smooth

__all__ = ["REJECT_REASONS", "LaneChange", "LaneChangeRule", "Extraction", "extract_lane_changes", "lane_of"]

REJECT_REASONS = ("not_adjacent", "not_mainline", "truncated", "not_persistent_before", "returned",
                  "another_change_after", "no_lateral_motion", "no_start", "no_end", "overlaps_another_change")
"""Why a candidate lane change is rejected: lanes not adjacent (a jump over a lane in 0.1 s), a
lane outside the mainline, a window or search running off the trajectory, another lane in the
``dwell_before_s`` before the change, a return to the old lane within ``dwell_after_s``, another
change within ``dwell_after_s``, a crossing slower than ``v_still`` (a drift over the line, no
lateral motion to delimit), no still sample within ``max_search_s`` before / after the
crossing, another lane change inside the lateral motion."""


@dataclass(frozen=True)
class LaneChangeRule:
    """Parameters of the extraction rule (module docstring); units s, m/s."""

    dwell_before_s: float = 2.0
    """The vehicle was in the old lane at least this long before the change."""
    dwell_after_s: float = 2.0
    """The vehicle stays in the new lane at least this long after the change."""
    v_still: float = 0.2
    """|lateral speed| (m/s) below which the lateral motion has not started / has ended."""
    max_search_s: float = 8.0
    """The start and the end of the lateral motion are searched at most this far from the crossing."""
    min_speed_heading: float = 1.0
    """Below this speed (m/s) the heading of the velocity is undefined: no yaw rate."""
    widths: SmoothingWidths = field(default_factory=SmoothingWidths)

    def validate(self) -> LaneChangeRule:
        """Self, or ValueError naming the parameter that is not positive and finite."""
        for name in ("dwell_before_s", "dwell_after_s", "v_still", "max_search_s", "min_speed_heading"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"LaneChangeRule.{name} must be positive and finite, got {v}")
        self.widths.validate()
        return self


@dataclass(frozen=True)
class LaneChange:
    """One accepted lane change. Times in s on the trajectory's clock, indices into its samples.

    ``from_lane`` / ``to_lane``: mainline lanes counted from the left (0 = leftmost);
    ``direction`` +1 to the left, -1 to the right; ``v_lat_cross`` the signed lateral speed at the
    crossing (m/s, positive left); ``speed_cross`` the speed at the crossing (m/s);
    ``duration`` = t_end - t_start (s); ``peak_*``: maxima of the magnitudes over
    [start, end]: lateral acceleration (m/s²), lateral and longitudinal jerk (m/s³), yaw rate
    (rad/s, NaN when undefined)."""

    i_start: int
    i_cross: int
    i_end: int
    t_start: float
    t_cross: float
    t_end: float
    s_cross: float
    from_lane: int
    to_lane: int
    direction: int
    v_lat_cross: float
    speed_cross: float
    duration: float
    peak_lat_accel: float
    peak_lat_jerk: float
    peak_long_jerk: float
    peak_yaw_rate: float


@dataclass
class Extraction:
    """The lane changes of one trajectory and the rejected candidates per reason."""

    events: list[LaneChange]
    rejected: dict[str, int]


def lane_of(d: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Lane counted from the left (0 = leftmost mainline lane; M = right of the mainline) of
    lateral positions ``d`` [N] (m, positive left) given the mainline lines ``lines`` [N, M] (m,
    column m on the right of lane m, descending along a row)."""
    return np.sum(np.asarray(d)[:, None] < np.asarray(lines), axis=1).astype(np.int64)


def extract_lane_changes(t: np.ndarray, s: np.ndarray, d: np.ndarray, lines: np.ndarray,
                         rule: LaneChangeRule = LaneChangeRule()) -> Extraction:
    """The lane changes of one trajectory by the rule of the module docstring.

    Args:
        t: [N] sample times (s), evenly spaced.
        s: [N] longitudinal positions along the road (m).
        d: [N] lateral positions (m, positive to the left).
        lines: [N, M] the mainline lane lines at each sample (m, positive left); column m is the
            line on the right of mainline lane m (0 = the leftmost lane), so columns descend.
        rule: the parameters.

    Raises:
        ValueError: shapes that disagree, fewer than 3 samples, non-finite values, or times not
        evenly spaced (a gap must split the trajectory before this call).
    """
    rule.validate()
    t = np.asarray(t, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    lines = np.asarray(lines, dtype=np.float64)
    n = t.shape[0]
    if s.shape != (n,) or d.shape != (n,) or lines.ndim != 2 or lines.shape[0] != n:
        raise ValueError(f"extract_lane_changes: shapes t {t.shape}, s {s.shape}, d {d.shape}, lines {lines.shape} "
                         "disagree (expected [N], [N], [N], [N, M])")
    if n < 3:
        raise ValueError(f"extract_lane_changes: {n} samples (at least 3)")
    for name, a in (("t", t), ("s", s), ("d", d), ("lines", lines)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"extract_lane_changes: non-finite value in {name}")
    dt = float(t[1] - t[0])
    if not (dt > 0 and np.allclose(np.diff(t), dt, rtol=0, atol=1e-6)):
        raise ValueError("extract_lane_changes: times are not evenly spaced (split the trajectory at its gaps)")
    w = rule.widths
    ks = smooth_derivatives(s, dt, w)
    kd = smooth_derivatives(d, dt, w)
    d_s, vs, vd = kd[0], ks[1], kd[1]
    speed = np.hypot(vs, vd)
    heading = np.unwrap(np.arctan2(vd, vs))
    yaw = tte_smooth(np.gradient(heading, dt), dt, w.accel)
    lane = lane_of(d_s, lines)
    m_lanes = lines.shape[1]
    changes = np.flatnonzero(lane[1:] != lane[:-1]) + 1
    n_before = int(round(rule.dwell_before_s / dt))
    n_after = int(round(rule.dwell_after_s / dt))
    n_search = int(round(rule.max_search_s / dt))
    still = np.abs(vd) < rule.v_still
    rejected = {r: 0 for r in REJECT_REASONS}
    events: list[LaneChange] = []
    for i in changes:
        old, new = int(lane[i - 1]), int(lane[i])
        if abs(new - old) != 1:
            rejected["not_adjacent"] += 1
            continue
        if old >= m_lanes or new >= m_lanes:
            rejected["not_mainline"] += 1
            continue
        if i - n_before < 0 or i + n_after > n:
            rejected["truncated"] += 1
            continue
        if np.any(lane[i - n_before:i] != old):
            rejected["not_persistent_before"] += 1
            continue
        after = lane[i:i + n_after]
        if np.any(after != new):
            rejected["returned" if np.any(after == old) else "another_change_after"] += 1
            continue
        # the line between the two lanes, crossed between samples i-1 and i
        col = min(old, new)
        y0, y1 = d_s[i - 1] - lines[i - 1, col], d_s[i] - lines[i, col]
        frac = float(np.clip(y0 / (y0 - y1), 0.0, 1.0)) if y0 != y1 else 0.5
        t_cross = float(t[i - 1] + frac * dt)
        v_lat_cross = float(vd[i - 1] + frac * (vd[i] - vd[i - 1]))
        if abs(v_lat_cross) < rule.v_still:
            rejected["no_lateral_motion"] += 1
            continue
        # start: the last still sample of the n_search before the crossing; end: the first of
        # the n_search after it
        lo = i - n_search
        before = np.flatnonzero(still[max(lo, 0):i])
        if before.size == 0:
            rejected["truncated" if lo < 0 else "no_start"] += 1
            continue
        i_start = int(max(lo, 0) + before[-1])
        hi = i + n_search
        after_still = np.flatnonzero(still[i:min(hi, n)])
        if after_still.size == 0:
            rejected["truncated" if hi > n else "no_end"] += 1
            continue
        i_end = int(i + after_still[0])
        if np.any((changes >= i_start) & (changes <= i_end) & (changes != i)):
            rejected["overlaps_another_change"] += 1
            continue
        win = slice(i_start, i_end + 1)
        yaw_ok = bool(np.all(speed[win] >= rule.min_speed_heading))
        events.append(LaneChange(
            i_start=i_start, i_cross=int(i), i_end=i_end, t_start=float(t[i_start]), t_cross=t_cross,
            t_end=float(t[i_end]), s_cross=float(ks[0, i - 1] + frac * (ks[0, i] - ks[0, i - 1])),
            from_lane=old, to_lane=new, direction=1 if new < old else -1,
            v_lat_cross=v_lat_cross,
            speed_cross=float(speed[i - 1] + frac * (speed[i] - speed[i - 1])),
            duration=float(t[i_end] - t[i_start]),
            peak_lat_accel=float(np.max(np.abs(kd[2, win]))), peak_lat_jerk=float(np.max(np.abs(kd[3, win]))),
            peak_long_jerk=float(np.max(np.abs(ks[3, win]))),
            peak_yaw_rate=float(np.max(np.abs(yaw[win]))) if yaw_ok else float("nan")))
    return Extraction(events=events, rejected=rejected)
