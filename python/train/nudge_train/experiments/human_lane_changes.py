"""A human reference for lane changes: every lane change in the real US-101 tracks, by the rule of
:mod:`nudge_train.data.lane_changes`, and the distributions of its duration and kinematics per
speed band and split.

Sources (both real NGSIM US-101, 10 Hz, metres):

* the CommonRoad scenes (``us101/commonroad_us101_*``): read, one variant per scene, and split by
  overlap group exactly as the data build does (:func:`nudge_train.data.sources.us101_sources`);
  lateral position = offset from the curvilinear frame's reference path, lane lines from the
  lanelet map. The same vehicle can appear in several scenes of one overlap group: a lane change
  seen twice (the same 21 logged speeds around the crossing, at most 1.5 s apart) is kept once.
* the partial vehicle set (``us101/chenshimao_us101_partial_per_vehicle_metric.csv.gz``, 370
  whole trajectories over the 45 minutes): no lane ids, so the lane lines are the midpoints
  between lane centres measured from the training and validation tracks (the density peaks of
  the lateral position, per 80 m of road, interpolated along the road). Split by the data build's
  rule for long recordings: time blocks of ``SplitConfig.i80_block_s`` (60 s) assigned by
  :func:`~nudge_train.data.splits.assign_or_test` (weights: rows), a track taking the block it
  starts in, so that no vehicle is on two sides.

The sources share vehicles (CommonRoad obstacle ids are NGSIM Vehicle_IDs; :func:`match_scenes`):
a partial-set track whose vehicle is in a CommonRoad scene takes that scene's split (test first),
and a lane change found in both is counted once.

Mainline: NGSIM lanes 1–5 (the five leftmost lanes); lane changes to or from the auxiliary lane 6
or a ramp are not counted.

Command: ``nudge-train human-lane-changes`` (writes the report, a JSON summary, the events as CSV
and a figure).
"""

from __future__ import annotations

import csv
import io
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nudge_train.artefacts import atomic_write_bytes, atomic_write_text
from nudge_train.data.chenshimao import PartialTracks, read_chenshimao
from nudge_train.data.errors import DataError
from nudge_train.data.lane_changes import REJECT_REASONS, LaneChange, LaneChangeRule, extract_lane_changes, lane_of
from nudge_train.data.smoothing import smooth_derivatives
from nudge_train.data.sources import SourceEntry, us101_sources
from nudge_train.data.splits import SplitConfig, assign_or_test

__all__ = ["BANDS", "QUANTITIES", "Event", "Study", "run", "study"]

SCHEMA = "nudge.human_lane_changes/1"
"""Schema string of the JSON summary."""

CHENSHIMAO = "us101/chenshimao_us101_partial_per_vehicle_metric.csv.gz"
"""The partial US-101 vehicle set, relative to the NGSIM folder."""

CHENSHIMAO_SALT = 2101
"""Salt of the split draw of the partial set's time blocks (the build uses 101 for the US-101 overlap
groups, 80 for I-80, 1000+k for extra raw files)."""

MAINLINE_LANES = 5
"""NGSIM US-101 lanes 1–5 are the mainline (6: auxiliary lane, 7–8: ramps)."""

LINE_BIN_M = 80.0
"""Length of road (m) over which the partial set's lane centres are measured once."""

BANDS = ((0.0, 5.0), (5.0, 10.0), (10.0, 15.0), (15.0, float("inf")))
"""Speed bands at the crossing (m/s)."""

QUANTITIES = (
    ("duration", "duration", "s"),
    ("peak_lat_accel", "peak lateral acceleration", "m/s²"),
    ("peak_lat_jerk", "peak lateral jerk", "m/s³"),
    ("peak_long_jerk", "peak longitudinal jerk", "m/s³"),
    ("peak_yaw_rate", "peak yaw rate", "rad/s"),
    ("abs_v_lat_cross", "lateral speed at the crossing", "m/s"),
    ("speed_cross", "speed at the crossing", "m/s"),
)
"""(field, name, unit) of every reported quantity (peaks and the lateral speed are magnitudes)."""

SUMMARY_FIELDS = ("duration", "peak_lat_accel", "peak_lat_jerk", "peak_long_jerk", "peak_yaw_rate")
"""The quantities of the JSON summary read by the planner side."""

GROUPS = ("train", "val", "test", "train+val", "all")
"""Split groups of the tables: train+val is what defaults may be taken from, test is held out."""


@dataclass(frozen=True)
class Event:
    """One lane change with where it comes from (``source``: commonroad | partial; ``where``: the
    scene or the file; ``track``: the NGSIM Vehicle_ID; ``partial_track``: the track index in the
    partial set, -1 for a scene) and its split."""

    source: str
    where: str
    track: int
    split: str
    group: str
    lc: LaneChange
    partial_track: int = -1

    def value(self, name: str) -> float:
        if name == "abs_v_lat_cross":
            return abs(self.lc.v_lat_cross)
        return float(getattr(self.lc, name))


@dataclass
class Study:
    """Everything the report shows."""

    events: list[Event]
    rejected: dict[str, dict[str, int]]  # source -> reason -> count
    duplicates: int
    tracks: dict[str, dict[str, int]]  # source -> split -> tracks
    partial_centres: np.ndarray  # [bins, 5] lane centres (m from the left edge) of the partial set
    partial_bin_s: np.ndarray  # [bins] centre of each bin along the road (m)
    lane_keeping: dict[str, list[float]]  # quantity -> p50, p80, p95 over train+val samples far from changes
    synthetic: list[dict[str, float]]  # the smoothing's recovery of noise-free lane changes
    rule: LaneChangeRule
    seed: int
    matches: list[SceneMatch]  # CommonRoad vehicles found in the partial set
    in_both: int  # lane changes of a scene also found in the partial set (counted once)
    block_split: dict[int, str]  # partial track -> split drawn for its time block
    track_split: dict[int, str]  # partial track -> split used


# ---- sources ---------------------------------------------------------------------------------
def _segments(t: np.ndarray, ok: np.ndarray, dt: float) -> list[tuple[int, int]]:
    """[a, b) runs of consecutive samples (time step dt) where ``ok``."""
    brk = np.concatenate([[True], (np.abs(np.diff(t) - dt) > 1e-6) | ~ok[1:] | ~ok[:-1]])
    starts = np.flatnonzero(brk)
    ends = np.concatenate([starts[1:], [t.shape[0]]])
    return [(int(a), int(b)) for a, b in zip(starts, ends) if ok[a] and b - a >= 3]


def _commonroad_events(entries: list[SourceEntry], rule: LaneChangeRule, progress: bool,
                       rejected: dict[str, int], tracks: dict[str, int]) -> tuple[list[Event], int, list]:
    """Lane changes of the CommonRoad scenes, duplicates across scenes of one group removed.
    Also returns lane-keeping samples (train+val) for the noise floor."""
    found: list[tuple[Event, np.ndarray, int]] = []
    keep_samples = []
    for e in tqdm(entries, desc="CommonRoad scenes", disable=not progress):
        tb = e.table
        assert tb is not None
        for v in tb.vehicle_ids():
            rows = np.flatnonzero(tb.vehicle == v)
            t, x, y = tb.t[rows], tb.x[rows], tb.y[rows]
            lines = np.full((rows.shape[0], MAINLINE_LANES), np.nan)
            for k in range(rows.shape[0]):
                b = tb.lanes.bounds_at(float(x[k]))
                n_lanes = b.shape[0] - 1
                if n_lanes >= MAINLINE_LANES:
                    lines[k] = b[n_lanes - 1 - np.arange(MAINLINE_LANES)]
            tracks[e.split] = tracks.get(e.split, 0) + 1
            for a, b_ in _segments(t, np.all(np.isfinite(lines), axis=1), tb.dt):
                ex = extract_lane_changes(t[a:b_], x[a:b_], y[a:b_], lines[a:b_], rule)
                for r, c in ex.rejected.items():
                    rejected[r] += c
                for lc in ex.events:
                    found.append((Event("commonroad", tb.scene, int(v), e.split, e.group, lc),
                                  tb.speed[rows][a:b_], lc.i_cross))
                if e.split in ("train", "val"):
                    keep_samples.append((t[a:b_], x[a:b_], y[a:b_], lines[a:b_], tb.dt))
    kept: list[tuple[Event, np.ndarray, int]] = []
    dups = 0
    for ev, sp, ic in found:
        if any(k.group == ev.group and k.where != ev.where and _same_vehicle(sp, ic, ksp, kic)
               for k, ksp, kic in kept):
            dups += 1
            continue
        kept.append((ev, sp, ic))
    return [k for k, _, _ in kept], dups, keep_samples


def _same_vehicle(sp1: np.ndarray, i1: int, sp2: np.ndarray, i2: int, half: int = 10, shift: int = 15) -> bool:
    """Whether the 2·half+1 logged speeds around sample i1 of one track equal (1e-6 m/s) those
    around a sample within ``shift`` of i2 of another: the same vehicle at the same moment."""
    if i1 - half < 0 or i1 + half + 1 > sp1.shape[0]:
        return False
    a = sp1[i1 - half:i1 + half + 1]
    for k in range(-shift, shift + 1):
        j = i2 + k
        if j - half < 0 or j + half + 1 > sp2.shape[0]:
            continue
        if np.max(np.abs(sp2[j - half:j + half + 1] - a)) < 1e-6:
            return True
    return False


def partial_splits(pt: PartialTracks, cfg: SplitConfig,
                   seen_in: dict[int, set[str]] | None = None) -> tuple[dict[int, str], dict[int, str]]:
    """Split of every track of the partial set and each track's group key: by the 60 s time block
    it starts in (the data build's rule for long recordings), except that a track whose vehicle is
    in CommonRoad scenes (``seen_in``: track -> the splits of those scenes, :func:`match_scenes`)
    takes their split, test first, then val, so that no vehicle of a test scene is in train+val."""
    bounds = pt.bounds()
    block_of = {int(pt.track[a]): f"partial-block-{int(pt.t[a] // cfg.i80_block_s):02d}" for a, _ in bounds}
    weights: dict[str, float] = {}
    for (a, b) in bounds:
        key = block_of[int(pt.track[a])]
        weights[key] = weights.get(key, 0.0) + float(b - a)
    split_of, _ = assign_or_test(weights, cfg, salt=CHENSHIMAO_SALT, what="time block of the partial US-101 set")
    out = {k: split_of[g] for k, g in block_of.items()}
    for k, splits in (seen_in or {}).items():
        out[k] = next(sp for sp in ("test", "val", "train") if sp in splits)
    return out, block_of


MATCH_RMSE = 0.05
"""A CommonRoad vehicle is a track of the partial set when they share the NGSIM Vehicle_ID and,
at some offset, the partial set's speeds are the CommonRoad speeds times a factor within 5 % of 1
(the two conversions differ by about 1.2 %) up to this RMS residual (m/s)."""

MATCH_MIN_SAMPLES = 20
"""A CommonRoad vehicle shorter than this (samples) is not matched."""


@dataclass(frozen=True)
class SceneMatch:
    """A CommonRoad vehicle found in the partial set: ``track`` and ``offset_s`` (the partial
    set's clock minus the scene's)."""

    scene: str
    vehicle: int
    split: str
    group: str
    track: int
    offset_s: float


def match_scenes(pt: PartialTracks, entries: list[SourceEntry]) -> list[SceneMatch]:
    """Every vehicle of the CommonRoad scenes that is also a track of the partial set
    (:data:`MATCH_RMSE`; CommonRoad obstacle ids are NGSIM Vehicle_IDs). A vehicle standing
    still throughout matches its first still window."""
    from numpy.lib.stride_tricks import sliding_window_view

    by_id: dict[int, list[tuple[int, int]]] = {}
    for a, b in pt.bounds():
        by_id.setdefault(int(pt.vehicle[a]), []).append((a, b))
    out = []
    for e in entries:
        tb = e.table
        assert tb is not None
        for v in tb.vehicle_ids():
            rows = np.flatnonzero(tb.vehicle == v)
            sp = tb.speed[rows]
            if sp.shape[0] < MATCH_MIN_SAMPLES:
                continue
            best: tuple[float, int, int] | None = None
            for a, b in by_id.get(int(v), []):
                if b - a < sp.shape[0]:
                    continue
                win = sliding_window_view(pt.speed[a:b], sp.shape[0])
                ss = float(sp @ sp)
                c = np.clip(win @ sp / ss, 0.95, 1.05) if ss > 0 else np.ones(win.shape[0])
                res = np.sqrt(np.mean((win - c[:, None] * sp) ** 2, axis=1))
                j = int(np.argmin(res))
                if res[j] < MATCH_RMSE and (best is None or res[j] < best[0]):
                    best = (float(res[j]), a, j)
            if best is not None:
                _, a, j = best
                out.append(SceneMatch(tb.scene, int(v), e.split, e.group, int(pt.track[a]),
                                      float(pt.t[a + j] - tb.t[rows[0]])))
    return out


def partial_lane_centres(pt: PartialTracks, use: np.ndarray, bin_m: float = LINE_BIN_M) -> tuple[np.ndarray, np.ndarray]:
    """Lane centres of the partial set (m from the left edge), [bins, 5], and the bins' centres
    along the road (m), measured from the rows where ``use``: the five highest peaks of the
    histogram (0.1 m) of the lateral position overall, then per ``bin_m`` of road the median of
    the rows within 1.2 m of each overall peak.

    Raises:
        DataError: fewer than five peaks (the file is not the five-lane US-101 mainline).
    """
    lat, s = pt.lateral_from_left[use], pt.s[use]
    edges = np.arange(0.0, max(float(lat.max()), 1.0) + 0.1, 0.1)
    h, _ = np.histogram(lat, bins=edges)
    h = np.convolve(h, np.ones(5) / 5, mode="same")
    peaks = [i for i in range(1, h.shape[0] - 1) if h[i] >= h[i - 1] and h[i] > h[i + 1]]
    peaks = sorted(peaks, key=lambda i: -h[i])
    chosen: list[float] = []
    for i in peaks:
        c = float(edges[i] + 0.05)
        if all(abs(c - o) > 2.0 for o in chosen):
            chosen.append(c)
        if len(chosen) == MAINLINE_LANES:
            break
    if len(chosen) < MAINLINE_LANES:
        raise DataError(pt.source, f"only {len(chosen)} lane-centre peaks in the lateral positions (expected "
                        f"{MAINLINE_LANES})", field="local_x(m)")
    overall = np.sort(np.asarray(chosen))
    n_bins = max(int(np.ceil((float(s.max()) - float(s.min())) / bin_m)), 1)
    s0 = float(s.min())
    centres = np.tile(overall, (n_bins, 1))
    for k in range(n_bins):
        m = (s >= s0 + k * bin_m) & (s < s0 + (k + 1) * bin_m)
        for j, c in enumerate(overall):
            near = lat[m & (np.abs(lat - c) < 1.2)] if m.any() else lat[:0]
            if near.shape[0] >= 50:
                centres[k, j] = float(np.median(near))
    return centres, s0 + (np.arange(n_bins) + 0.5) * bin_m


def partial_lines(s: np.ndarray, centres: np.ndarray, bin_s: np.ndarray) -> np.ndarray:
    """Mainline lines [N, 5] (m, positive LEFT, i.e. minus the distance from the left edge) at
    positions ``s`` [N]: midpoints between neighbouring centres, and half the mean lane width right
    of the fifth centre; interpolated linearly along the road between the bins' centres."""
    mids = 0.5 * (centres[:, :-1] + centres[:, 1:])
    last = centres[:, -1:] + 0.5 * np.mean(np.diff(centres, axis=1), axis=1, keepdims=True)
    from_left = np.concatenate([mids, last], axis=1)  # [bins, 5], ascending to the right
    return -np.stack([np.interp(s, bin_s, from_left[:, j]) for j in range(from_left.shape[1])], axis=1)


def _partial_events(pt: PartialTracks, cfg: SplitConfig, matches: list[SceneMatch], rule: LaneChangeRule,
                    progress: bool, rejected: dict[str, int], tracks: dict[str, int],
                    splits_out: dict[str, dict[int, str]]) -> tuple[list[Event], np.ndarray, np.ndarray, list]:
    seen_in: dict[int, set[str]] = {}
    for m in matches:
        seen_in.setdefault(m.track, set()).add(m.split)
    split_of, block_of = partial_splits(pt, cfg, seen_in)
    drawn, _ = partial_splits(pt, cfg)
    splits_out.update({"block": drawn, "used": split_of})
    use = np.asarray([split_of[int(k)] in ("train", "val") for k in pt.track])
    centres, bin_s = partial_lane_centres(pt, use)
    events: list[Event] = []
    keep_samples = []
    for a, b in tqdm(pt.bounds(), desc="partial US-101 tracks", disable=not progress):
        k = int(pt.track[a])
        sp = split_of[k]
        tracks[sp] = tracks.get(sp, 0) + 1
        if b - a < 3:
            continue
        lines = partial_lines(pt.s[a:b], centres, bin_s)
        d = -pt.lateral_from_left[a:b]
        ex = extract_lane_changes(pt.t[a:b], pt.s[a:b], d, lines, rule)
        for r, c in ex.rejected.items():
            rejected[r] += c
        events += [Event("partial", pt.source, int(pt.vehicle[a]), sp, block_of[k], lc, k) for lc in ex.events]
        if sp in ("train", "val"):
            keep_samples.append((pt.t[a:b], pt.s[a:b], d, lines, pt.dt))
    return events, centres, bin_s, keep_samples


def _lane_keeping(samples: list, rule: LaneChangeRule, far_s: float = 5.0) -> dict[str, list[float]]:
    """p50, p80, p95 of |lateral speed|, |lateral acceleration|, |lateral jerk| and |longitudinal
    jerk| over the samples at least ``far_s`` from any lane-index change: the noise floor."""
    acc: dict[str, list[np.ndarray]] = {"abs_v_lat": [], "abs_lat_accel": [], "abs_lat_jerk": [], "abs_long_jerk": []}
    for t, s, d, lines, dt in samples:
        kd = smooth_derivatives(d, dt, rule.widths)
        ks = smooth_derivatives(s, dt, rule.widths)
        lane = lane_of(kd[0], lines)
        ch = t[np.flatnonzero(lane[1:] != lane[:-1]) + 1]
        far = np.ones(t.shape[0], dtype=bool) if ch.size == 0 else \
            np.min(np.abs(t[:, None] - ch[None, :]), axis=1) >= far_s
        acc["abs_v_lat"].append(np.abs(kd[1][far]))
        acc["abs_lat_accel"].append(np.abs(kd[2][far]))
        acc["abs_lat_jerk"].append(np.abs(kd[3][far]))
        acc["abs_long_jerk"].append(np.abs(ks[3][far]))
    return {k: [float(x) for x in np.percentile(np.concatenate(v), [50, 80, 95])] for k, v in acc.items()}


def synthetic_recovery(rule: LaneChangeRule, durations: tuple[float, ...] = (3.0, 5.0, 7.0),
                       width_m: float = 3.6, speed: float = 12.0) -> list[dict[str, float]]:
    """What the smoothing and the rule make of noise-free lane changes of ``width_m`` whose lateral
    acceleration is one sine period of ``T`` s (peak 2π·w/T², peak jerk 4π²·w/T³): measured
    against true duration, peak lateral acceleration and peak lateral jerk."""
    out = []
    dt = 0.1
    for T in durations:
        t = np.arange(0.0, T + 16.0, dt)
        u = np.clip((t - 8.0) / T, 0.0, 1.0)
        d = -width_m * (u - np.sin(2 * np.pi * u) / (2 * np.pi))  # to the right, from lane 0 to lane 1
        lines = np.full((t.shape[0], MAINLINE_LANES), -width_m / 2) - width_m * np.arange(MAINLINE_LANES)
        ex = extract_lane_changes(t, speed * t, d, lines, rule)
        if len(ex.events) != 1:
            raise AssertionError(f"synthetic lane change of {T} s: {len(ex.events)} events found")
        lc = ex.events[0]
        out.append({"T": T, "duration": lc.duration, "peak_lat_accel": lc.peak_lat_accel,
                    "true_peak_lat_accel": 2 * np.pi * width_m / T**2, "peak_lat_jerk": lc.peak_lat_jerk,
                    "true_peak_lat_jerk": 4 * np.pi**2 * width_m / T**3, "v_lat_cross": abs(lc.v_lat_cross),
                    "true_v_lat_cross": 2 * width_m / T})
    return out


def study(data_root: Path, rule: LaneChangeRule = LaneChangeRule(), seed: int = 0, progress: bool = True) -> Study:
    """Every lane change of both sources with its split (module docstring)."""
    rule.validate()
    cfg = SplitConfig(seed=seed)
    rej_cr = {r: 0 for r in REJECT_REASONS}
    rej_p = {r: 0 for r in REJECT_REASONS}
    tr_cr: dict[str, int] = {}
    tr_p: dict[str, int] = {}
    entries = [e for e in us101_sources(data_root, cfg) if e.table is not None]
    pt = read_chenshimao(data_root / CHENSHIMAO)
    matches = match_scenes(pt, entries)
    cr, dups, keep_cr = _commonroad_events(entries, rule, progress, rej_cr, tr_cr)
    splits: dict[str, dict[int, str]] = {}
    pe, centres, bin_s, keep_p = _partial_events(pt, cfg, matches, rule, progress, rej_p, tr_p, splits)
    # a lane change seen in a scene and in the partial set counts once (the partial set's: its
    # whole trajectory, its split already that of the scene)
    where = {(m.scene, m.vehicle): m for m in matches}
    kept_cr, both = [], 0
    for ev in cr:
        m = where.get((ev.where, ev.track))
        if m is not None and any(p.partial_track == m.track and abs(p.lc.t_cross - (ev.lc.t_cross + m.offset_s)) < 1.5
                                 for p in pe):
            both += 1
            continue
        kept_cr.append(ev)
    return Study(events=kept_cr + pe, rejected={"commonroad": rej_cr, "partial": rej_p}, duplicates=dups,
                 tracks={"commonroad": tr_cr, "partial": tr_p}, partial_centres=centres, partial_bin_s=bin_s,
                 lane_keeping=_lane_keeping(keep_cr + keep_p, rule), synthetic=synthetic_recovery(rule), rule=rule,
                 seed=seed, matches=matches, in_both=both, block_split=splits["block"], track_split=splits["used"])


# ---- statistics ------------------------------------------------------------------------------
def in_group(ev: Event, group: str) -> bool:
    """Whether ``ev`` belongs to the split group (:data:`GROUPS`)."""
    if group == "all":
        return True
    if group == "train+val":
        return ev.split in ("train", "val")
    return ev.split == group


def in_band(ev: Event, band: tuple[float, float] | None) -> bool:
    return band is None or band[0] <= ev.lc.speed_cross < band[1]


def describe(values: list[float]) -> dict[str, float | int]:
    """n, median, p25, p75, p5, p95 of the finite values (NaN statistics when none)."""
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return {"n": 0, **{k: float("nan") for k in ("median", "p25", "p75", "p5", "p95")}}
    p = np.percentile(v, [50, 25, 75, 5, 95])
    return {"n": int(v.size), "median": float(p[0]), "p25": float(p[1]), "p75": float(p[2]), "p5": float(p[3]),
            "p95": float(p[4])}


def stats(events: list[Event], quantity: str, group: str, band: tuple[float, float] | None = None) -> dict:
    return describe([e.value(quantity) for e in events if in_group(e, group) and in_band(e, band)])


def band_name(band: tuple[float, float] | None) -> str:
    if band is None:
        return "all speeds"
    lo, hi = band
    if lo == 0:
        return f"< {hi:g} m/s"
    if not np.isfinite(hi):
        return f"≥ {lo:g} m/s"
    return f"{lo:g}–{hi:g} m/s"


def band_key(band: tuple[float, float]) -> str:
    """The JSON key of a speed band: ``"10-15"`` (m/s, lower bound included), ``"15-inf"``."""
    return f"{band[0]:g}-{band[1]:g}"


def _rounded(d: dict) -> dict:
    """Statistics with 4 significant digits (the data carry fewer)."""
    return {k: (v if isinstance(v, int) or not np.isfinite(v) else float(f"{v:.4g}")) for k, v in d.items()}


def summary(st: Study) -> dict:
    """The JSON summary: train+val (defaults may be taken from it) and test (held out) statistics
    of :data:`SUMMARY_FIELDS`, overall and per speed band, and how they were measured."""
    def block(group: str) -> dict:
        out = {}
        for q in SUMMARY_FIELDS:
            out[q] = {"all": _rounded(stats(st.events, q, group)),
                      **{band_key(b): _rounded(stats(st.events, q, group, b)) for b in BANDS}}
        return out

    return {
        "schema": SCHEMA,
        "note": "train_val: the numbers defaults may be taken from; test: held out, for reporting only",
        "n": {g: sum(in_group(e, g) for e in st.events) for g in GROUPS},
        "train_val": block("train+val"),
        "test": block("test"),
        "units": {q: u for q, _, u in QUANTITIES if q in SUMMARY_FIELDS},
        "speed_bands": "speed at the crossing (m/s), lower bound included: " + ", ".join(band_key(b) for b in BANDS),
        "rule": {k: v for k, v in asdict(st.rule).items() if k != "widths"},
        "smoothing_widths_s": asdict(st.rule.widths),
        "split_seed": st.seed,
    }


# ---- outputs ---------------------------------------------------------------------------------
CSV_COLUMNS = ("source", "where", "vehicle", "split", "group", "t_cross_s", "s_cross_m", "from_lane", "to_lane",
               "direction", "speed_cross", "v_lat_cross", "duration", "peak_lat_accel", "peak_lat_jerk",
               "peak_long_jerk", "peak_yaw_rate", "t_start_s", "t_end_s")
"""Columns of the events CSV (lanes as NGSIM lane numbers, 1 = leftmost; direction +1 left)."""


def events_csv(events: list[Event]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for e in events:
        lc = e.lc
        w.writerow([e.source, e.where, e.track, e.split, e.group, f"{lc.t_cross:.2f}", f"{lc.s_cross:.1f}",
                    lc.from_lane + 1, lc.to_lane + 1, lc.direction, f"{lc.speed_cross:.3f}", f"{lc.v_lat_cross:.3f}",
                    f"{lc.duration:.1f}", f"{lc.peak_lat_accel:.3f}", f"{lc.peak_lat_jerk:.3f}",
                    f"{lc.peak_long_jerk:.3f}", "" if not np.isfinite(lc.peak_yaw_rate) else f"{lc.peak_yaw_rate:.4f}",
                    f"{lc.t_start:.1f}", f"{lc.t_end:.1f}"])
    return buf.getvalue()


def _fmt(x: float, q: str) -> str:
    if not np.isfinite(x):
        return "–"
    return f"{x:.3f}" if q == "peak_yaw_rate" else f"{x:.2f}"


def _row(label: str, d: dict, q: str) -> str:
    if d["n"] == 0:
        return f"| {label} | 0 | – | – | – |"
    return (f"| {label} | {d['n']} | {_fmt(d['median'], q)} | {_fmt(d['p25'], q)}–{_fmt(d['p75'], q)} | "
            f"{_fmt(d['p5'], q)}–{_fmt(d['p95'], q)} |")


def figure(st: Study, png: Path) -> None:
    """Histograms of duration, peak lateral acceleration, |lateral speed| at the crossing and peak
    lateral jerk: train+val and test."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    png.parent.mkdir(parents=True, exist_ok=True)
    panels = (("duration", "duration (s)", np.arange(0, 12.5, 0.5)),
              ("peak_lat_accel", "peak |lateral acceleration| (m/s²)", np.arange(0, 2.1, 0.1)),
              ("abs_v_lat_cross", "|lateral speed| at the crossing (m/s)", np.arange(0, 2.1, 0.1)),
              ("peak_lat_jerk", "peak |lateral jerk| (m/s³)", np.arange(0, 3.1, 0.15)))
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.2))
    for ax, (q, label, bins) in zip(axes, panels):
        for group, col in (("train+val", "C0"), ("test", "C3")):
            v = [e.value(q) for e in st.events if in_group(e, group)]
            v = np.clip(np.asarray(v), bins[0], bins[-1])
            ax.hist(v, bins=bins, density=True, alpha=0.5, color=col, label=f"{group} (n={len(v)})")
            if len(v):
                ax.axvline(float(np.median(v)), color=col, lw=1)
        ax.set_xlabel(label, fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7)
    w = st.rule.widths
    fig.suptitle(f"Human lane changes on US-101 (NGSIM), every speed; lines: medians; last bin holds the values beyond "
                 f"it; smoothing widths {w.position:g}/{w.speed:g}/{w.accel:g}/{w.jerk:g} s", fontsize=9)
    fig.tight_layout()
    fig.savefig(png, dpi=90)
    plt.close(fig)


def markdown(st: Study, figure_link: str, command: str, csv_name: str, json_name: str) -> str:
    ev = st.events
    r, w = st.rule, st.rule.widths
    n = {g: sum(in_group(e, g) for e in ev) for g in GROUPS}
    per_src = {src: {g: sum(in_group(e, g) and e.source == src for e in ev) for g in ("train", "val", "test")}
               for src in ("commonroad", "partial")}
    lines = [
        "# Human lane changes on US-101 (NGSIM)",
        "",
        f"Written by `{command}`. The reference the planner's comfort limits are to be taken from: "
        "every lane change between mainline lanes in the real NGSIM US-101 tracks, how long it takes and how hard "
        "it turns, per speed band and split.",
        "",
        f"**Which numbers to use.** Defaults are taken from the **train+val** rows only (n = {n['train+val']}); the "
        f"**test** rows (n = {n['test']}) are held out and reported for comparison, never for tuning. The JSON summary "
        f"[{json_name}]({json_name}) holds the train+val and test statistics of duration, peak lateral acceleration, "
        f"peak lateral and longitudinal jerk and peak yaw rate; every event is a row of [{csv_name}]({csv_name}).",
        "",
        "## Headline (train+val, every speed)",
        "",
        "| quantity | n | median | IQR (p25–p75) | p5–p95 |",
        "|---|---|---|---|---|",
    ]
    for q, name, unit in QUANTITIES:
        lines.append(_row(f"{name} ({unit})", stats(ev, q, "train+val"), q))
    lines += ["", "The same on the test split:", "", "| quantity | n | median | IQR (p25–p75) | p5–p95 |",
              "|---|---|---|---|---|"]
    for q, name, unit in QUANTITIES:
        lines.append(_row(f"{name} ({unit})", stats(ev, q, "test"), q))
    lines += ["", f"![human lane changes]({figure_link})", ""]
    lines += ["## Lane changes per split and source", "",
              "| source | train | val | test | total |", "|---|---|---|---|---|"]
    for src, label in (("commonroad", "CommonRoad scenes"), ("partial", "partial vehicle set")):
        c = per_src[src]
        lines.append(f"| {label} | {c['train']} | {c['val']} | {c['test']} | {sum(c.values())} |")
    lines.append(f"| **total** | {n['train']} | {n['val']} | {n['test']} | {n['all']} |")
    lines += ["", "Tracks read: " + "; ".join(
        f"{src} " + ", ".join(f"{s} {st.tracks[src].get(s, 0)}" for s in ("train", "val", "test"))
        for src in ("commonroad", "partial")) + f". Duplicates removed (one lane change in two scenes of one overlap "
        f"group): {st.duplicates}.", ""]
    lines += ["Candidates rejected (a change of lane index that the rule does not accept), per reason:", "",
              "| reason | CommonRoad scenes | partial vehicle set |", "|---|---|---|"]
    for reason in REJECT_REASONS:
        lines.append(f"| {reason} | {st.rejected['commonroad'][reason]} | {st.rejected['partial'][reason]} |")
    lines += ["", "## Per speed band (speed at the crossing)", "",
              "Each table: the train+val rows first, then test. IQR = p25–p75.", ""]
    for q, name, unit in QUANTITIES:
        if q == "speed_cross":
            continue
        lines += [f"### {name} ({unit})", "", "| split | speed band | n | median | IQR | p5–p95 |",
                  "|---|---|---|---|---|---|"]
        for group in ("train+val", "test"):
            for b in (None, *BANDS):
                row = _row(band_name(b), stats(ev, q, group, b), q)
                lines.append(f"| {group} " + row)
        lines.append("")
    lines += ["## Every split", "", "train, val and test separately (every speed).", "",
              "| quantity | split | n | median | IQR | p5–p95 |", "|---|---|---|---|---|---|"]
    for q, name, unit in QUANTITIES:
        for group in ("train", "val", "test", "all"):
            lines.append(f"| {name} ({unit}) " + _row(group, stats(ev, q, group), q))
    lk = st.lane_keeping
    syn = st.synthetic
    n_tracks = len({m.track for m in st.matches})
    overridden = sum(1 for k in {m.track for m in st.matches}
                     if k in st.block_split and st.track_split.get(k) != st.block_split[k])
    groups_of: dict[int, set[str]] = {}
    for m in st.matches:
        groups_of.setdefault(m.track, set()).add(m.group)
    cross = sorted({tuple(sorted(g)) for g in groups_of.values() if len(g) > 1})
    n_cross = sum(1 for g in groups_of.values() if len(g) > 1)
    test_groups = {m.group for m in st.matches if m.split == "test"}
    cross_test = sum(1 for g in groups_of.values() if len(g) > 1 and g & test_groups and g - test_groups)
    cross_text = ("No vehicle is in scenes of two overlap groups." if not cross else
                  f"**{n_cross} vehicles are in scenes of more than one overlap group**, {cross_test} of them in a "
                  "test scene and in a train or val scene: the overlap table groups scenes that share states, but "
                  "scenes of different groups follow one another within seconds with the same vehicles (the start "
                  "of every matched scene on the partial set's clock is in the last table of this report). This "
                  "concerns the project's split of the scenes, which this report uses as it is.")
    lines += [
        "",
        "## How the lane changes are found",
        "",
        "**Data.** Two real NGSIM US-101 sources (15 June 2005, 7:50–8:35 am, 10 Hz, metres; "
        "`../shared/data/ngsim/PROVENANCE.md`):",
        "",
        "* the CommonRoad scenes (4.8–16.6 s each): read as the data build reads them (curvilinear road frame, "
        "one variant per scene, `USA_US101-3_5_T-1` excluded) and **split by overlap group with the build's own "
        f"assignment** (`us101_sources`, seed {st.seed}); vehicle centres; lane lines from the lanelet map. A vehicle "
        "seen in two scenes of one overlap group gives its lane change once (same 21 logged speeds around the "
        "crossing).",
        "* the partial vehicle set (`chenshimao_us101_partial_per_vehicle_metric.csv.gz`: 370 whole trajectories, "
        "no lane ids; positions of the FRONT centre, which crosses a line (L/2)·ψ ≈ 0.1–0.2 m, about 0.15 s, "
        "before the vehicle's centre does): **split by the build's rule for long recordings** — 60 s time blocks drawn "
        "to train/val/test by `assign_or_test` (weights: rows), each trajectory in the block where it starts, so "
        "no vehicle is on two sides. Lane lines: the midpoints between lane centres measured from the train+val "
        "trajectories (the five density peaks of the lateral position, then per 80 m of road the median within "
        "1.2 m of each peak; interpolated along the road); the right line of lane 5 half a lane width right of "
        "its centre.",
        "",
        f"**The two sources share vehicles.** CommonRoad obstacle ids are NGSIM Vehicle_IDs: "
        f"{len(st.matches)} vehicles of the scenes are tracks of the partial set ({n_tracks} tracks; same id, and "
        f"speeds equal up to a factor within 5 % of 1 — the two unit conversions differ by about 1.2 % — at RMS "
        f"residual < {MATCH_RMSE:g} m/s over the whole scene). Such a track takes the split of its scenes (test "
        f"before val before train; {overridden} tracks thereby moved), so no vehicle of a test scene is in "
        f"train+val, and a lane change seen in both is counted once ({st.in_both}), from the partial set. "
        + cross_text,
        "",
        "Lane centres of the partial set (m from the left edge), per 80 m of road:",
        "",
        "| road (m) | lane 1 | lane 2 | lane 3 | lane 4 | lane 5 |",
        "|---|---|---|---|---|---|",
    ]
    for s_c, row in zip(st.partial_bin_s, st.partial_centres):
        lines.append(f"| {s_c - LINE_BIN_M / 2:.0f}–{s_c + LINE_BIN_M / 2:.0f} | " +
                     " | ".join(f"{c:.2f}" for c in row) + " |")
    lines += [
        "",
        f"**Mainline.** NGSIM lanes 1–5 (the five leftmost lanes); the auxiliary lane 6 and the ramps are not "
        "counted (changes to or from them are rejected as `not_mainline`).",
        "",
        f"**Smoothing.** Positions along and across the road are smoothed with the symmetric exponential moving "
        f"average of Thiemann, Treiber & Kesting (2008): weights exp(−|Δt|/Δ), the kernel cut at 3Δ and truncated "
        f"symmetrically at the trajectory ends. Widths: positions Δ = {w.position:g} s; speed, acceleration and "
        f"jerk are central differences of the previous smoothed signal, each smoothed again with "
        f"{w.speed:g} / {w.accel:g} / {w.jerk:g} s; the yaw rate (the change of the heading of the smoothed "
        f"velocity relative to the road) with {w.accel:g} s. Half a second is long against the position noise "
        "(a few samples) and short against a lane change (seconds); the derivative widths are shorter because every "
        "pass lowers the peaks of a real manoeuvre (table below), and long enough that lane keeping reads as little "
        "lateral acceleration and jerk (the noise floor below).",
        "",
        f"**Rule** (`nudge_train.data.lane_changes`). (1) Each sample's lane from the smoothed lateral position "
        f"and the lane lines. (2) A change of lane between adjacent mainline lanes counts when the vehicle was in "
        f"the old lane for {r.dwell_before_s:g} s before it and stays in the new lane for {r.dwell_after_s:g} s after "
        f"it (no return, no other change). (3) Crossing time: where the smoothed lateral position crosses the line "
        f"(linear interpolation); the lateral speed there must be at least {r.v_still:g} m/s. (4) Start / end of "
        f"the lateral motion: the last sample before / first after the crossing with |lateral speed| < "
        f"{r.v_still:g} m/s, searched at most {r.max_search_s:g} s from the crossing; no other lane change inside. "
        "(5) Events whose windows or searches run off the trajectory are rejected as truncated. (6) Quantities "
        "over [start, end]: duration, peak |lateral acceleration|, peak |lateral jerk|, peak |longitudinal jerk|, "
        f"peak |yaw rate| (undefined below {r.min_speed_heading:g} m/s: such events have no yaw rate); at the "
        "crossing: lateral speed and speed.",
        "",
        f"**Why {r.v_still:g} m/s.** In lane keeping (train+val samples at least 5 s from any change of lane index) "
        f"|lateral speed| has median {lk['abs_v_lat'][0]:.2f}, p80 {lk['abs_v_lat'][1]:.2f} and p95 "
        f"{lk['abs_v_lat'][2]:.2f} m/s: below {r.v_still:g} m/s a vehicle is doing what it does in its lane. A "
        "lower threshold would make start and end wait for lane-keeping noise to be quiet, a higher one would "
        "cut the slow beginning and end of the manoeuvre.",
        "",
        "**Noise floor** (the same lane-keeping samples; p50 / p80 / p95): "
        f"|lateral acceleration| {' / '.join(f'{x:.2f}' for x in lk['abs_lat_accel'])} m/s², "
        f"|lateral jerk| {' / '.join(f'{x:.2f}' for x in lk['abs_lat_jerk'])} m/s³, "
        f"|longitudinal jerk| {' / '.join(f'{x:.2f}' for x in lk['abs_long_jerk'])} m/s³. NGSIM positions come "
        "from video and carry noise of the order of decimetres (Punzo et al. 2011; Coifman & Li 2017); each "
        "derivative amplifies it, so jerk, above all longitudinal jerk, is inflated by noise: a peak jerk of a lane "
        "change is a peak over a noisy signal, and depends on the smoothing widths above.",
        "",
        "**What the smoothing and the rule do to a known lane change** (noise-free, 3.6 m, the lateral acceleration "
        "one sine period of T s, 12 m/s):",
        "",
        "| T (s) | duration found (s) | peak lat. accel. found / true (m/s²) | peak lat. jerk found / true (m/s³) "
        "| lateral speed at the crossing found / true (m/s) |",
        "|---|---|---|---|---|",
    ]
    for row in syn:
        lines.append(f"| {row['T']:g} | {row['duration']:.1f} | {row['peak_lat_accel']:.2f} / "
                     f"{row['true_peak_lat_accel']:.2f} | {row['peak_lat_jerk']:.2f} / {row['true_peak_lat_jerk']:.2f} "
                     f"| {row['v_lat_cross']:.2f} / {row['true_v_lat_cross']:.2f} |")
    lines += [
        "",
        "The duration found is within about a second of T: shorter for slow manoeuvres (their first and last "
        f"parts are slower than {r.v_still:g} m/s), longer for quick ones (the smoothing spreads them). The peaks "
        "are lower because of the smoothing, more so for short manoeuvres and for jerk: read peak acceleration and "
        "jerk as lower bounds of the peaks of a smooth manoeuvre of that duration.",
        "",
        f"**Longitudinal jerk is mostly noise here**: the train+val median of its peak over a lane change "
        f"({stats(ev, 'peak_long_jerk', 'train+val')['median']:.2f} m/s³) is below the p95 of lane keeping "
        f"({lk['abs_long_jerk'][2]:.2f} m/s³), a peak over a window of seconds being the maximum of many noisy "
        "samples. It bounds what drivers do from above, not from below.",
        "",
        "Speed bands are the speed at the crossing: < 5, 5–10, 10–15, ≥ 15 m/s.",
        "",
        "## When the CommonRoad scenes were recorded",
        "",
        "Start of each scene on the partial set's clock (s after its first row, 7:49:45 am): the median over its "
        "vehicles found in the partial set, with the spread of those vehicles' offsets (a spread near 0 says the "
        "matches agree).",
        "",
        "| scene | overlap group | split | vehicles matched | start (s) | spread (s) |",
        "|---|---|---|---|---|---|",
    ]
    per_scene: dict[str, list[SceneMatch]] = {}
    for m in st.matches:
        per_scene.setdefault(m.scene, []).append(m)
    for scene, ms in sorted(per_scene.items(), key=lambda kv: float(np.median([m.offset_s for m in kv[1]]))):
        off = np.asarray([m.offset_s for m in ms])
        lines.append(f"| {scene} | {ms[0].group} | {ms[0].split} | {len(ms)} | {np.median(off):.1f} | "
                     f"{np.ptp(off):.1f} |")
    lines.append("")
    return "\n".join(lines)


def run(data_root: Path, doc: Path, json_path: Path, csv_path: Path, png: Path, command: str,
        rule: LaneChangeRule = LaneChangeRule(), seed: int = 0, progress: bool = True) -> Study:
    """Run the study and write the report ``doc``, the summary ``json_path``, the events
    ``csv_path`` and the figure ``png`` (links in the report are relative to its folder)."""
    st = study(data_root, rule, seed, progress)
    figure(st, png)
    doc.parent.mkdir(parents=True, exist_ok=True)
    for p in (json_path, csv_path):
        p.parent.mkdir(parents=True, exist_ok=True)
    def rel(p: Path) -> str:
        return os.path.relpath(p.resolve(), doc.parent.resolve())

    atomic_write_text(json_path, json.dumps(_finite(summary(st)), indent=1, sort_keys=True) + "\n")
    atomic_write_bytes(csv_path, events_csv(st.events).encode())
    atomic_write_text(doc, markdown(st, rel(png), command, rel(csv_path), rel(json_path)))
    return st


def _finite(obj: object) -> object:
    """NaN as null (JSON has no NaN)."""
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj
