"""Planner scenarios: the shipped assets follow nudge.scenario/1 exactly; the writer is
deterministic and only uses the requested split."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
from safetensors import safe_open

from nudge_train import paths
from nudge_train.data.commonroad import read_commonroad
from nudge_train.data.grid import build_grid
from nudge_train.data.scenarios import ScenarioConfig, scene_scenarios
from nudge_train.data.scene_cmd import ScenesConfig, write_scenes
from nudge_train.data.splits import SplitConfig

FIX = Path(__file__).parent / "fixtures"
ASSETS = paths.shipped_scenes()
SPEC = {
    "history": np.float64, "heading": np.float64, "speed": np.float64, "size": np.float64,
    "future": np.float64, "future_valid": np.uint8, "lane_centres": np.float64,
    "lane_bounds": np.float64, "ego_lane": np.int64, "agent_ids": np.int64,
}
META = {"schema", "source", "scene", "split", "t0_s", "dt", "provenance"}


def check_scenario(path: Path) -> dict[str, np.ndarray]:
    with safe_open(str(path), "np") as fh:
        meta = fh.metadata()
        t = {k: fh.get_tensor(k) for k in fh.keys()}
    assert set(t) == set(SPEC)
    for k, dt in SPEC.items():
        assert t[k].dtype == dt, k
    assert set(meta) == META
    assert meta["schema"] == "nudge.scenario/1" and meta["dt"] == "0.3"
    float(meta["t0_s"])
    n = t["history"].shape[0]
    assert 1 <= n <= 47 and t["history"].shape == (n, 8, 2)
    assert t["heading"].shape == (n,) and t["speed"].shape == (n,) and t["size"].shape == (n, 2)
    f = t["future"].shape[1]
    assert 6 <= f <= 30 and t["future"].shape == (n, f, 2) and t["future_valid"].shape == (n, f)
    assert np.all(t["future"][t["future_valid"] == 0] == 0.0)
    assert np.all(t["future_valid"][0] == 1)  # the ego's logged future is complete
    lc, lb = t["lane_centres"], t["lane_bounds"]
    assert lb.shape == (lc.shape[0] + 1,) and np.all(np.diff(lb) > 0)
    np.testing.assert_allclose(lc, 0.5 * (lb[:-1] + lb[1:]))
    e = int(t["ego_lane"][0])
    assert t["ego_lane"].shape == (1,) and 0 <= e < lc.shape[0]
    y = t["history"][0, -1, 1]
    assert lb[e] <= y <= lb[e + 1]
    # Neighbours nearest first at the last observed step.
    d = np.linalg.norm(t["history"][1:, -1] - t["history"][0, -1], axis=1)
    assert np.all(np.diff(d) >= 0)
    assert len(set(t["agent_ids"].tolist())) == n
    # Continuity: first future step is one 0.3 s step after the last observed one (< 15 m).
    assert np.all(np.linalg.norm(t["future"][:, 0] - t["history"][:, -1], axis=1)[t["future_valid"][:, 0] == 1] < 15)
    return t


def test_shipped_assets() -> None:
    files = sorted(ASSETS.glob("*.safetensors"))
    assert 8 <= len(files) <= 12
    assert sum(p.stat().st_size for p in files) < 500_000
    counts = []
    for p in files:
        t = check_scenario(p)
        with safe_open(str(p), "np") as fh:
            assert fh.metadata()["split"] == "test"
        n_lanes = t["lane_centres"].shape[0]
        assert n_lanes >= 2  # the ego always has an adjacent lane
        counts.append(t["history"].shape[0] - 1)
    assert min(counts) <= 4 and max(counts) >= 8
    assert (ASSETS / "PROVENANCE.md").exists()


def test_scene_scenarios_on_fixture() -> None:
    table = read_commonroad(FIX / "commonroad" / "USA_US101-26_1_T-1_cut.xml.gz")
    grid = build_grid(table)
    from collections import Counter

    drops: Counter = Counter()
    scs = scene_scenarios(table, grid, ScenarioConfig(), "test", drops, "fixture")
    assert scs
    for sc, f_last in scs:
        assert f_last % 3 == 0
        # History is the grid at f_last - 21 .. f_last in steps of 3.
        ego = int(np.flatnonzero(grid.ids == sc.tensors["agent_ids"][0])[0])
        np.testing.assert_allclose(sc.tensors["history"][0], grid.pos[ego, f_last - 21:f_last + 1:3])
    # Candidates whose ego lacks history/future or whose lanes are not straight are counted.
    assert set(drops) <= {"ego_history_incomplete", "ego_future_short", "lanes_not_straight"}


@pytest.fixture
def data_root(tmp_path: Path) -> Path:
    root = tmp_path / "ngsim"
    a = root / "us101" / "commonroad_us101_T-1"
    a.mkdir(parents=True)
    (root / "us101" / "commonroad_us101_2018b_extra").mkdir()
    shutil.copy(FIX / "commonroad" / "USA_US101-1_1_T-1.xml.gz", a)
    shutil.copy(FIX / "commonroad" / "USA_US101-26_1_T-1_cut.xml.gz", a)
    shutil.copy(FIX / "commonroad" / "USA_US101-7_1_T-1_cut.xml.gz", root / "us101" / "commonroad_us101_2018b_extra")
    shutil.copy(FIX / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    return root


def test_write_scenes_deterministic_and_split_only(data_root: Path, tmp_path: Path) -> None:
    outs = []
    for k in range(2):
        out = tmp_path / f"s{k}"
        paths, _, _ = write_scenes(data_root, out, ScenesConfig(split="test"), SplitConfig(), progress=False)
        assert paths
        outs.append({p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths})
        for p in paths:
            check_scenario(p)
            with safe_open(str(p), "np") as fh:
                assert fh.metadata()["split"] == "test"
    assert outs[0] == outs[1]
