"""Real cut-ins and the followers' reactions.

A cut-in: a vehicle (the intruder) changes from lane ``lane_from`` to the adjacent lane
``lane_to`` and, at the moment its centre crosses the lane line, the nearest vehicle behind it in
``lane_to`` (the follower, within ``CutInConfig.max_gap`` of bumper-to-bumper gap) stays in that
lane. Sources: US-101 CommonRoad tracks (measured lateral motion: centre and nearest-edge
crossings, lateral overlap); I-80 Coifman & Li (longitudinal only: the crossing is the frame of
the Lane_ID jump, no edge, no overlap).

Reaction measures (the follower's extra fall-back): ``fb(tau) = x_F(t0 + tau) - [x_F(t0) +
v_F(t0) tau]`` at tau = 0, 0.3, ..., 4.2 s after the alignment time t0 (centre crossing, or the
nearest-edge crossing), negative = behind its own constant-speed prediction; and the same against
an IDM prediction that follows only the pre-cut-in leader.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nudge_train.data.tracks import TrackTable
from nudge_train.errors import ConfigError
from nudge_train.jsonio import load_json

from .model import simulate_follower
from .sources import Sources

TAUS = np.round(np.arange(0.0, 4.2 + 1e-9, 0.3), 1)
"""Reaction time grid (s after the alignment time): 0, 0.3, ..., 4.2 (15 values)."""

CUTINS_SCHEMA = "nudge.cutins/1"


@dataclass(frozen=True)
class CutInConfig:
    """Detection settings (one source of their defaults). Times in s, distances in m."""

    max_gap: float = 60.0
    intruder_before_s: float = 0.5
    intruder_after_s: float = 1.0
    follower_before_s: float = 0.5
    follower_min_after_s: float = 1.2
    min_lateral_move: float = 1.0
    horizon_s: float = 4.2
    accel_smooth_s: float = 0.5
    onset_drop: float = 0.5
    onset_hold_s: float = 0.5
    control_every_s: float = 1.0


class Tracks:
    """Row lookups on a :class:`TrackTable`: per-vehicle slices and per-frame rows."""

    def __init__(self, table: TrackTable) -> None:
        self.table = table
        self.frame = table.frame()
        ids, starts = np.unique(table.vehicle, return_index=True)
        ends = np.concatenate([starts[1:], [len(table)]])
        self.rows = {int(i): slice(int(s), int(e)) for i, s, e in zip(ids, starts, ends)}
        fo = np.argsort(self.frame, kind="stable")
        fs = self.frame[fo]
        uf, fstart = np.unique(fs, return_index=True)
        fend = np.concatenate([fstart[1:], [fs.shape[0]]])
        self.by_frame = {int(f): fo[s:e] for f, s, e in zip(uf, fstart, fend)}
        self.dt = table.dt

    def at(self, frame: int) -> np.ndarray:
        """Row indices present at ``frame``."""
        return self.by_frame.get(int(frame), np.zeros(0, dtype=np.int64))

    def series(self, vid: int, col: str, t: np.ndarray) -> np.ndarray:
        """Column ``col`` of vehicle ``vid`` linearly interpolated at times ``t`` (s); NaN outside."""
        sl = self.rows[vid]
        tt = self.table.t[sl]
        vals = getattr(self.table, col)[sl]
        out = np.interp(t, tt, vals)
        return np.where((t >= tt[0] - 1e-9) & (t <= tt[-1] + 1e-9), out, np.nan)

    def lane_run(self, vid: int, frame: int, lane: int) -> tuple[float, float]:
        """(seconds before, seconds after) ``frame`` that ``vid`` stays in ``lane`` without a gap."""
        sl = self.rows[vid]
        fr = self.frame[sl]
        ln = self.table.lane[sl]
        j = int(np.searchsorted(fr, frame))
        if j >= fr.shape[0] or fr[j] != frame or ln[j] != lane:
            return 0.0, 0.0
        a = j
        while a > 0 and ln[a - 1] == lane and fr[a - 1] == fr[a] - 1:
            a -= 1
        b = j
        while b + 1 < fr.shape[0] and ln[b + 1] == lane and fr[b + 1] == fr[b] + 1:
            b += 1
        return (frame - fr[a]) * self.dt, (fr[b] - frame) * self.dt


@dataclass
class CutIn:
    """One real cut-in (times in scene seconds; distances in m; speeds in m/s)."""

    source: str
    scene: str
    group: str
    split: str
    intruder: int
    follower: int
    old_leader: int
    lane_from: int
    lane_to: int
    t_centre: float
    t_edge: float | None
    gap: float
    follower_speed: float
    intruder_speed: float
    time_headway: float
    follower_after_s: float
    follower_before_s: float

    @property
    def key(self) -> str:
        return f"{self.source}:{self.scene}:{self.intruder}>{self.follower}@{self.t_centre:.2f}"


def _floor4(x: float) -> float:
    """``x`` rounded DOWN to 1e-4 (a stored duration never exceeds the observed one)."""
    return float(np.floor(float(x) * 1e4 + 1e-6) / 1e4)


def _boundary(bounds: np.ndarray, lane_from: int, lane_to: int) -> float:
    """Lateral position (m) of the line between adjacent left-indexed lanes (bounds ascending)."""
    n = bounds.shape[0] - 1
    return float(bounds[n - max(lane_from, lane_to)])


def overlap_series(tr: Tracks, vid: int, t: np.ndarray, lane_from: int, lane_to: int) -> tuple[np.ndarray, np.ndarray]:
    """(centre, nearest-edge) signed lateral distance (m) of ``vid`` beyond the line into
    ``lane_to`` at times ``t`` (positive = inside ``lane_to``). The edge is the box's outermost
    point toward the new lane at the vehicle's heading."""
    x = tr.series(vid, "x", t)
    y = tr.series(vid, "y", t)
    psi = tr.series(vid, "heading", t)
    ln = tr.series(vid, "length", t)
    w = tr.series(vid, "width", t)
    side = 1.0 if lane_to < lane_from else -1.0  # left = +y
    yb = np.array([_boundary(tr.table.lanes.bounds_at(float(xx)), lane_from, lane_to) if np.isfinite(xx) else np.nan
                   for xx in x])
    centre = side * (y - yb)
    ext = 0.5 * ln * np.abs(np.sin(psi)) + 0.5 * w * np.abs(np.cos(psi))
    return centre, centre + ext


def _first_crossing(t: np.ndarray, d: np.ndarray, t_hint: float) -> float | None:
    """Latest time <= t_hint where ``d`` rises through 0 (linear interpolation), or None."""
    idx = np.flatnonzero((d[:-1] <= 0) & (d[1:] > 0) & (t[1:] <= t_hint + 1e-9))
    if idx.shape[0] == 0:
        return None
    i = int(idx[-1])
    return float(t[i] + (t[i + 1] - t[i]) * (-d[i]) / (d[i + 1] - d[i]))


def _nearest(tr: Tracks, frame: int, lane: int, x_ref: float, ahead: bool, exclude: set[int]) -> int:
    rows = tr.at(frame)
    rows = rows[tr.table.lane[rows] == lane]
    best, bd = -1, np.inf
    for r in rows:
        v = int(tr.table.vehicle[r])
        if v in exclude:
            continue
        d = (tr.table.x[r] - x_ref) if ahead else (x_ref - tr.table.x[r])
        if 0 < d < bd:
            best, bd = v, d
    return best


def detect(tr: Tracks, source: str, scene: str, group: str, split_of, cfg: CutInConfig,
           lateral_measured: bool) -> list[CutIn]:
    """Every cut-in of one track table. ``split_of(frame) -> split``."""
    out = []
    tab = tr.table
    dt = tr.dt
    for vid, sl in tr.rows.items():
        fr = tr.frame[sl]
        ln = tab.lane[sl]
        ch = np.flatnonzero((ln[1:] != ln[:-1]) & (fr[1:] == fr[:-1] + 1)) + 1
        for j in ch:
            lf, lt = int(ln[j - 1]), int(ln[j])
            if abs(lf - lt) != 1 or lf < 0 or lt < 0:
                continue
            f = int(fr[j])
            before, _ = tr.lane_run(vid, int(fr[j - 1]), lf)
            _, after = tr.lane_run(vid, f, lt)
            t_end = float(tab.t[sl][-1])
            if before + dt < cfg.intruder_before_s - 1e-9:
                continue
            if after < cfg.intruder_after_s - 1e-9 and not (f * dt + after >= t_end - 1e-9 and after >= 0.5):
                continue
            t_c_frame = f * dt
            if lateral_measured:
                tt = np.arange(t_c_frame - 3.0, t_c_frame + 3.0 + 1e-9, dt)
                centre, edge = overlap_series(tr, vid, tt, lf, lt)
                ok = np.isfinite(centre)
                tt, centre, edge = tt[ok], centre[ok], edge[ok]
                t_c = _first_crossing(tt, centre, t_c_frame)
                if t_c is None:
                    continue
                t_e = _first_crossing(tt, edge, t_c)
                yy = tr.series(vid, "y", np.array([t_c - 1.0, t_c + 1.0]))
                if np.all(np.isfinite(yy)) and abs(yy[1] - yy[0]) < cfg.min_lateral_move:
                    continue
            else:
                t_c, t_e = t_c_frame, None
            x_i = float(tab.x[sl][j])
            fol = _nearest(tr, f, lt, x_i, ahead=False, exclude={vid})
            if fol < 0:
                continue
            fb, fa = tr.lane_run(fol, f, lt)
            if fb < cfg.follower_before_s - 1e-9 or fa < cfg.follower_min_after_s - 1e-9:
                continue
            st = tr.series(vid, "x", np.array([t_c])), tr.series(vid, "length", np.array([t_c]))
            sf = tr.series(fol, "x", np.array([t_c])), tr.series(fol, "length", np.array([t_c]))
            gap = float(st[0][0] - 0.5 * st[1][0] - sf[0][0] - 0.5 * sf[1][0])
            if not (0.0 < gap <= cfg.max_gap):
                continue
            vf = float(tr.series(fol, "speed", np.array([t_c]))[0])
            vi = float(tr.series(vid, "speed", np.array([t_c]))[0])
            old = _nearest(tr, f, lt, float(tr.series(fol, "x", np.array([t_c_frame]))[0]), ahead=True,
                           exclude={vid, fol})
            out.append(CutIn(source=source, scene=scene, group=group, split=split_of(f), intruder=int(vid),
                             follower=fol, old_leader=old, lane_from=lf, lane_to=lt, t_centre=round(t_c, 4),
                             t_edge=None if t_e is None else round(t_e, 4), gap=round(gap, 3),
                             follower_speed=round(vf, 3), intruder_speed=round(vi, 3),
                             time_headway=round(gap / max(vf, 0.1), 3),
                             follower_after_s=_floor4(min(fa + (t_c_frame - t_c), cfg.horizon_s)),
                             follower_before_s=_floor4(fb - (t_c_frame - t_c))))
    return out


def _raw_speeds(tr: Tracks, vid: int, frames: np.ndarray) -> np.ndarray:
    """Logged speeds (mm/s, integers; -1 where absent) of ``vid`` at integer ``frames``."""
    sl = tr.rows[vid]
    fr = tr.frame[sl]
    sp = np.rint(tr.table.speed[sl] * 1000).astype(np.int64)
    j = np.clip(np.searchsorted(fr, frames), 0, fr.shape[0] - 1)
    return np.where(fr[j] == frames, sp[j], -1)


def _event_signatures(tr: Tracks, e: CutIn, width: int = 10) -> set[bytes]:
    """Fingerprints of an event: windows of ``width`` logged (intruder, follower) speed pairs
    within 1 s of the crossing. Scenes of one overlap group re-cut the same NGSIM states, so a
    repeated event shares windows even where the two scenes' road frames differ slightly."""
    fc = int(np.ceil(e.t_centre / tr.dt - 1e-9))
    frames = np.arange(fc - 10, fc + 11)
    a = _raw_speeds(tr, e.intruder, frames)
    b = _raw_speeds(tr, e.follower, frames)
    return {a[i:i + width].tobytes() + b[i:i + width].tobytes() for i in range(frames.shape[0] - width + 1)
            if (a[i:i + width] >= 0).all() and (b[i:i + width] >= 0).all()}


@dataclass
class CutInSet:
    """Detected events, the track lookups they refer to, and what was dropped (reason -> n)."""

    events: list[CutIn]
    tracks: dict[str, Tracks]
    dropped: dict[str, int] = field(default_factory=dict)


def find_cutins(sources: Sources, cfg: CutInConfig = CutInConfig(), progress: bool = False) -> CutInSet:
    """Cut-ins in every US-101 scene (one copy per event across the scenes of an overlap group)
    and in the Coifman & Li I-80 table."""
    events: list[CutIn] = []
    tracks: dict[str, Tracks] = {}
    dropped: dict[str, int] = {}
    seen: dict[str, set[bytes]] = {}
    for sc in tqdm(sources.us101, desc="cut-ins US-101", disable=not progress):
        tr = Tracks(sc.table)
        tracks[sc.name] = tr
        for e in detect(tr, "us101", sc.name, sc.group, lambda f, s=sc.split: s, cfg, lateral_measured=True):
            sig = _event_signatures(tr, e)
            grp = seen.setdefault(sc.group, set())
            if sig & grp:
                dropped["repeated in another scene of the overlap group"] = dropped.get(
                    "repeated in another scene of the overlap group", 0) + 1
                continue
            grp |= sig
            events.append(e)
    tr = Tracks(sources.coifman)
    tracks["i80-coifman"] = tr
    events += detect(tr, "i80", "i80-coifman", "i80", sources.i80_split, cfg, lateral_measured=False)
    return CutInSet(events=events, tracks=tracks, dropped=dropped)


def accel_series(tr: Tracks, vid: int, t: np.ndarray, smooth_s: float) -> np.ndarray:
    """Follower acceleration (m/s^2) at times ``t``: centred difference of speed over ``smooth_s``."""
    h = 0.5 * smooth_s
    return (tr.series(vid, "speed", t + h) - tr.series(vid, "speed", t - h)) / smooth_s


def fall_back(tr: Tracks, vid: int, t0: float, taus: np.ndarray = TAUS) -> np.ndarray:
    """Extra fall-back [len(taus)] (m) of ``vid`` against its constant-speed prediction from t0."""
    x = tr.series(vid, "x", t0 + taus)
    v0 = tr.series(vid, "speed", np.array([t0]))[0]
    return x - (x[0] + v0 * taus)


def idm_fall_back(tr: Tracks, e: CutIn, params: np.ndarray, taus: np.ndarray = TAUS,
                  delta: float = 4.0) -> np.ndarray:
    """Fall-back [len(taus)] (m) of the real follower against an IDM follower (``params`` [5]:
    T, s0, a_max, b, v0_ratio) that starts in the real state at the centre crossing and follows
    only the pre-cut-in leader (free road where there is none)."""
    dt = tr.dt
    t = e.t_centre + np.arange(0, int(round(taus[-1] / dt)) + 1) * dt
    xf = tr.series(e.follower, "x", t) + 0.5 * tr.series(e.follower, "length", t)
    vf = tr.series(e.follower, "speed", t)
    if e.old_leader >= 0:
        lr = tr.series(e.old_leader, "x", t) - 0.5 * tr.series(e.old_leader, "length", t)
        lv = tr.series(e.old_leader, "speed", t)
    else:
        lr = np.full(t.shape, np.nan)
        lv = np.zeros(t.shape)
    v_ref = float(np.nanmax(tr.series(e.follower, "speed", tr.table.t[tr.rows[e.follower]])))
    sim = simulate_follower(xf[0], vf[0], lr, np.nan_to_num(lv), params[None, :4], params[4] * v_ref, dt, delta)
    idx = np.rint(taus / dt).astype(int)
    return xf[idx] - sim.x[0, idx]


def onset(tr: Tracks, e: CutIn, cfg: CutInConfig) -> tuple[float | None, float | None, float]:
    """(onset time, intruder edge overlap at onset, peak deceleration) of the follower.

    Onset: the first time in [t_ref - 2 s, t_centre + 2 s] (t_ref = the edge crossing, else the
    centre crossing) from which the follower's acceleration stays ``onset_drop`` below its
    pre-event baseline (its mean over [t_ref - 3 s, t_ref - 2 s]) for ``onset_hold_s``; None if
    it never does. Peak deceleration: the lowest acceleration (m/s^2) over [t_ref - 1 s,
    t_centre + the observed horizon]."""
    dt = tr.dt
    t_ref = e.t_edge if e.t_edge is not None else e.t_centre
    tb = np.arange(t_ref - 3.0, t_ref - 2.0 + 1e-9, dt)
    base = accel_series(tr, e.follower, tb, cfg.accel_smooth_s)
    tt = np.arange(t_ref - 2.0, e.t_centre + 2.0 + 1e-9, dt)
    acc = accel_series(tr, e.follower, tt, cfg.accel_smooth_s)
    tp = np.arange(t_ref - 1.0, e.t_centre + e.follower_after_s + 1e-9, dt)
    ap = accel_series(tr, e.follower, tp, cfg.accel_smooth_s)
    peak = float(np.nanmin(ap)) if np.any(np.isfinite(ap)) else float("nan")
    if not np.any(np.isfinite(base)):
        base_v = 0.0
    else:
        base_v = float(np.nanmean(base))
    below = np.nan_to_num(acc, nan=np.inf) < base_v - cfg.onset_drop
    hold = int(round(cfg.onset_hold_s / dt))
    for i in range(below.shape[0] - hold):
        if below[i:i + hold + 1].all():
            t_on = float(tt[i])
            if e.source == "us101":
                _, edge = overlap_series(tr, e.intruder, np.array([t_on]), e.lane_from, e.lane_to)
                return t_on, float(edge[0]) if np.isfinite(edge[0]) else None, peak
            return t_on, None, peak
    return None, None, peak


def control_fall_backs(tr: Tracks, events: list[CutIn], cfg: CutInConfig, lateral_measured: bool) -> np.ndarray:
    """Fall-back curves [M, len(TAUS)] of followers WITHOUT a cut-in: every vehicle every
    ``control_every_s`` that stays in its lane from 0.5 s before to ``horizon_s`` after, with a
    leader within ``max_gap``, and no vehicle entering its lane ahead of it within ``max_gap``
    between 2 s before and ``horizon_s`` after (the baseline noise of the measure)."""
    dt = tr.dt
    tab = tr.table
    step = max(int(round(cfg.control_every_s / dt)), 1)
    # Lane entries: (frame, lane, x) of every lane change in the table.
    entries = []
    for vid, sl in tr.rows.items():
        fr, ln, x = tr.frame[sl], tab.lane[sl], tab.x[sl]
        ch = np.flatnonzero((ln[1:] != ln[:-1]) & (fr[1:] == fr[:-1] + 1)) + 1
        entries += [(int(fr[j]), int(ln[j]), float(x[j]), vid) for j in ch]
    ent = np.array([(a, b, c) for a, b, c, _ in entries]) if entries else np.zeros((0, 3))
    n_h = int(round(cfg.horizon_s / dt))
    n_b = int(round(0.5 / dt))
    out = []
    for vid, sl in tr.rows.items():
        fr, ln, x = tr.frame[sl], tab.lane[sl], tab.x[sl]
        for j in range(n_b, fr.shape[0] - n_h, step):
            lane = ln[j]
            if np.any(ln[j - n_b:j + n_h + 1] != lane) or fr[j + n_h] - fr[j - n_b] != n_h + n_b:
                continue
            f = int(fr[j])
            lead = _nearest(tr, f, int(lane), float(x[j]), ahead=True, exclude={vid})
            if lead < 0:
                continue
            if float(tr.series(lead, "x", np.array([f * dt]))[0]) - float(x[j]) > cfg.max_gap:
                continue
            if ent.shape[0]:
                m = ((ent[:, 0] >= f - int(round(2.0 / dt))) & (ent[:, 0] <= f + n_h) & (ent[:, 1] == lane)
                     & (ent[:, 2] > x[j] - 5.0) & (ent[:, 2] < x[j] + cfg.max_gap))
                if m.any():
                    continue
            out.append(fall_back(tr, vid, f * dt))
    return np.asarray(out).reshape(-1, TAUS.shape[0])


def write_events(path: Path, cs: CutInSet, cfg: CutInConfig, provenance: dict) -> None:
    """The event list as ``nudge.cutins/1`` JSON (small; times in scene seconds)."""
    doc = {"schema": CUTINS_SCHEMA, "units": {"time": "s (scene time; I-80: Frame_ID * 0.1)", "gap": "m",
                                              "speed": "m/s", "time_headway": "s"},
           "definition": __doc__.strip().split("\n\n")[0].replace("\n", " "),
           "config": asdict(cfg), "provenance": provenance, "dropped": cs.dropped,
           "events": [asdict(e) for e in cs.events]}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=None, separators=(",", ":")).replace("},{", "},\n{") + "\n")


MAX_CUTINS_BYTES = 16 << 20
"""Largest cut-in file read (bytes): 500 times the shipped ``assets/worlds/cutins.json``."""


def _typed(path: Path, where: str, cls: type, doc: object) -> dict:
    """The keyword arguments of dataclass ``cls`` read from the JSON object ``doc`` (named
    ``where`` in errors): every field present, no other key, each value of the field's type
    (``str``; ``int`` exactly, not a bool; ``float`` a finite number; ``float | None``).

    Raises:
        ConfigError: naming the file and the item (``events[3].gap``).
    """
    if not isinstance(doc, dict):
        raise ConfigError(path, f"{where}: a JSON object expected, got {type(doc).__name__}", key=where)
    names = [f.name for f in fields(cls)]
    missing = [n for n in names if n not in doc]
    if missing:
        raise ConfigError(path, f"{where}: missing key(s) {', '.join(missing)}", key=where)
    unknown = sorted(set(doc) - set(names))
    if unknown:
        raise ConfigError(path, f"{where}: unknown key(s) {', '.join(unknown)}", key=where)
    for f in fields(cls):
        v, item, kind = doc[f.name], f"{where}.{f.name}", str(f.type)
        if kind == "str":
            ok = isinstance(v, str)
        elif kind == "int":
            ok = isinstance(v, int) and not isinstance(v, bool)
            if not ok:
                raise ConfigError(path, f"{item}: {v!r} is not an integer", key=item)
        else:
            if v is None and "None" in kind:
                continue
            ok = isinstance(v, (int, float)) and not isinstance(v, bool)
            if not ok:
                raise ConfigError(path, f"{item}: {v!r} is not a number", key=item)
            ok = math.isfinite(v)
            if not ok:
                raise ConfigError(path, f"{item}: {v!r} is not a finite number", key=item)
        if not ok:
            raise ConfigError(path, f"{item}: {v!r} is not a {kind}", key=item)
    return dict(doc)


def _cutins_doc(path: Path) -> dict:
    """The checked top level of a ``nudge.cutins/1`` file (checked open, schema)."""
    path = Path(path)
    doc = load_json(path, max_bytes=MAX_CUTINS_BYTES)
    if not isinstance(doc, dict):
        raise ConfigError(path, "a JSON object expected at the top level")
    if doc.get("schema") != CUTINS_SCHEMA:
        raise ConfigError(path, f"schema {doc.get('schema')!r}, expected {CUTINS_SCHEMA!r}", key="schema")
    return doc


def read_events(path: Path) -> list[CutIn]:
    """Events of a ``nudge.cutins/1`` file: opened by the checked open (a regular file of at most
    :data:`MAX_CUTINS_BYTES`), every event an object with exactly the :class:`CutIn` fields,
    integers where integers are due and finite numbers elsewhere.

    Raises:
        ConfigError: naming the file and the item (``events[3].gap``); a wrong schema included.
    """
    doc = _cutins_doc(path)
    events = doc.get("events")
    if not isinstance(events, list):
        raise ConfigError(path, f"events: a list expected, got {type(events).__name__}", key="events")
    return [CutIn(**_typed(Path(path), f"events[{i}]", CutIn, e)) for i, e in enumerate(events)]


def read_config(path: Path) -> CutInConfig:
    """The detection settings a ``nudge.cutins/1`` file was made with (its ``config``), checked
    as :func:`read_events` checks the events."""
    doc = _cutins_doc(path)
    return CutInConfig(**_typed(Path(path), "config", CutInConfig, doc.get("config")))
