"""Window extraction, filters and labels on real tracks (hand-checked counts)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nudge_train.data.coifman import read_coifman
from nudge_train.data.commonroad import read_commonroad
from nudge_train.data.grid import build_grid
from nudge_train.data.windows import (
    WindowConfig,
    WindowStats,
    extract_windows,
    kinematic_violations,
    overlapping_pairs,
)

FIX = Path(__file__).parent / "fixtures"


def _scene1():
    return read_commonroad(FIX / "commonroad" / "USA_US101-1_1_T-1.xml.gz")


def test_window_counts_hand_checked() -> None:
    # Two vehicles, both present in all 61 frames (0..60). A window spans 39 frames (13 x 3),
    # so starts s with s + 39 <= 60: phase 0 -> 0,3,..,21 (8), phase 1 -> 1,..,19 (7),
    # phase 2 -> 2,..,20 (7): 22 windows.
    t = _scene1()
    st = WindowStats()
    ws = extract_windows(build_grid(t), WindowConfig(), stats=st)
    assert len(ws) == 22 and st.candidates == 22
    assert [sum(w.phase == p for w in ws) for p in (0, 1, 2)] == [8, 7, 7]
    assert all(w.positions.shape == (2, 14, 2) for w in ws)
    for p in (0,):
        assert len(extract_windows(build_grid(t), WindowConfig(phases=(p,)))) == 8


def test_missing_frame_removes_phase() -> None:
    # Remove frame 30 of one vehicle: every phase-0 window (starts 0..21, samples s+3k) samples
    # frame 30, so all 8 lose that vehicle and are dropped (one agent left); phases 1, 2 keep 14.
    t = _scene1()
    v = t.vehicle_ids()[1]
    keep = ~((t.vehicle == v) & (np.rint(t.t * 10) == 30))
    st = WindowStats()
    ws = extract_windows(build_grid(t.select(keep)), WindowConfig(), stats=st)
    assert len(ws) == 14
    assert st.windows_dropped["fewer_than_2_agents"] == 8
    assert {w.phase for w in ws} == {1, 2}


def test_window_content_matches_tracks() -> None:
    t = _scene1()
    ws = extract_windows(build_grid(t), WindowConfig(phases=(0,)))
    w = ws[2]  # start frame 6, last observed frame 6 + 21 = 27
    assert w.t0 == pytest.approx(2.7)
    np.testing.assert_allclose(w.positions[0, 7], 0.0, atol=1e-12)
    for a, vid in enumerate(w.ids):
        rows = t.vehicle == vid
        fr = np.rint(t.t[rows] * 10).astype(int)
        for k in range(14):
            f = 6 + 3 * k
            xy = np.array([t.x[rows][fr == f][0], t.y[rows][fr == f][0]])
            np.testing.assert_allclose(w.positions[a, k] + w.origin, xy, atol=1e-9)


def test_kinematic_rules_fire_on_corrupted_real_track() -> None:
    t = _scene1()
    ws = extract_windows(build_grid(t), WindowConfig(phases=(0,)))
    pos = ws[0].positions.copy()
    cfg = WindowConfig()
    clean = kinematic_violations(pos, 0.3, cfg)
    assert not any(v.any() for v in clean.values())
    pos[1, 6, 0] += 1.5  # a 1.5 m jump at one step of agent 1
    bad = kinematic_violations(pos, 0.3, cfg)
    assert bad["accel"].tolist() == [False, True] and bad["jerk"].tolist() == [False, True]
    fast = ws[0].positions.copy()
    fast[1] = fast[1] * np.array([[4.0, 1.0]])  # x scaled: ~60 m/s
    assert kinematic_violations(fast, 0.3, cfg)["speed"][1]
    back = ws[0].positions.copy()
    back[1, :, 0] = back[1, ::-1, 0]  # driving backwards
    assert kinematic_violations(back, 0.3, cfg)["speed"][1]


def test_overlap_rule_and_counts() -> None:
    t = _scene1()
    g = build_grid(t)
    ws = extract_windows(g, WindowConfig(phases=(0,)))
    pos = ws[0].positions
    size = ws[0].size
    assert overlapping_pairs(pos, size, 0.8) == []
    moved = pos.copy()
    moved[1] = moved[0] + np.array([1.0, 0.2])  # agent 1 drawn on top of agent 0
    assert overlapping_pairs(moved, size, 0.8) == [(0, 1)]
    # In a grid, the overlapping neighbour is dropped and counted; the window then has 1 agent.
    g.pos[1] = g.pos[0] + np.array([1.0, 0.2])
    st = WindowStats()
    assert extract_windows(g, WindowConfig(phases=(0,)), stats=st) == []
    assert st.agents_dropped["overlap"] == 8 and st.windows_dropped["overlap_left_lt_2_agents"] == 8


def test_single_vehicle_scene_is_counted_not_crashing() -> None:
    t = _scene1()
    one = t.select(t.vehicle == t.vehicle_ids()[0])
    st = WindowStats()
    assert extract_windows(build_grid(one), WindowConfig(), stats=st) == []
    assert st.windows_dropped["fewer_than_2_agents"] == 22


def test_max_agents_and_ego_first() -> None:
    t = read_commonroad(FIX / "commonroad" / "USA_US101-26_1_T-1_cut.xml.gz")
    g = build_grid(t)
    full = extract_windows(g, WindowConfig(phases=(0,)))
    assert full and all(w.positions.shape[0] >= 2 for w in full)
    capped_stats = WindowStats()
    capped = extract_windows(g, WindowConfig(phases=(0,), max_agents=2), stats=capped_stats)
    assert all(w.positions.shape[0] == 2 for w in capped)
    for w in capped:
        np.testing.assert_allclose(w.positions[0, 7], 0.0, atol=1e-9)
        # The kept neighbour is the nearest to the ego at the last observed step.
        full_w = next(f for f in full if f.t0 == w.t0)
        d = np.linalg.norm(full_w.positions[1:, 7] + full_w.origin - w.origin, axis=1)
        assert np.linalg.norm(w.positions[1, 7]) == pytest.approx(d.min())
    assert capped_stats.agents_dropped["beyond_max_agents"] == sum(f.positions.shape[0] - 2 for f in full)


def test_lane_change_label_on_i80_fixture() -> None:
    t = read_coifman(FIX / "i80" / "coifman_cut.csv")
    ws = extract_windows(build_grid(t), WindowConfig())
    assert ws
    lc = [w for w in ws if 190 in w.ids.tolist()]
    # Vehicle 190 moves from lane 2 to lane 3 at frame 1293 (t = 129.3 s); a window covering
    # frames well before to well after it labels 190 as changing lane.
    labelled = [w for w in lc if w.lane_change[w.ids.tolist().index(190)]]
    assert labelled and all(w.interactive for w in labelled)
    for w in labelled:
        start = w.t0 - 2.1
        assert start < 129.3 < w.t0 + 1.8 + 1e-9
