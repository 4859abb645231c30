"""The human lane-change reference: the Thiemann–Treiber–Kesting smoother against analytic
signals, the lane-change rule on synthetic trajectories with known answers (and the events it
must reject), the partial US-101 reader's typed errors, and the rule on real NGSIM rows."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from nudge_train import paths
from nudge_train.data.chenshimao import read_chenshimao
from nudge_train.data.commonroad import read_commonroad
from nudge_train.data.errors import DataError
from nudge_train.data.lane_changes import LaneChangeRule, extract_lane_changes
from nudge_train.data.smoothing import SmoothingWidths, smooth_derivatives, tte_smooth
from nudge_train.experiments import human_lane_changes as hlc

DT = 0.1
W = 3.6  # lane width (m)
LINES = -W / 2 - W * np.arange(5)  # mainline lines, lane 0 centred on d = 0


# ---- smoother ----------------------------------------------------------------------------------
def _naive(x: np.ndarray, dt: float, width: float) -> np.ndarray:
    """The paper's formula, one sample at a time."""
    n = len(x)
    out = np.empty(n)
    for i in range(n):
        d = min(int(round(3 * width / dt)), i, n - 1 - i)
        k = np.arange(i - d, i + d + 1)
        w = np.exp(-np.abs(k - i) * dt / width)
        out[i] = np.sum(w * x[k]) / np.sum(w)
    return out


def test_smoother_is_the_papers_formula_with_symmetric_truncation() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=57)
    np.testing.assert_allclose(tte_smooth(x, DT, 0.5), _naive(x, DT, 0.5), rtol=0, atol=1e-12)
    y = tte_smooth(x, DT, 0.5)
    assert y[0] == x[0] and y[-1] == x[-1]  # a window of one sample at the ends
    w = np.exp(-1.0 / 5.0)
    assert y[1] == pytest.approx((w * x[0] + x[1] + w * x[2]) / (1 + 2 * w))


def test_smoother_keeps_a_straight_line_everywhere() -> None:
    t = np.arange(0, 10, DT)
    np.testing.assert_allclose(tte_smooth(3.0 - 2.0 * t, DT, 0.7), 3.0 - 2.0 * t, atol=1e-12)


def test_derivatives_of_a_noisy_parabola() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, DT)
    x = 0.4 * t**2 - 3.0 * t + 1.0 + rng.normal(scale=0.05, size=t.shape)
    k = smooth_derivatives(x, DT, SmoothingWidths(0.5, 0.25, 0.25, 0.25))
    inner = slice(30, -30)  # away from the truncated ends
    np.testing.assert_allclose(k[1][inner], (0.8 * t - 3.0)[inner], atol=0.12)
    np.testing.assert_allclose(k[2][inner], 0.8, atol=0.35)
    assert np.median(np.abs(k[2][inner] - 0.8)) < 0.1
    assert np.median(np.abs(k[3][inner])) < 0.6  # jerk 0 plus noise


def test_derivatives_of_a_slow_sinusoid() -> None:
    t = np.arange(0, 40, DT)
    om = 2 * np.pi / 20.0
    k = smooth_derivatives(np.sin(om * t), DT, SmoothingWidths(0.5, 0.25, 0.25, 0.25))
    inner = slice(40, -40)
    np.testing.assert_allclose(k[1][inner], (om * np.cos(om * t))[inner], atol=0.03 * om)
    np.testing.assert_allclose(k[2][inner], (-om**2 * np.sin(om * t))[inner], atol=0.05 * om**2)
    np.testing.assert_allclose(k[3][inner], (-om**3 * np.cos(om * t))[inner], atol=0.08 * om**3)


def test_smoother_refuses_bad_input() -> None:
    with pytest.raises(ValueError, match="non-finite sample at index 2"):
        tte_smooth(np.array([0.0, 1.0, np.nan, 2.0]), DT, 0.5)
    with pytest.raises(ValueError, match="width_s"):
        tte_smooth(np.zeros(5), DT, -1.0)
    with pytest.raises(ValueError, match="SmoothingWidths.jerk"):
        smooth_derivatives(np.zeros(5), DT, SmoothingWidths(jerk=float("inf")))


# ---- the rule on synthetic trajectories --------------------------------------------------------
def _lane_change(T: float, t0: float, n: int, width: float = W, speed: float = 12.0) -> tuple[np.ndarray, ...]:
    """A lane change to the right (lane 0 -> 1) whose lateral acceleration is one sine period."""
    t = np.arange(n) * DT
    u = np.clip((t - t0) / T, 0.0, 1.0)
    d = -width * (u - np.sin(2 * np.pi * u) / (2 * np.pi))
    return t, speed * t, d, np.tile(LINES, (n, 1))


def _threshold_times(T: float, t0: float, v_still: float) -> tuple[float, float]:
    """When the noise-free lateral speed w/T·(1 - cos 2πu) passes v_still."""
    u = np.arccos(1 - v_still * T / W) / (2 * np.pi)
    return t0 + u * T, t0 + (1 - u) * T


def test_a_known_lane_change_is_found() -> None:
    T, t0 = 5.0, 6.0
    t, s, d, lines = _lane_change(T, t0, 200)
    ex = extract_lane_changes(t, s, d, lines)
    assert len(ex.events) == 1 and sum(ex.rejected.values()) == 0
    lc = ex.events[0]
    assert (lc.from_lane, lc.to_lane, lc.direction) == (0, 1, -1)
    assert lc.t_cross == pytest.approx(t0 + T / 2, abs=0.05)  # the line is crossed halfway
    start, end = _threshold_times(T, t0, LaneChangeRule().v_still)
    assert lc.t_start == pytest.approx(start, abs=0.4)
    assert lc.t_end == pytest.approx(end, abs=0.4)
    assert lc.duration == pytest.approx(end - start, abs=0.8)
    assert lc.speed_cross == pytest.approx(np.hypot(12.0, 2 * W / T), rel=0.02)
    assert 0.8 * 2 * W / T < -lc.v_lat_cross <= 2 * W / T  # smoothing only lowers the peak speed
    true_acc = 2 * np.pi * W / T**2
    assert 0.6 * true_acc < lc.peak_lat_accel <= true_acc
    assert lc.peak_yaw_rate == pytest.approx(lc.peak_lat_accel / 12.0, rel=0.15)  # ψ' ≈ a_y / v
    assert lc.peak_long_jerk < 1e-6  # constant speed along the road


def test_a_noisy_lane_change_is_found_at_the_same_place() -> None:
    T, t0 = 4.0, 7.0
    t, s, d, lines = _lane_change(T, t0, 220)
    rng = np.random.default_rng(3)
    ex = extract_lane_changes(t, s + rng.normal(scale=0.05, size=t.shape), d + rng.normal(scale=0.05, size=t.shape),
                              lines)
    assert len(ex.events) == 1
    assert ex.events[0].t_cross == pytest.approx(t0 + T / 2, abs=0.2)
    assert ex.events[0].duration == pytest.approx(T, abs=1.2)


def test_a_truncated_lane_change_is_rejected() -> None:
    t, s, d, lines = _lane_change(5.0, 2.0, 200)  # crossing at 4.5 s, the motion starts at 2 s
    ex = extract_lane_changes(t, s, d, lines)
    assert len(ex.events) == 1  # the whole motion is logged
    # the log starts at 3 s, the vehicle already moving sideways: too short a history for the
    # dwell rule, and (with a shorter dwell) for the search of the start
    for rule in (LaneChangeRule(), LaneChangeRule(dwell_before_s=1.0)):
        ex = extract_lane_changes(t[30:], s[30:], d[30:], lines[30:], rule)
        assert ex.events == [] and ex.rejected["truncated"] == 1
    t, s, d, lines = _lane_change(5.0, 6.0, 95)  # the log ends 1 s after the crossing
    ex = extract_lane_changes(t, s, d, lines)
    assert ex.events == [] and ex.rejected["truncated"] == 1


def test_a_returning_vehicle_is_rejected() -> None:
    t, s, d, lines = _lane_change(3.0, 6.0, 250)
    back = -_lane_change(3.0, 8.0, 250)[2]  # back over the line at 9.5 s, 2 s after crossing it
    ex = extract_lane_changes(t, s, d + back, lines, LaneChangeRule(dwell_after_s=2.5))
    assert ex.events == []
    assert ex.rejected["returned"] == 1 and ex.rejected["not_persistent_before"] == 1


def test_changes_off_the_mainline_and_drifts_are_rejected() -> None:
    t, s, d, lines = _lane_change(5.0, 6.0, 200)
    ex = extract_lane_changes(t, s, d - 4 * W, lines)  # lane 4 -> right of the mainline
    assert ex.events == [] and ex.rejected["not_mainline"] == 1
    # a slow drift over the line: 0.1 m/s at the crossing
    drift = -1.0 - 0.1 * np.clip(t - 5.0, 0.0, 16.0)
    ex = extract_lane_changes(t, s, drift, lines)
    assert ex.events == [] and ex.rejected["no_lateral_motion"] == 1


def test_bad_trajectories_are_refused() -> None:
    t, s, d, lines = _lane_change(5.0, 6.0, 100)
    with pytest.raises(ValueError, match="evenly spaced"):
        extract_lane_changes(np.concatenate([t[:50], t[51:]]), s[1:], d[1:], lines[1:])
    with pytest.raises(ValueError, match="shapes"):
        extract_lane_changes(t, s, d[:-1], lines)
    with pytest.raises(ValueError, match="v_still"):
        extract_lane_changes(t, s, d, lines, LaneChangeRule(v_still=0.0))


# ---- the partial US-101 reader -----------------------------------------------------------------
HEAD = "Vehicle_ID,Frame_ID,Total_Frames,Global_Time,local_x(m),local_y(m),v_Vel(m)\n"


def _write(tmp_path: Path, body: str, head: str = HEAD) -> Path:
    p = tmp_path / "partial.csv.gz"
    with gzip.open(p, "wt") as fh:
        fh.write(head + body)
    return p


def test_partial_reader_errors_name_the_row_and_field(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"row 3: local_x\(m\) is not a number"):
        read_chenshimao(_write(tmp_path, "1,1,2,1000,2.0,1.0,5\n1,2,2,1100,x,1.5,5\n"))
    with pytest.raises(DataError, match="missing columns"):
        read_chenshimao(_write(tmp_path, "1,1,2,1000,2.0,1.0\n", head="Vehicle_ID,Frame_ID,Total_Frames,"
                               "Global_Time,local_x(m),local_y(m)\n"))
    with pytest.raises(DataError, match="duplicate row: vehicle 1 at Global_Time 1000"):
        read_chenshimao(_write(tmp_path, "1,1,2,1000,2.0,1.0,5\n1,1,2,1000,2.1,1.5,5\n"))
    with pytest.raises(DataError, match="not finite"):
        read_chenshimao(_write(tmp_path, "1,1,2,1000,2.0,inf,5\n"))


def test_partial_reader_splits_tracks_at_gaps(tmp_path: Path) -> None:
    pt = read_chenshimao(_write(tmp_path, "2,5,3,1200,2.0,1.0,5\n2,3,3,1000,2.0,0.0,5\n2,4,3,1100,2.0,0.5,5\n"
                                          "2,9,1,5000,2.0,9.0,5\n7,1,1,1000,6.0,3.0,4\n"))
    assert pt.bounds() == [(0, 3), (3, 4), (4, 5)]
    np.testing.assert_allclose(pt.s[:3], [0.0, 0.5, 1.0])  # sorted by time within the vehicle
    np.testing.assert_allclose(pt.t[:4], [0.0, 0.1, 0.2, 4.0])


# ---- real rows ---------------------------------------------------------------------------------
NGSIM = paths.ngsim()
needs_data = pytest.mark.skipif(not (NGSIM / hlc.CHENSHIMAO).exists(), reason="no NGSIM data")


def _plausible(events: list) -> None:
    for lc in events:
        assert 1.0 <= lc.duration <= 2 * LaneChangeRule().max_search_s
        assert lc.t_start < lc.t_cross < lc.t_end
        assert 0.2 <= abs(lc.v_lat_cross) < 3.0
        assert 0.0 < lc.peak_lat_accel < 4.0
        assert 0.0 <= lc.speed_cross < 40.0
        assert abs(lc.from_lane - lc.to_lane) == 1 and max(lc.from_lane, lc.to_lane) < hlc.MAINLINE_LANES


@needs_data
def test_real_partial_tracks() -> None:
    pt = read_chenshimao(NGSIM / hlc.CHENSHIMAO)
    assert len(pt.bounds()) == 370
    split_of, _ = hlc.partial_splits(pt, hlc.SplitConfig())
    assert set(split_of.values()) == {"train", "val", "test"}
    assert hlc.partial_splits(pt, hlc.SplitConfig())[0] == split_of  # deterministic
    centres, bin_s = hlc.partial_lane_centres(pt, np.ones(pt.t.shape[0], dtype=bool))
    assert centres.shape == (8, 5)
    assert np.all(np.abs(np.diff(centres, axis=1) - W) < 0.6)  # lanes about 12 ft apart
    events = []
    for a, b in pt.bounds()[:60]:
        lines = hlc.partial_lines(pt.s[a:b], centres, bin_s)
        events += extract_lane_changes(pt.t[a:b], pt.s[a:b], -pt.lateral_from_left[a:b], lines).events
    assert len(events) >= 20
    _plausible(events)
    assert 3.0 < np.median([e.duration for e in events]) < 7.0


@needs_data
def test_real_commonroad_scene() -> None:
    tb = read_commonroad(NGSIM / "us101/commonroad_us101_T-1/USA_US101-22_1_T-1.xml.gz")
    events = []
    for v in tb.vehicle_ids():
        r = tb.vehicle == v
        b = [tb.lanes.bounds_at(float(x)) for x in tb.x[r]]
        lines = np.stack([bb[len(bb) - 2 - np.arange(5)] for bb in b])
        events += extract_lane_changes(tb.t[r], tb.x[r], tb.y[r], lines).events
    assert len(events) >= 2
    _plausible(events)


# ---- the summary -------------------------------------------------------------------------------
def _event(split: str, duration: float, speed: float) -> hlc.Event:
    lc = extract_lane_changes(*_lane_change(5.0, 6.0, 200)).events[0]
    from dataclasses import replace

    return hlc.Event("partial", "f", 1, split, "g", replace(lc, duration=duration, speed_cross=speed))


def test_summary_keeps_test_out_of_train_val() -> None:
    evs = [_event("train", 4.0, 12.0), _event("val", 6.0, 3.0), _event("test", 100.0, 12.0)]
    st = hlc.Study(events=evs, rejected={}, duplicates=0, tracks={}, partial_centres=np.zeros((1, 5)),
                   partial_bin_s=np.zeros(1), lane_keeping={}, synthetic=[], rule=LaneChangeRule(), seed=0,
                   matches=[], in_both=0, block_split={}, track_split={})
    s = hlc.summary(st)
    assert s["n"] == {"train": 1, "val": 1, "test": 1, "train+val": 2, "all": 3}
    assert s["train_val"]["duration"]["all"]["median"] == 5.0
    assert s["train_val"]["duration"]["0-5"]["n"] == 1 and s["train_val"]["duration"]["10-15"]["median"] == 4.0
    assert s["test"]["duration"]["all"]["median"] == 100.0
    assert s["train_val"]["duration"]["15-inf"]["n"] == 0
