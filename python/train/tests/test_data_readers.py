"""Readers on real rows cut from the shared NGSIM files (tests/fixtures)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nudge_train.data.coifman import FLAG_LC_INTERPOLATED, LANE_W, lateral_path, read_coifman
from nudge_train.data.commonroad import read_commonroad
from nudge_train.data.raw import FT, read_raw_ngsim, smooth_flicker
from nudge_train.data.tracks import FLAG_LATERAL_SYNTHETIC, FLAG_SIZE_ASSUMED

FIX = Path(__file__).parent / "fixtures"


def test_commonroad_2020a_full_scene() -> None:
    t = read_commonroad(FIX / "commonroad" / "USA_US101-1_1_T-1.xml.gz")
    assert t.scene == "USA_US101-1_1_T-1"
    assert len(t) == 122 and list(t.vehicle_ids()) == sorted(set(t.vehicle.tolist()))
    assert len(t.vehicle_ids()) == 2
    # 61 steps at 0.1 s per vehicle, sorted by (vehicle, time).
    for v in t.vehicle_ids():
        tt = t.t[t.vehicle == v]
        assert tt.shape[0] == 61 and np.allclose(np.diff(tt), 0.1)
    # Traffic runs along +x after the rotation: headings near 0, x increases.
    assert np.all(np.abs(t.heading) < 0.15)
    for v in t.vehicle_ids():
        assert np.all(np.diff(t.x[t.vehicle == v]) > 0)
    # Five main lanes plus the auxiliary lane: 6 lanes, boundaries ascending, about 3.5 m wide.
    b = t.lanes.bounds
    assert b.shape[0] == 7 and np.all(np.diff(b) > 2.5) and np.all(np.diff(b) < 5.0)
    assert t.lanes.local_deviation(float(np.median(t.x)), 100.0) < 0.6
    # Both vehicles are inside the road.
    assert np.all((t.y > b[0]) & (t.y < b[-1]))


def test_commonroad_2018b_obstacles() -> None:
    t = read_commonroad(FIX / "commonroad" / "USA_US101-7_1_T-1_cut.xml.gz")
    assert t.scene == "USA_US101-7_1_T-1"
    assert len(t.vehicle_ids()) == 5
    # First obstacle of the file (id 415): length 5.0292, width 2.1031, speed 15.4137 at step 0,
    # orientation -0.71369 rad (the scene's road runs at about -0.72 rad before rotation).
    m = (t.vehicle == 415) & (t.t == 0.0)
    assert m.sum() == 1
    assert t.length[m][0] == pytest.approx(5.0292) and t.width[m][0] == pytest.approx(2.1031)
    assert t.speed[m][0] == pytest.approx(15.4137)
    assert abs(t.heading[m][0]) < 0.05
    # Positions 0.1 s apart: (112.3563, -107.5158) -> (113.5118, -108.5146) is a 1.527 m step,
    # which becomes (almost) all +x after rotation.
    xs = t.x[t.vehicle == 415]
    raw_step = np.hypot(113.5118 - 112.3563, -108.5146 + 107.5158)
    assert xs[1] - xs[0] == pytest.approx(raw_step, abs=0.02)


RAW25 = FIX / "raw" / "peachtree_cut_25col.csv"


def test_raw_25col_quirks() -> None:
    tables = read_raw_ngsim(RAW25)
    notes = tables[0].notes
    # 19 duplicate (Vehicle_ID, Frame_ID) keys: vehicle 70 reused in two recording periods.
    assert notes["duplicate_keys_in_file"] == 19
    assert notes["periods_in_file"] == 2
    assert notes["duplicate_rows_dropped"] == 0
    assert notes["global_time_10_digit_rows"] == notes["rows_read"]
    scenes = {t.scene: t for t in tables}
    assert set(scenes) == {"peachtree-p0-dir2", "peachtree-p1-dir2", "peachtree-p1-dir4"}
    # Rows sorted by (vehicle, time) although the file is in reverse frame order.
    for t in tables:
        key = t.vehicle * 10**6 + np.rint(t.t * 10).astype(np.int64)
        assert np.all(np.diff(key) > 0)
    # Vehicle 70 appears in both periods with different lengths (16.5 ft vs 17.5 ft).
    lens = sorted({round(float(t.length[t.vehicle == 70][0]) / FT, 3) for t in tables if (t.vehicle == 70).any()})
    assert lens == [16.5, 17.5]


def test_raw_unit_conversion_by_hand() -> None:
    tables = {t.scene: t for t in read_raw_ngsim(RAW25)}
    # Row "352,3380,...,Local_X=-5.359,Local_Y=0.0,...,v_length=15.0,v_Width=6.5,...,v_Vel=33.96,
    # Direction=4": southbound (towards -Local_Y), so x = -(Local_Y + L/2), y = +Local_X.
    t = tables["peachtree-p1-dir4"]
    m = (t.vehicle == 352) & (np.rint(t.t * 10) == 3380)
    assert m.sum() == 1
    assert t.x[m][0] == pytest.approx(-(0.0 + 7.5) * 0.3048)
    assert t.y[m][0] == pytest.approx(-5.359 * 0.3048)
    assert t.speed[m][0] == pytest.approx(33.96 * 0.3048)
    assert t.length[m][0] == pytest.approx(4.572) and t.width[m][0] == pytest.approx(1.9812)
    # Row "70,405,628,1163059100,14.597,24.334,...,16.5,7.0,...": northbound, period 0:
    # x = (24.334 - 16.5 / 2) ft, y = -14.597 ft.
    t = tables["peachtree-p0-dir2"]
    m = (t.vehicle == 70) & (np.rint(t.t * 10) == 405)
    assert m.sum() == 1
    assert t.x[m][0] == pytest.approx((24.334 - 8.25) * 0.3048)
    assert t.y[m][0] == pytest.approx(-14.597 * 0.3048)
    assert t.t[m][0] == pytest.approx(40.5)


def test_raw_18col_without_header_matches_25col() -> None:
    t18 = {t.scene.split("-")[-1]: t for t in read_raw_ngsim(FIX / "raw" / "peachtree_cut_18col.txt")}
    t25 = {t.scene: t for t in read_raw_ngsim(RAW25)}
    # 18-column layout has no Location/Direction: scenes are <file stem>-p<period>.
    assert sorted(t18) == ["p0", "p1"]
    a, b = t18["p0"], t25["peachtree-p0-dir2"]
    assert np.array_equal(a.vehicle, b.vehicle)
    assert np.allclose(a.x, b.x) and np.allclose(a.y, b.y) and np.allclose(a.t, b.t)


def test_lane_flicker_smoothing() -> None:
    lane = np.array([2, 2, 2, 2, 3, 3, 2, 2, 2, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3, 3])
    out, changed = smooth_flicker(lane, max_run=10)
    assert changed == 2
    assert out.tolist() == [2] * 9 + [3] * 12


COIF = FIX / "i80" / "coifman_cut.csv"


def test_coifman_lateral_and_flags() -> None:
    t = read_coifman(COIF)
    assert np.all(t.flags & FLAG_LATERAL_SYNTHETIC) and np.all(t.flags & FLAG_SIZE_ASSUMED)
    v = t.vehicle == 190
    assert v.any()
    # Vehicle 190 changes from lane 2 to lane 3 at frame 1293: flagged, y moves from the lane 2
    # centre towards the lane 3 centre (12 ft lanes, lane 1 leftmost).
    assert np.all(t.flags[v] & FLAG_LC_INTERPOLATED)
    y = t.y[v]
    frames = np.rint(t.t[v] * 10).astype(int)
    c2, c3 = -1.5 * LANE_W, -2.5 * LANE_W
    assert y[frames == 1293][0] == pytest.approx(0.5 * (c2 + c3), abs=0.05)
    assert y[frames == 1262][0] == pytest.approx(c2 + (c3 - c2) * 0.0, abs=LANE_W * 0.11)
    assert np.all(np.diff(y) <= 1e-12)  # monotone move to the right
    # x: Local_Y (ft) minus half the assumed 4.5 m length; speed: v_Vel ft/s -> m/s.
    import csv

    with open(COIF, newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["Vehicle_ID"] == "190" and r["Frame_ID"] == "1293"]
    assert t.x[v][frames == 1293][0] == pytest.approx(float(rows[0]["Local_Y"]) * 0.3048 - 2.25)
    assert t.speed[v][frames == 1293][0] == pytest.approx(float(rows[0]["v_Vel"]) * 0.3048)
    # Lane-keeping vehicles stay on their lane centre.
    keep = [k for k in t.vehicle_ids() if not (t.flags[t.vehicle == k] & FLAG_LC_INTERPOLATED).any()]
    assert keep
    for k in keep:
        yy = t.y[t.vehicle == k]
        assert np.ptp(yy) == 0.0


def test_lateral_path_duration() -> None:
    t = np.arange(0, 10.0, 0.1)
    lane = np.where(t < 5.0 - 1e-9, 1, 2)
    y = lateral_path(t, lane, duration=4.0)
    moving = np.flatnonzero(np.abs(np.diff(y)) > 1e-12)
    # The move spans 4 s centred on the change at t = 5 s.
    assert t[moving[0]] == pytest.approx(3.0, abs=0.11) and t[moving[-1] + 1] == pytest.approx(7.0, abs=0.11)
    assert y[0] == pytest.approx(-0.5 * LANE_W) and y[-1] == pytest.approx(-1.5 * LANE_W)
