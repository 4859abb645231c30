"""The curvilinear (Frenet) road frame: the exact projection against brute force and quadrature,
lanes that begin and end against the raw lanelet geometry, refusals as DataErrors, and the
straight-scene regression (a straight road gives the same windows and scenarios as the
straightened frame, within 1 mm)."""

from __future__ import annotations

import gzip
import math
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from nudge_train import paths
from nudge_train.data.commonroad import _parse_xml, _points, _rot, read_commonroad
from nudge_train.data.errors import DataError
from nudge_train.data.frenet import FrameRefusal, FrenetConfig, ReferencePath, fit_reference
from nudge_train.data.grid import build_grid
from nudge_train.data.scenarios import ScenarioConfig, scene_scenarios
from nudge_train.data.sources import US101_DIRS
from nudge_train.data.windows import WindowConfig, extract_windows

FIX = Path(__file__).parent / "fixtures" / "commonroad"
SHARED = paths.ngsim()


def _curved_path(radius: float = 1000.0, theta: float = 0.3) -> tuple[ReferencePath, list]:
    """A reference path fitted to three concentric arcs (lane boundaries of a road bending left,
    radius 1 km over 200 m; US-101 bends with about 1.7 km)."""
    phi = np.linspace(-0.1, 0.1, 120)
    bounds = []
    for off in (0.0, 3.5, 7.0):
        r = radius - off
        pts = np.stack([r * np.sin(phi), radius - r * np.cos(phi)], axis=1)
        bounds.append(pts)
    cfg = FrenetConfig()
    lanelets = [(bounds[1], bounds[0]), (bounds[2], bounds[1])]
    path = ReferencePath.build(theta, fit_reference(lanelets, cfg), cfg)
    return path, lanelets


def test_projection_is_the_nearest_point_of_the_path() -> None:
    path, _ = _curved_path()
    rng = np.random.default_rng(0)
    c, s_ = math.cos(path.theta), math.sin(path.theta)
    local = np.stack([rng.uniform(-100, 100, 200), rng.uniform(-15, 15, 200)], axis=1)
    world = np.stack([c * local[:, 0] - s_ * local[:, 1], s_ * local[:, 0] + c * local[:, 1]], axis=1)
    s, d, u = path.project(world)
    # Independent truth: brute-force nearest point on a 1 cm sampling of the curve.
    grid = np.arange(path.x_lo + 1, path.x_hi - 1, 0.01)
    curve = np.stack([grid, path.shape(grid)], axis=1)
    curve_w = np.stack([c * curve[:, 0] - s_ * curve[:, 1], s_ * curve[:, 0] + c * curve[:, 1]], axis=1)
    for i in range(0, 200, 7):
        dist = np.linalg.norm(curve_w - world[i], axis=1)
        j = int(np.argmin(dist))
        assert abs(abs(d[i]) - dist[j]) < 1e-4, (i, d[i], dist[j])
        assert abs(u[i] - grid[j]) < 0.02
        # Sign: left of the tangent is positive.
        t = np.asarray([1.0, path.shape(grid[j], 1)])
        t_w = np.asarray([c * t[0] - s_ * t[1], s_ * t[0] + c * t[1]])
        cross = t_w[0] * (world[i, 1] - curve_w[j, 1]) - t_w[1] * (world[i, 0] - curve_w[j, 0])
        assert np.sign(cross) == np.sign(d[i])
    # Arclength against adaptive quadrature of |c'(u)|.
    for i in range(0, 200, 23):
        ref = quad(lambda x: math.sqrt(1.0 + float(path.shape(x, 1)) ** 2), 0.0, float(u[i]), limit=200)[0]
        assert abs(s[i] - ref) < 1e-5  # the table is linear between 0.25 m samples: O(h^2 s'')
    # And the inverse map returns the points.
    back = path.to_world(s, d)
    assert np.max(np.abs(back - world)) < 1e-6


def test_reference_path_follows_curved_lanes() -> None:
    """Arcs of radius 1 km: every boundary at constant d, lanes 3.5 m apart, within 2 cm (the fit
    offsets boundaries vertically in the rotated frame, not along the normal: an error of about
    offset * (1 / cos(slope) - 1), 1.8 cm for 7 m at slope 0.1)."""
    path, lanelets = _curved_path()
    c, s_ = math.cos(path.theta), math.sin(path.theta)
    ds = []
    for left, right in lanelets:
        for b in (left, right):
            w = np.stack([c * b[:, 0] - s_ * b[:, 1], s_ * b[:, 0] + c * b[:, 1]], axis=1)
            _, d, _ = path.project(w)
            assert np.ptp(d) < 0.02
            ds.append(float(np.mean(d)))
    assert abs(abs(ds[0] - ds[1]) - 3.5) < 0.02


def test_points_off_the_path_are_refused() -> None:
    path, _ = _curved_path()
    far = path.to_world(np.asarray([0.0]), np.asarray([0.0])) + np.asarray([[5000.0, 0.0]])
    with pytest.raises(FrameRefusal, match="beyond the ends of the reference path"):
        path.project(far)


def _turning_copy(f: Path) -> None:
    """Fixture scene 1 with its lanes bent into a quarter circle and more (radius 60 m), as ``f``."""
    root = ET.fromstring(gzip.decompress((FIX / "USA_US101-1_1_T-1.xml.gz").read_bytes()))
    for ll in root.findall("lanelet"):
        for tag in ("leftBound", "rightBound"):
            pts = ll.find(tag).findall("point")  # type: ignore[union-attr]
            n = len(pts)
            for k, p in enumerate(pts):
                a = -0.8 + 2.4 * k / max(n - 1, 1)  # a quarter circle and more, radius 60 m
                r = 60.0 + (3.5 if tag == "leftBound" else 0.0) + 3.5 * int(ll.get("id", "0")) % 7
                p.find("x").text = f"{r * math.sin(a):.4f}"  # type: ignore[union-attr]
                p.find("y").text = f"{60.0 - r * math.cos(a):.4f}"  # type: ignore[union-attr]
    f.write_bytes(gzip.compress(ET.tostring(root)))


def test_a_turning_road_is_refused_naming_the_scene(tmp_path: Path) -> None:
    """A scene whose lanes turn by 90 degrees: the frame refuses it, naming the file and why."""
    f = tmp_path / "USA_US101-1_1_T-1.xml.gz"
    _turning_copy(f)
    with pytest.raises(DataError) as exc:
        read_commonroad(f, frame="frenet")
    msg = str(exc.value)
    assert str(f) in msg and "USA_US101-1_1_T-1 cannot be represented in the curvilinear road frame" in msg


def test_data_build_refuses_the_turning_scene_by_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """data build and data scenes (curvilinear frame by default) stop with exit status 2 and the
    DataError naming the file, the scene and why; no traceback."""
    import shutil

    from nudge_train.cli import main

    root = tmp_path / "ngsim"
    a = root / US101_DIRS[0]
    a.mkdir(parents=True)
    _turning_copy(a / "USA_US101-1_1_T-1.xml.gz")
    shutil.copy(FIX / "USA_US101-26_1_T-1_cut.xml.gz", a)
    shutil.copy(FIX.parent / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    for argv in (["data", "build", "--out", str(tmp_path / "p"), "--no-i80"],
                 ["data", "scenes", "--split", "test", "--out", str(tmp_path / "s")]):
        assert main([*argv, "--data-root", str(root), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and str(a / "USA_US101-1_1_T-1.xml.gz") in err
        assert "USA_US101-1_1_T-1 cannot be represented in the curvilinear road frame" in err and "turns by" in err


def test_unknown_frame_is_rejected() -> None:
    with pytest.raises(ValueError, match="unknown road frame"):
        read_commonroad(FIX / "USA_US101-1_1_T-1.xml.gz", frame="curvy")


def test_exit_lane_ends_where_it_separates_from_the_road() -> None:
    """Scene 7: the sixth (auxiliary) lane leaves the road downstream. Its extent ends where its
    inner boundary, projected from the raw lanelets, is farther than the gore gap from the
    neighbouring lane's boundary; vehicles beyond are no longer in an ending lane."""
    cfg = FrenetConfig()
    table = read_commonroad(FIX / "USA_US101-7_1_T-1_cut.xml.gz", frame="frenet")
    ending = [ln for ln in table.lanes.lanes if ln.ends]
    assert len(ending) == 1
    lane = ending[0]
    assert table.notes["lanes_ending"] == 1
    # Independent check on the raw geometry: rebuild the path and project the lanelets.
    root = _parse_xml(FIX / "USA_US101-7_1_T-1_cut.xml.gz")
    raw = [(_points(ll.find("leftBound"), FIX, "", ll), _points(ll.find("rightBound"), FIX, "", ll))
           for ll in root.findall("lanelet")]
    theta = table.notes["rotation_mrad"] / 1000.0
    # (theta is rounded in the notes: the path below differs from the reader's by < 1 mrad)
    path = ReferencePath.build(theta, fit_reference([(_rot(l, theta), _rot(r, theta)) for l, r in raw], cfg), cfg)
    projected = []
    for left, right in raw:
        sl, dl, _ = path.project(left)
        sr, dr, _ = path.project(right)
        projected.append((sl, dl, sr, dr))
    # Gap between the lowest lanelet's left bound and the right bound of the lane above it.
    def gap_at(s: float) -> float:
        present = [(np.interp(s, sl, dl), np.interp(s, sr, dr)) for sl, dl, sr, dr in projected
                   if sl.min() <= s <= sl.max() and sr.min() <= s <= sr.max()]
        present.sort(key=lambda p: p[0] + p[1])
        return float(present[1][1] - present[0][0])
    assert gap_at(lane.s_end - 3.0) < cfg.gore_gap_m + 0.1
    assert gap_at(lane.s_end + 3.0) > cfg.gore_gap_m - 0.1
    # Vehicles inside the lane before its end are in an ending lane; nothing beyond the end is.
    inside = table.lanes.ending_lane(table.x, table.y)
    assert not np.any(inside & (table.x > lane.s_end))


def _straight_copy(src: Path, dst: Path) -> None:
    """``src`` with its road straightened: every lanelet boundary replaced by the line y = its
    mean lateral position in the straightened frame, every vehicle state by its straightened-frame
    position and heading. A real scene on a straight road."""
    table = read_commonroad(src, frame="straightened")
    polys = table.lanes.polylines
    root = ET.fromstring(read_gz(src))
    lanelets = root.findall("lanelet")
    assert len(polys) == 2 * len(lanelets)
    for k, ll in enumerate(lanelets):
        for j, tag in enumerate(("leftBound", "rightBound")):
            poly = polys[2 * k + j]
            y = round(float(np.mean(poly[:, 1])), 3)
            pts = ll.find(tag).findall("point")  # type: ignore[union-attr]
            xs = np.linspace(poly[0, 0], poly[-1, 0], len(pts))
            for p, x in zip(pts, xs):
                p.find("x").text = f"{x:.4f}"  # type: ignore[union-attr]
                p.find("y").text = f"{y:.4f}"  # type: ignore[union-attr]
    step = np.rint(table.t / table.dt).astype(np.int64)
    where = {(int(v), int(s)): i for i, (v, s) in enumerate(zip(table.vehicle, step))}
    obstacles = root.findall("dynamicObstacle") or [o for o in root.findall("obstacle")]
    for ob in obstacles:
        oid = int(ob.get("id", "0"))
        for st in [ob.find("initialState")] + ob.findall("trajectory/state"):
            if st is None:
                continue
            i = where[(oid, int(st.find("time/exact").text))]  # type: ignore[union-attr,arg-type]
            st.find("position/point/x").text = repr(float(table.x[i]))  # type: ignore[union-attr]
            st.find("position/point/y").text = repr(float(table.y[i]))  # type: ignore[union-attr]
            st.find("orientation/exact").text = repr(float(table.heading[i]))  # type: ignore[union-attr]
    dst.write_bytes(gzip.compress(ET.tostring(root), mtime=0))


def read_gz(p: Path) -> bytes:
    return gzip.decompress(p.read_bytes())


def _windows_and_scenarios(table) -> tuple[list, list]:  # type: ignore[no-untyped-def]
    grid = build_grid(table)
    ws = extract_windows(grid, WindowConfig())
    scs = scene_scenarios(table, grid, ScenarioConfig(), "test", Counter(), "p")
    return ws, [sc for sc, _ in scs]


def _assert_same(a_table, b_table, tol: float = 1e-3) -> tuple[int, int]:  # type: ignore[no-untyped-def]
    wa, sa = _windows_and_scenarios(a_table)
    wb, sb = _windows_and_scenarios(b_table)
    assert len(wa) == len(wb) and len(sa) == len(sb)
    for x, y in zip(wa, wb):
        assert np.array_equal(x.ids, y.ids) and np.array_equal(x.lane_change, y.lane_change)
        assert x.t0 == y.t0 and x.phase == y.phase
        assert np.max(np.abs(x.positions - y.positions)) <= tol
        assert np.max(np.abs(x.origin - y.origin)) <= tol
    for x, y in zip(sa, sb):
        assert x.stem == y.stem
        for k in x.tensors:
            assert x.tensors[k].shape == y.tensors[k].shape, k
            if x.tensors[k].dtype.kind == "f":
                assert np.max(np.abs(x.tensors[k] - y.tensors[k]), initial=0.0) <= tol, k
            else:
                assert np.array_equal(x.tensors[k], y.tensors[k]), k
    return len(wa), len(sa)


@pytest.mark.parametrize("name", ["USA_US101-1_1_T-1.xml.gz"])
def test_straight_scene_same_windows_and_scenarios(tmp_path: Path, name: str) -> None:
    dst = tmp_path / name
    _straight_copy(FIX / name, dst)
    a = read_commonroad(dst, frame="straightened")
    b = read_commonroad(dst, frame="frenet")
    assert a.lanes.straightness_m < 1e-3 and b.lanes.straightness_m < 1e-3
    assert not any(ln.begins or ln.ends for ln in b.lanes.lanes)
    n_w, n_s = _assert_same(a, b)
    assert n_w > 0 and n_s > 0


@pytest.mark.skipif(not (SHARED / US101_DIRS[0]).exists(), reason="../shared/data/ngsim not present")
@pytest.mark.parametrize("scene", ["USA_US101-5_1_T-1", "USA_US101-8_1_T-1", "USA_US101-16_1_T-1",
                                   "USA_US101-28_1_T-1"])
def test_straight_shared_scene_same_windows_and_scenarios(tmp_path: Path, scene: str) -> None:
    """The regression on real scenes of the shared data whose lanes all run through the scene
    (5-lane scenes, and a 6-lane test scene), each straightened."""
    dst = tmp_path / f"{scene}.xml.gz"
    _straight_copy(SHARED / US101_DIRS[0] / f"{scene}.xml.gz", dst)
    b = read_commonroad(dst, frame="frenet")
    assert not any(ln.begins or ln.ends for ln in b.lanes.lanes)  # a straight scene: no lane begins or ends
    n_w, n_s = _assert_same(read_commonroad(dst, frame="straightened"), b)
    assert n_w > 0 and n_s > 0


def test_frames_command_writes_the_per_scene_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import shutil

    from nudge_train.cli import main

    root = tmp_path / "ngsim"
    a = root / US101_DIRS[0]
    b = root / US101_DIRS[1]
    a.mkdir(parents=True)
    b.mkdir(parents=True)
    shutil.copy(FIX / "USA_US101-1_1_T-1.xml.gz", a)
    shutil.copy(FIX / "USA_US101-26_1_T-1_cut.xml.gz", a)
    shutil.copy(FIX / "USA_US101-7_1_T-1_cut.xml.gz", b)
    shutil.copy(FIX.parent / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    doc = tmp_path / "road_frame.md"
    rc = main(["data", "frames", "--data-root", str(root), "--doc", str(doc), "--no-progress"])
    out = capsys.readouterr().out
    assert rc == 0 and "3 scenes, 0 refused" in out
    rows = {ln.split(" | ")[0].lstrip("| "): ln.split(" | ") for ln in doc.read_text().splitlines()
            if ln.startswith("| USA_US101")}
    assert set(rows) == {"USA_US101-1_1_T-1.xml.gz", "USA_US101-26_1_T-1_cut.xml.gz", "USA_US101-7_1_T-1_cut.xml.gz"}
    seven = rows["USA_US101-7_1_T-1_cut.xml.gz"]
    assert seven[4] == "0 / 1"  # the auxiliary lane ends (it leaves the road downstream)
    assert float(seven[3]) < float(seven[2])  # residual after < before
    # The straightened frame's counts are today's: the same as reading the file directly.
    from nudge_train.data.frame_cmd import frame_counts
    t = read_commonroad(b / "USA_US101-7_1_T-1_cut.xml.gz", frame="straightened")
    fc = frame_counts(t, WindowConfig(), ScenarioConfig(), "test")
    assert int(seven[5]) == fc.windows and int(seven[8]) == fc.scenarios


def test_build_in_the_curvilinear_frame_records_it(tmp_path: Path) -> None:
    """data build (the curvilinear frame by default) against --frame straightened: the same
    windows per source on the fixture scenes (the frames differ by centimetres in x, not in which
    vehicles are present), and the frame recorded in the manifest's config either way."""
    import json
    import shutil

    from nudge_train.cli import main

    root = tmp_path / "ngsim"
    a = root / US101_DIRS[0]
    a.mkdir(parents=True)
    for name in ("USA_US101-1_1_T-1.xml.gz", "USA_US101-26_1_T-1_cut.xml.gz", "USA_US101-9_1_T-1_cut.xml.gz"):
        shutil.copy(FIX / name, a)
    shutil.copy(FIX.parent / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    mans = {}
    for frame, extra in (("straightened", ["--frame", "straightened"]), ("frenet", [])):
        out = tmp_path / frame
        assert main(["data", "build", "--data-root", str(root), "--out", str(out), "--no-i80", "--no-progress",
                     *extra]) == 0
        mans[frame] = json.loads((out / "manifest.json").read_text())
    assert mans["straightened"]["config"]["road_frame"] == "straightened"
    assert mans["frenet"]["config"]["road_frame"] == "frenet"
    for sa, sb in zip(mans["straightened"]["sources"], mans["frenet"]["sources"]):
        assert sa["name"] == sb["name"] and sa["split"] == sb["split"]
        assert sa.get("candidates") == sb.get("candidates")
    nine = next(s for s in mans["frenet"]["sources"] if s["name"] == "USA_US101-9_1_T-1_cut.xml.gz")
    assert nine["reader_notes"]["lanes_ending"] == 1


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), theta=st.floats(-math.pi, math.pi), bend=st.floats(0.0, 2e-3))
def test_projection_property(seed: int, theta: float, bend: float) -> None:
    """Random smooth paths (curvature up to about 1/250 m) and points within 15 m: the foot point
    is orthogonal (the offset vector is perpendicular to the tangent), |d| is the distance to it,
    and the inverse map returns the point."""
    from scipy.interpolate import BSpline

    rng = np.random.default_rng(seed)
    h = 25.0
    t = -200.0 + h * np.arange(-3, 20)
    coef = np.cumsum(np.cumsum(rng.normal(0.0, bend * h * h, t.shape[0] - 4)))
    coef -= BSpline(t, coef, 3)(0.0)
    path = ReferencePath.build(theta, BSpline(t, coef, 3, extrapolate=False), FrenetConfig(max_turn_rad=3.0))
    u0 = rng.uniform(path.x_lo + 30, path.x_hi - 30, 50)
    local = np.stack([u0, path.shape(u0) + rng.uniform(-15, 15, 50)], axis=1)
    c, s_ = math.cos(theta), math.sin(theta)
    world = np.stack([c * local[:, 0] - s_ * local[:, 1], s_ * local[:, 0] + c * local[:, 1]], axis=1)
    try:
        s, d, u = path.project(world)
    except FrameRefusal:
        return  # a point whose nearest foot is off the path's range: refused, as it must be
    foot = np.stack([u, path.shape(u)], axis=1)
    foot_w = np.stack([c * foot[:, 0] - s_ * foot[:, 1], s_ * foot[:, 0] + c * foot[:, 1]], axis=1)
    tan = np.stack([np.ones_like(u), path.shape(u, 1)], axis=1)
    tan /= np.linalg.norm(tan, axis=1, keepdims=True)
    tan_w = np.stack([c * tan[:, 0] - s_ * tan[:, 1], s_ * tan[:, 0] + c * tan[:, 1]], axis=1)
    off = world - foot_w
    assert np.max(np.abs(np.sum(off * tan_w, axis=1))) < 1e-6
    assert np.max(np.abs(np.linalg.norm(off, axis=1) - np.abs(d))) < 1e-9
    assert np.max(np.abs(path.to_world(s, d) - world)) < 1e-5


def test_offsets_near_the_radius_of_curvature_are_refused() -> None:
    """Radius 60 m: a point 35 m inside the bend (0.58 of the radius) is refused, one 20 m
    inside (0.33) is accepted."""
    from nudge_train.data.frenet import check_offsets

    path, _ = _curved_path(radius=60.0)
    cfg = FrenetConfig()
    for d_want, refused in ((20.0, False), (35.0, True)):
        world = path.to_world(np.asarray([0.0]), np.asarray([d_want]))
        s, d, u = path.project(world)
        assert abs(d[0] - d_want) < 1e-6
        if refused:
            with pytest.raises(FrameRefusal, match="not unique"):
                check_offsets(path, u, d, cfg)
        else:
            check_offsets(path, u, d, cfg)


def test_window_difference_matches_agents_by_id() -> None:
    """The frames table's window Δ compares the same agent in both frames (whatever its row), and
    counts windows whose agents differ instead of comparing them."""
    from nudge_train.data.frame_cmd import FrameCounts, window_difference

    rng = np.random.default_rng(1)
    pos = rng.normal(size=(4, 14, 2))
    ids = np.asarray([7, 3, 9, 1])
    perm = np.asarray([0, 2, 3, 1])
    moved = pos[perm].copy()
    moved[2, 5, 1] += 0.25  # agent ids[perm][2] = 1 moves 0.25 m at one step
    a = FrameCounts(window_positions={(1.2, 0, 7): (ids, pos), (1.5, 0, 7): (ids, pos)})
    b = FrameCounts(window_positions={(1.2, 0, 7): (ids[perm], moved), (1.5, 0, 7): (ids[:3], pos[:3]),
                                      (1.8, 0, 7): (ids, pos)})
    worst, unmatched = window_difference(a, b)
    assert abs(worst - 0.25) < 1e-12 and unmatched == 2
