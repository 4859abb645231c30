"""Scenario.from_arrays: a scene from your own data passes exactly the file reader's checks
(the shipped scenes rebuilt from their arrays are equal to the files; bad arrays are refused
by the reader's own messages), and Scenario.save writes a file that loads back equal and runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import nudge


def _arrays(sc: nudge.Scenario) -> dict:
    kw = dict(history=sc.history, size=sc.size, lane_bounds=sc.lane_bounds, ego_lane=sc.ego_lane,
              heading=sc.heading, speed=sc.speed, future=sc.future, future_valid=sc.future_valid,
              lane_centres=sc.lane_centres, agent_ids=sc.agent_ids, name=sc.name, metadata=sc.metadata)
    if sc.lane_extents is not None:
        kw.update(lane_extents=sc.lane_extents, lane_extent_real=sc.lane_extent_real)
    return kw


def _same(a: nudge.Scenario, b: nudge.Scenario) -> None:
    for k in ("history", "size", "heading", "speed", "future", "future_valid", "lane_centres", "lane_bounds",
              "agent_ids"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert (a.name, a.n_agents, a.ego_lane, a.metadata) == (b.name, b.n_agents, b.ego_lane, b.metadata)
    if a.lane_extents is None:
        assert b.lane_extents is None
    else:
        np.testing.assert_array_equal(a.lane_extents, b.lane_extents)
        np.testing.assert_array_equal(a.lane_extent_real, b.lane_extent_real)


def test_shipped_scenes_rebuilt_from_their_arrays_are_the_files(scenes: list[Path]) -> None:
    paths = scenes + nudge.scene_paths(nudge.assets_dir() / "scenes" / "merge")
    assert any(nudge.Scenario.load(p).lane_extents is not None for p in paths)
    for p in paths:
        sc = nudge.Scenario.load(p)
        _same(nudge.Scenario.from_arrays(**_arrays(sc)), sc)


def test_defaults_are_derived_from_the_history(scenes: list[Path]) -> None:
    sc = nudge.Scenario.load(scenes[0])
    built = nudge.Scenario.from_arrays(sc.history, sc.size, sc.lane_bounds, sc.ego_lane)
    d = sc.history[:, -1] - sc.history[:, -2]
    np.testing.assert_allclose(built.speed, np.hypot(d[:, 0], d[:, 1]) / nudge.DT, rtol=1e-12)
    np.testing.assert_allclose(built.heading, np.arctan2(d[:, 1], d[:, 0]), rtol=1e-12)
    np.testing.assert_allclose(built.lane_centres, (sc.lane_bounds[1:] + sc.lane_bounds[:-1]) / 2)
    np.testing.assert_array_equal(built.agent_ids, np.arange(sc.n_agents))
    assert built.future.shape == (sc.n_agents, 6, 2) and not built.future_valid.any()
    assert built.name == "scene" and built.metadata["schema"] == "nudge.scenario/1"


def test_bad_arrays_get_the_file_readers_refusal(scenes: list[Path]) -> None:
    sc = nudge.Scenario.load(scenes[0])
    kw = _arrays(sc)
    fast = dict(kw, speed=np.where(np.arange(sc.n_agents) == 1, 70.0, sc.speed))
    with pytest.raises(nudge.ScenarioError, match=r"agent 1 .*speed") as e:
        nudge.Scenario.from_arrays(**fast)
    assert sc.name in str(e.value)
    nan = dict(kw, history=np.where(np.isclose(sc.history, sc.history[0, 0, 0]), np.nan, sc.history))
    with pytest.raises(nudge.ScenarioError, match=r'tensor "history" holds non-finite value'):
        nudge.Scenario.from_arrays(**nan)
    with pytest.raises(nudge.ScenarioError, match=r"ego_lane.*not a lane index"):
        nudge.Scenario.from_arrays(**dict(kw, ego_lane=len(sc.lane_centres)))
    with pytest.raises(nudge.InputError, match=r"size: expected shape \[%d, 2\]" % sc.n_agents):
        nudge.Scenario.from_arrays(**dict(kw, size=sc.size[:-1]))
    with pytest.raises(nudge.InputError, match="future_valid: expected a bool array"):
        nudge.Scenario.from_arrays(**dict(kw, future_valid=sc.future_valid.astype(float)))
    with pytest.raises(nudge.InputError, match="give both or neither"):
        nudge.Scenario.from_arrays(**dict(kw, future_valid=None))


def test_a_saved_scene_loads_back_equal_and_runs(scenes: list[Path], tmp_path: Path) -> None:
    sc = nudge.Scenario.load(scenes[0])
    built = nudge.Scenario.from_arrays(sc.history, sc.size, sc.lane_bounds, sc.ego_lane, name="mine")
    path = tmp_path / "mine.safetensors"
    built.save(path)
    _same(nudge.Scenario.load(path), built)
    r = nudge.simulate([path], "constant_velocity", world="idm", max_steps=3)
    assert r["runs"]["scenario"] == ["mine"] and r["runs"]["error"] == [None]
