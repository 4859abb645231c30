"""Reader for CommonRoad scenario XML (2020a ``dynamicObstacle`` and 2018b ``obstacle``/``role``).

Produces a :class:`TrackTable` in a road frame: the scene is rotated so traffic runs along +x
(direction fitted to the lanelet boundaries), y positive left, then either mapped to arclength and
offset along a spline reference path (frame ``frenet``, the default, :mod:`nudge_train.data.frenet`)
or straightened along a fitted polynomial (frame ``straightened``, the older frame). Lanes come from the
lanelet boundaries (order by lateral position); lanelets that start or end inside the scene
(on-ramps, lane drops) give per-x pieces of the lane map, and in the ``frenet`` frame every lane
also carries its extent along s.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from xml.parsers import expat
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from nudge_train.constants import DEFAULT_ROAD_FRAME, ROAD_FRAMES

from .errors import DataError, read_source
from .frenet import FrameRefusal, FrenetConfig, ReferencePath, check_offsets, fit_reference, lane_extents
from .raw import FieldRule, number
from .tracks import LaneMap, TrackTable, lane_index_from_left, sort_and_check

FRAMES = ROAD_FRAMES
"""Road frames of the reader (:data:`nudge_train.constants.ROAD_FRAMES`): ``frenet`` (the default:
the curvilinear frame of :mod:`nudge_train.data.frenet`, exact projection, lanes with extents) and
``straightened`` (one rotation and a first-order straightening along a fitted curve; the frame of
the ten scenarios in ``assets/scenes``)."""


_LINE = "\x00line"
"""Attribute under which the parser records each element's 1-based line (internal)."""

COORD = FieldRule(-1e5, 1e5, "m")
"""Lanelet points and vehicle positions (m): a scene spans a few hundred metres."""
ORIENTATION = FieldRule(-4 * math.pi, 4 * math.pi, "rad")
VELOCITY = FieldRule(-300.0, 300.0, "m/s")
SIZE = FieldRule(0.0, 100.0, "m", lo_open=True)
TIME_STEP = FieldRule(0.0, 1e7, integer=True)
OBSTACLE_ID = FieldRule(0.0, 1e9, integer=True)
STEP_SIZE = FieldRule(0.0, 60.0, "s", lo_open=True)


MAX_XML_BYTES = 32 << 20
"""Largest CommonRoad document read (bytes, after decompression): 12 times the largest US-101
scene (2.6 MB); the Rust reader's ``nudge::commonroad::xml::MAX_XML_BYTES``."""
MAX_XML_DEPTH = 64
"""Deepest element nesting read (levels, the root is 1); CommonRoad nests 7 deep."""
MAX_XML_ELEMENTS = 1_000_000
"""Most elements read in one document: 13 times the largest US-101 scene (76,753)."""
MAX_XML_ATTRIBUTES = 64
"""Most attributes of one element (CommonRoad's carry at most 7)."""


def _parse_xml(path: Path) -> ET.Element:
    """The element tree of the file, each element carrying its line number (expat's position).

    Budgets (each refusal a DataError naming the file and the budget): :data:`MAX_XML_BYTES`
    after decompression, :data:`MAX_XML_DEPTH` levels, :data:`MAX_XML_ELEMENTS` elements.
    Entities declared in a DTD are refused (the Rust reader does not expand them either);
    character references and the predefined entities are decoded by expat.
    """
    data = read_source(path, max_bytes=MAX_XML_BYTES)
    if not data.strip():
        raise DataError(path, "empty file")
    parser = expat.ParserCreate()
    builder = ET.TreeBuilder()
    depth = [0, 0]  # open elements, elements seen

    def start(tag: str, attrs: dict[str, object]) -> None:
        depth[0] += 1
        depth[1] += 1
        if depth[0] > MAX_XML_DEPTH:
            raise DataError(path, f"exceeds the nesting-depth budget of {MAX_XML_DEPTH} levels",
                            row=parser.CurrentLineNumber)
        if depth[1] > MAX_XML_ELEMENTS:
            raise DataError(path, f"exceeds the element-count budget of {MAX_XML_ELEMENTS} elements",
                            row=parser.CurrentLineNumber)
        if len(attrs) > MAX_XML_ATTRIBUTES:
            raise DataError(path, f"exceeds the attributes-per-element budget of {MAX_XML_ATTRIBUTES}",
                            row=parser.CurrentLineNumber)
        attrs[_LINE] = parser.CurrentLineNumber
        builder.start(tag, attrs)  # type: ignore[arg-type]

    def end(tag: str) -> None:
        depth[0] -= 1
        builder.end(tag)

    def entity_decl(name: str, *_: object) -> None:
        raise DataError(path, f"entity {name!r} declared in a DTD: not read (only character references "
                        "and the predefined entities are)", row=parser.CurrentLineNumber)

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = builder.data
    parser.EntityDeclHandler = entity_decl
    parser.buffer_text = True
    try:
        parser.Parse(data, True)
    except expat.ExpatError as exc:
        raise DataError(path, f"not valid XML: {expat.errors.messages[exc.code]} (column {exc.offset})",
                        row=exc.lineno) from None
    return builder.close()


def _line(*elems: ET.Element | None) -> int | None:
    """Line of the first element given that exists."""
    for e in elems:
        if e is not None:
            return int(e.get(_LINE))  # type: ignore[arg-type]
    return None


def _num(elem: ET.Element | None, path: Path, what: str, rule: FieldRule, parent: ET.Element | None = None,
         field: str | None = None) -> float:
    """The number in ``elem`` (named ``what`` in errors), checked against ``rule``."""
    field = field or what.split()[-1]
    row = _line(elem, parent)
    if elem is None or elem.text is None:
        raise DataError(path, f"missing {what}", row=row, field=field)
    tok = elem.text.strip()
    v = number(tok)
    if v is None:
        raise DataError(path, f"{what} is not a number: {elem.text!r}", row=row, field=field)
    if not math.isfinite(v):
        raise DataError(path, f"{what} is not finite: {tok!r}", row=row, field=field)
    why = rule.problem(what, tok, v)
    if why is not None:
        raise DataError(path, why, row=row, field=field)
    return v


def _integer(path: Path, tok: str, what: str, rule: FieldRule, row: int | None, field: str) -> int:
    """The integer written ``tok`` (named ``what`` in errors), checked against ``rule``."""
    v = number(tok)
    if v is None or not math.isfinite(v):
        raise DataError(path, f"{what} {tok!r} is not an integer", row=row, field=field)
    why = rule.problem(what, tok, v)
    if why is not None:
        raise DataError(path, why, row=row, field=field)
    return int(v)


def _points(bound: ET.Element | None, path: Path, lid: str, parent: ET.Element) -> np.ndarray:
    if bound is None:
        raise DataError(path, f"lanelet {lid}: missing bound", row=_line(parent))
    pts = [(_num(p.find("x"), path, f"lanelet {lid} x", COORD, p),
            _num(p.find("y"), path, f"lanelet {lid} y", COORD, p)) for p in bound.findall("point")]
    if len(pts) < 2:
        raise DataError(path, f"lanelet {lid}: bound with fewer than 2 points", row=_line(bound))
    return np.asarray(pts, dtype=np.float64)


def _rot(points: np.ndarray, theta: float) -> np.ndarray:
    """Rotate points [N, 2] by -theta (so direction theta maps to +x)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.stack([c * points[:, 0] + s * points[:, 1], -s * points[:, 0] + c * points[:, 1]], axis=1)


def _interp_bound(poly: np.ndarray, x: np.ndarray) -> np.ndarray:
    order = np.argsort(poly[:, 0], kind="stable")
    return np.interp(x, poly[order, 0], poly[order, 1])


@dataclass(frozen=True)
class RoadCurve:
    """Gentle road curvature in the rotated frame: centre-line shape y = a1 x + a2 x^2 (+ a3 x^3).

    US-101 bends with a radius of about 1.7 km, so a single rotation leaves lane boundaries up to
    3 m off y = const over 200 m. The road frame is therefore *straightened*: x = arc length along
    the fitted shape, y = perpendicular offset from it. Lanes then are lines y = const (residuals
    are reported per scene in LaneMap.straightness_m). Fitted on every lanelet boundary with a
    per-boundary offset; boundaries that do not follow the road (ramp tapers) are rejected
    iteratively (residual > 0.3 m).
    """

    coef: tuple[float, ...]  # polynomial coefficients, highest power first, constant 0
    x0: float
    x1: float

    @staticmethod
    def fit(lanelets: list[tuple[np.ndarray, np.ndarray]]) -> "RoadCurve":
        polys = [p for l, r in lanelets for p in (l, r) if np.ptp(p[:, 0]) > 20.0]
        if not polys:
            polys = [p for l, r in lanelets for p in (l, r)]
        xs_all = np.concatenate([p[:, 0] for p in polys])
        x0, x1 = float(xs_all.min()), float(xs_all.max())
        scale = max(abs(x0), abs(x1), 1.0)
        keep = list(range(len(polys)))
        deg = 3 if (x1 - x0) > 150 else 2
        coef = np.zeros(deg + 1)
        for _ in range(4):
            rows, rhs = [], []
            for k, i in enumerate(keep):
                p = polys[i]
                u = p[:, 0] / scale
                a = np.zeros((len(p), deg + len(keep)))
                for d in range(1, deg + 1):
                    a[:, d - 1] = u ** d
                a[:, deg + k] = 1.0
                rows.append(a)
                rhs.append(p[:, 1])
            sol = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]
            shape = sol[:deg]
            new_keep = []
            for k, i in enumerate(keep):
                p = polys[i]
                u = p[:, 0] / scale
                pred = sum(shape[d - 1] * u ** d for d in range(1, deg + 1)) + sol[deg + k]
                if np.max(np.abs(p[:, 1] - pred)) <= 0.3:
                    new_keep.append(i)
            coef = np.array([shape[d - 1] / scale ** d for d in range(deg, 0, -1)] + [0.0])
            if len(new_keep) == len(keep) or len(new_keep) < 2:
                break
            keep = new_keep
        return RoadCurve(coef=tuple(float(c) for c in coef), x0=x0 - 50.0, x1=x1 + 50.0)

    def _grid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        g = np.linspace(self.x0 - 200.0, self.x1 + 200.0, 4001)
        fy = np.polyval(self.coef, g)
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(g), np.diff(fy)))])
        arc -= np.interp(0.0, g, arc)
        return g, fy, arc

    def tangent_angle(self, x: np.ndarray) -> np.ndarray:
        """Angle (rad) of the road direction at rotated-frame x [N] (m)."""
        return np.arctan(np.polyval(np.polyder(np.asarray(self.coef)), x))

    def to_road(self, pts: np.ndarray) -> np.ndarray:
        """Rotated-frame points [N, 2] (m) -> straightened road frame [N, 2] (m)."""
        g, _, arc = self._grid()
        x = pts[:, 0]
        ang = self.tangent_angle(x)
        dy = pts[:, 1] - np.polyval(self.coef, x)
        # Perpendicular offset d = dy cos(a); the point is foot + d (-sin a, cos a), so the foot
        # lies at x + d sin(a) (first order in the curvature).
        y_road = dy * np.cos(ang)
        x_foot = x + dy * np.sin(ang) * np.cos(ang)
        return np.stack([np.interp(x_foot, g, arc), y_road], axis=1)


def _lane_map(lanelets: list[tuple[np.ndarray, np.ndarray]], path: Path,
              names: list[tuple[str, int | None]]) -> LaneMap:
    """Build the straight lane map from rotated lanelets [(left [P,2], right [Q,2])] named
    ``names`` [(id, line)].

    Raises DataError when a lanelet's left bound is not left of its right bound, or the lanelets
    give lane boundaries that are not strictly ascending (overlapping or inverted lanes)."""
    # Breakpoints: where a lanelet starts or ends.
    extents = [(min(l[:, 0].min(), r[:, 0].min()), max(l[:, 0].max(), r[:, 0].max())) for l, r in lanelets]
    xs = sorted({round(v, 3) for e in extents for v in e})
    pieces: list[tuple[float, float, np.ndarray]] = []
    worst = 0.0
    for x0, x1 in zip(xs[:-1], xs[1:]):
        if x1 - x0 < 1.0:
            continue
        mid = 0.5 * (x0 + x1)
        present = [i for i, (a, b) in enumerate(extents) if a <= mid + 1e-6 and b >= mid - 1e-6]
        if not present:
            continue
        grid = np.linspace(x0, x1, 9)
        rows = []
        for i in present:
            left, right = lanelets[i]
            yl = _interp_bound(left, grid)
            yr = _interp_bound(right, grid)
            worst = max(worst, float(np.ptp(yl)) / 2, float(np.ptp(yr)) / 2)
            if not np.mean(yl) > np.mean(yr):
                lid, line = names[i]
                raise DataError(path, f"lanelet {lid}: left bound is not left of the right bound over "
                                f"x {x0:.1f}..{x1:.1f} m (road frame)", row=line, field="leftBound")
            rows.append((float(np.mean(yr)), float(np.mean(yl))))
        rows.sort()
        # Lanelets that overlap laterally at this x (e.g. successor pieces) are merged.
        merged: list[list[float]] = []
        for r, lft in rows:
            if merged and r < merged[-1][1] - 0.5:
                merged[-1][1] = max(merged[-1][1], lft)
                continue
            merged.append([r, lft])
        b = [merged[0][0]]
        for k in range(len(merged) - 1):
            b.append(0.5 * (merged[k][1] + merged[k + 1][0]))
        b.append(merged[-1][1])
        if any(hi <= lo for lo, hi in zip(b[:-1], b[1:])):
            raise DataError(path, f"lanelets give overlapping or inverted lanes over x {x0:.1f}..{x1:.1f} m "
                            f"(boundaries {', '.join(f'{v:.2f}' for v in b)} m are not ascending)", field="lanelet")
        pieces.append((x0, x1, np.asarray(b, dtype=np.float64)))
    if not pieces:
        raise DataError(path, "lanelet map has no lanes")
    # Merge neighbouring pieces with the same lanes (same count, boundaries within 0.2 m).
    merged_pieces: list[tuple[float, float, np.ndarray]] = [pieces[0]]
    for x0, x1, b in pieces[1:]:
        px0, px1, pb = merged_pieces[-1]
        if pb.shape == b.shape and np.max(np.abs(pb - b)) < 0.2 and abs(px1 - x0) < 1.5:
            merged_pieces[-1] = (px0, x1, pb)
        else:
            merged_pieces.append((x0, x1, b))
    widest = max(merged_pieces, key=lambda p: (p[1] - p[0]))
    polylines = []
    for left, right in lanelets:
        for p in (left, right):
            o = np.argsort(p[:, 0], kind="stable")
            polylines.append(p[o])
    return LaneMap(bounds=widest[2], x_range=(xs[0], xs[-1]), straightness_m=worst,
                   pieces=tuple(merged_pieces), polylines=tuple(polylines))


def lane_chains(names: list[tuple[str, int | None]], successors: list[list[str]]) -> list[list[int]]:
    """Lanelets joined along the road into lanes: chains following each lanelet's first
    successor, from every lanelet that is no lanelet's successor (indices into ``names``)."""
    index = {lid: i for i, (lid, _) in enumerate(names)}
    is_successor = {index[r] for succ in successors for r in succ if r in index}
    chains: list[list[int]] = []
    used: set[int] = set()
    for start in [i for i in range(len(names)) if i not in is_successor] + list(range(len(names))):
        if start in used:
            continue
        chain, i = [], start
        while i is not None and i not in used:
            chain.append(i)
            used.add(i)
            nxt = [index[r] for r in successors[i] if r in index]
            i = nxt[0] if nxt else None
        chains.append(chain)
    return chains


def _clip_sd(poly: np.ndarray, a: float, b: float) -> np.ndarray:
    """The part of an (s, d) polyline [P, 2] (s ascending) over a <= s <= b, with points
    interpolated at a and b (both within the polyline's s range)."""
    inner = poly[(poly[:, 0] > a) & (poly[:, 0] < b)]
    d_ab = np.interp([a, b], poly[:, 0], poly[:, 1])
    return np.concatenate([[[a, d_ab[0]]], inner, [[b, d_ab[1]]]])


def _frenet_lane_map(ref: ReferencePath, raw_lanelets: list[tuple[np.ndarray, np.ndarray]],
                     names: list[tuple[str, int | None]], successors: list[list[str]], path: Path,
                     cfg: FrenetConfig) -> LaneMap:
    """The lane map in the curvilinear frame: lanelet bounds projected to (s, d), lanelets joined
    into lanes (:func:`lane_chains`), each lane's extent on the carriageway
    (:func:`~nudge_train.data.frenet.lane_extents`), lanelets cut to their lane's extent, then the
    per-s pieces of :func:`_lane_map`; ``lanes`` holds the extents.

    Raises:
        FrameRefusal: a bound off the path, or lanes deviating from d = const by more than
        ``cfg.max_residual_m`` within their extent.
    """
    sd = []
    for left, right in raw_lanelets:
        pair = []
        for bound in (left, right):
            s, d, u = ref.project(bound)
            check_offsets(ref, u, d, cfg)
            o = np.argsort(s, kind="stable")
            pair.append(np.stack([s[o], d[o]], axis=1))
        sd.append((pair[0], pair[1]))
    chains = lane_chains(names, successors)
    chain_bounds = [(np.concatenate([sd[i][0] for i in ch]), np.concatenate([sd[i][1] for i in ch])) for ch in chains]
    extents = lane_extents(chain_bounds, cfg)
    kept: list[tuple[np.ndarray, np.ndarray]] = []
    kept_names: list[tuple[str, int | None]] = []
    for ch, (cl, cr_), ext in zip(chains, chain_bounds, extents):
        start = min(cl[:, 0].min(), cr_[:, 0].min())
        stop = max(cl[:, 0].max(), cr_[:, 0].max())
        a = ext.s_begin if ext.s_begin > start + cfg.lane_step_m else -math.inf
        b = ext.s_end if ext.s_end < stop - cfg.lane_step_m else math.inf
        for i in ch:
            left, right = sd[i]
            if a == -math.inf and b == math.inf:
                kept.append((left, right))
                kept_names.append(names[i])
                continue
            lo = max(a, left[0, 0], right[0, 0])
            hi = min(b, left[-1, 0], right[-1, 0])
            if hi - lo < 1.0:
                continue
            kept.append((_clip_sd(left, lo, hi), _clip_sd(right, lo, hi)))
            kept_names.append(names[i])
    if not kept:
        raise FrameRefusal("no lane lies on the carriageway")
    lanes = _lane_map(kept, path, kept_names)
    if lanes.straightness_m > cfg.max_residual_m:
        raise FrameRefusal(f"lane boundaries deviate up to {lanes.straightness_m:.2f} m from d = const within "
                           f"their extents (at most {cfg.max_residual_m:g} m)")
    return replace(lanes, lanes=tuple(extents))


def read_commonroad(path: Path | str, frame: str = DEFAULT_ROAD_FRAME, frenet: FrenetConfig | None = None) -> TrackTable:
    """Read one CommonRoad scenario (.xml or .xml.gz, format 2020a or 2018b) into a TrackTable in
    the road frame ``frame`` (one of :data:`FRAMES`; ``frenet`` uses ``frenet`` or its defaults).

    Raises DataError (naming the file) for an unknown format, missing fields, non-finite
    values, a scene without lanelets or without dynamic obstacles, non-monotonic time, or (frame
    ``frenet``) a scene whose geometry the curvilinear frame cannot represent, saying why.
    """
    if frame not in FRAMES:
        raise ValueError(f"unknown road frame {frame!r} (one of {', '.join(FRAMES)})")
    path = Path(path)
    root = _parse_xml(path)
    if root.tag != "commonRoad":
        raise DataError(path, f"unknown layout: root element <{root.tag}>, expected <commonRoad>")
    version = root.get("commonRoadVersion", "")
    if version not in ("2020a", "2018b"):
        raise DataError(path, f"unknown CommonRoad version {version!r} (supported: 2020a, 2018b)",
                        field="commonRoadVersion")
    dt_tok = str(root.get("timeStepSize", "")).strip()
    dt = number(dt_tok)
    if dt is None or not math.isfinite(dt) or STEP_SIZE.problem("timeStepSize", dt_tok, dt) is not None:
        raise DataError(path, f"missing or invalid timeStepSize {dt_tok!r} (expected a number in (0, 60] s)",
                        field="timeStepSize")
    scene = root.get("benchmarkID") or path.name.split(".")[0]

    raw_lanelets = []
    names: list[tuple[str, int | None]] = []
    successors: list[list[str]] = []
    for ll in root.findall("lanelet"):
        lid = ll.get("id", "?")
        names.append((str(lid), _line(ll)))
        successors.append([str(e.get("ref")) for e in ll.findall("successor")])
        raw_lanelets.append((_points(ll.find("leftBound"), path, lid, ll),
                             _points(ll.find("rightBound"), path, lid, ll)))
    if not raw_lanelets:
        raise DataError(path, "no <lanelet> elements: no lane map")

    # Travel direction: mean direction of all bounds (first -> last point), length weighted.
    d = np.zeros(2)
    for left, right in raw_lanelets:
        d += left[-1] - left[0]
        d += right[-1] - right[0]
    theta = math.atan2(d[1], d[0])
    # Refine with a least-squares slope of every bound in the provisional frame.
    slopes, weights = [], []
    for left, right in raw_lanelets:
        for poly in (left, right):
            p = _rot(poly, theta)
            span = np.ptp(p[:, 0])
            if span > 5.0:
                A = np.stack([p[:, 0] - p[:, 0].mean(), np.ones(len(p))], axis=1)
                slope = np.linalg.lstsq(A, p[:, 1], rcond=None)[0][0]
                slopes.append(slope)
                weights.append(span)
    if slopes:
        theta += math.atan(float(np.average(slopes, weights=weights)))
    rot_lanelets = [(_rot(l, theta), _rot(r, theta)) for l, r in raw_lanelets]
    if frame == "frenet":
        fcfg = (frenet or FrenetConfig()).validate()
        try:
            ref = ReferencePath.build(theta, fit_reference(rot_lanelets, fcfg), fcfg)
            lanes = _frenet_lane_map(ref, raw_lanelets, names, successors, path, fcfg)
        except FrameRefusal as exc:
            raise DataError(path, f"scene {scene} cannot be represented in the curvilinear road frame: {exc}") \
                from None
    else:
        road = RoadCurve.fit(rot_lanelets)
        lanelets = [(road.to_road(l), road.to_road(r)) for l, r in rot_lanelets]
        lanes = _lane_map(lanelets, path, names)

    if version == "2020a":
        obstacles = root.findall("dynamicObstacle")
    else:
        obstacles = [o for o in root.findall("obstacle") if (o.findtext("role") or "").strip() == "dynamic"]
    if not obstacles:
        raise DataError(path, "no dynamic obstacles (vehicles) in the scene")

    cols: dict[str, list[float]] = {k: [] for k in ("vehicle", "step", "x", "y", "heading", "speed", "length", "width")}
    seen: dict[int, int] = {}
    for ob in obstacles:
        row = _line(ob)
        oid = _integer(path, str(ob.get("id", "")).strip(), "obstacle id", OBSTACLE_ID, row, "id")
        if oid in seen:
            raise DataError(path, f"obstacle id {oid} appears twice (first at row {seen[oid]})", row=row, field="id")
        seen[oid] = row or 0
        rect = ob.find("shape/rectangle")
        if rect is None:
            raise DataError(path, f"obstacle {oid}: no rectangle shape", row=row, field="shape")
        length = _num(rect.find("length"), path, f"obstacle {oid} length", SIZE, rect)
        width = _num(rect.find("width"), path, f"obstacle {oid} width", SIZE, rect)
        states = [ob.find("initialState")] + ob.findall("trajectory/state")
        if states[0] is None:
            raise DataError(path, f"obstacle {oid}: no initialState", row=row, field="initialState")
        last = -1
        for st in states:
            assert st is not None
            te = st.find("time/exact")
            if te is None or te.text is None:
                raise DataError(path, f"missing obstacle {oid} time", row=_line(st), field="time")
            step = _integer(path, te.text.strip(), f"obstacle {oid} time step", TIME_STEP, _line(te), "time")
            if step <= last:
                raise DataError(path, f"obstacle {oid}: non-monotonic time (step {step} after {last})",
                                row=_line(te, st), field="time")
            last = step
            pt = st.find("position/point")
            at = pt if pt is not None else st
            x = _num(at.find("x") if pt is not None else None, path, f"obstacle {oid} step {step} x", COORD, at)
            y = _num(at.find("y") if pt is not None else None, path, f"obstacle {oid} step {step} y", COORD, at)
            cols["vehicle"].append(oid)
            cols["step"].append(step)
            cols["x"].append(x)
            cols["y"].append(y)
            cols["heading"].append(_num(st.find("orientation/exact"), path, f"obstacle {oid} step {step} orientation",
                                        ORIENTATION, st))
            cols["speed"].append(_num(st.find("velocity/exact"), path, f"obstacle {oid} step {step} velocity",
                                      VELOCITY, st))
            cols["length"].append(length)
            cols["width"].append(width)
    world = np.stack([np.asarray(cols["x"]), np.asarray(cols["y"])], axis=1)
    if frame == "frenet":
        try:
            x, y, u = ref.project(world)
            check_offsets(ref, u, y, fcfg)
        except FrameRefusal as exc:
            raise DataError(path, f"scene {scene} cannot be represented in the curvilinear road frame: {exc}") \
                from None
        heading = np.asarray(cols["heading"]) - ref.tangent_angle(u)
    else:
        xy_rot = _rot(world, theta)
        xy = road.to_road(xy_rot)
        heading = np.asarray(cols["heading"]) - theta - road.tangent_angle(xy_rot[:, 0])
        x = xy[:, 0]
        y = xy[:, 1]
    heading = (heading + math.pi) % (2 * math.pi) - math.pi
    # Lane index (from the left) with the lane-map piece covering each row's x, or the nearest
    # piece for rows outside every piece.
    x0s = np.asarray([p[0] for p in lanes.pieces])
    x1s = np.asarray([p[1] for p in lanes.pieces])
    dist = np.maximum(x0s[None, :] - x[:, None], 0.0) + np.maximum(x[:, None] - x1s[None, :], 0.0)
    piece = np.argmin(dist, axis=1)
    lane = np.empty(x.shape[0], dtype=np.int64)
    for k, (_, _, b) in enumerate(lanes.pieces):
        m = piece == k
        lane[m] = lane_index_from_left(y[m], b)
    n = x.shape[0]
    table = TrackTable(
        scene=scene, source=path.name,
        vehicle=np.asarray(cols["vehicle"], dtype=np.int64),
        t=np.asarray(cols["step"], dtype=np.float64) * dt,
        x=x, y=y, heading=heading, speed=np.asarray(cols["speed"], dtype=np.float64),
        length=np.asarray(cols["length"], dtype=np.float64), width=np.asarray(cols["width"], dtype=np.float64),
        lane=lane, flags=np.zeros(n, dtype=np.int64), lanes=lanes, dt=dt,
        notes={"rotation_mrad": int(round(theta * 1000)),
               "lane_straightness_cm": int(round(lanes.straightness_m * 100)),
               **({"lanes_beginning": int(sum(bool(ln.begins) for ln in lanes.lanes)),
                   "lanes_ending": int(sum(bool(ln.ends) for ln in lanes.lanes))} if frame == "frenet" else {})},
    )
    return sort_and_check(table)
