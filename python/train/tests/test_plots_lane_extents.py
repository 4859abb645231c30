"""``figures runs`` draws where a lane of a "nudge.scenario/2" scene really ends (a red bar at
the end across that lane, the lane shaded beyond it) and reaches far enough to show the ego
lane's end; a "nudge.scenario/1" scene draws none."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

nudge = pytest.importorskip("nudge")

from nudge.figures import _draw_lane_extents, _pyplot  # noqa: E402

ASSETS = Path(__file__).resolve().parents[3] / "assets" / "scenes"


def test_lane_ends_are_drawn_where_the_scene_says() -> None:
    plt = _pyplot()
    scene = nudge.Scenario.load(ASSETS / "merge" / "us101-9_1-t02.1-ego434.safetensors")
    fig, ax = plt.subplots()
    reach = _draw_lane_extents(ax, scene)
    end = float(scene.lane_extents[scene.ego_lane, 1])
    assert reach == end + 10.0
    bars = [ln for ln in ax.get_lines() if ln.get_color() == "tab:red"]
    real = scene.lane_extent_real
    assert len(bars) == int(real.sum()) == 1
    lo, hi = scene.lane_bounds[scene.ego_lane], scene.lane_bounds[scene.ego_lane + 1]
    np.testing.assert_array_equal(bars[0].get_xdata(), [end, end])
    np.testing.assert_array_equal(bars[0].get_ydata(), [lo, hi])
    assert len(ax.collections) == 1
    plt.close(fig)
    plain = nudge.Scenario.load(sorted(ASSETS.glob("*.safetensors"))[0])
    fig, ax = plt.subplots()
    assert _draw_lane_extents(ax, plain) == -np.inf
    assert not ax.get_lines() and not ax.collections
    plt.close(fig)
