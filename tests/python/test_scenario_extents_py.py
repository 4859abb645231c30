"""Scenario files with lane extents ("nudge.scenario/2") written by the data pipeline in the
curvilinear road frame and read by the Rust reader; the straightened frame still writes
"nudge.scenario/1", which reads without extents."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from safetensors import safe_open

import nudge
from nudge_train.data.commonroad import read_commonroad
from nudge_train.data.scene_cmd import ScenesConfig, write_scenes
from nudge_train.data.splits import SplitConfig

FIX = Path(__file__).resolve().parents[2] / "python" / "train" / "tests" / "fixtures"


@pytest.fixture
def data_root(tmp_path: Path) -> Path:
    """Three fixture scenes in three overlap groups; in 9_1 (cut to five vehicles) vehicle 434
    drives in the auxiliary lane, which ends where it leaves the road."""
    root = tmp_path / "ngsim"
    a = root / "us101" / "commonroad_us101_T-1"
    b = root / "us101" / "commonroad_us101_2018b_extra"
    a.mkdir(parents=True)
    b.mkdir(parents=True)
    shutil.copy(FIX / "commonroad" / "USA_US101-1_1_T-1.xml.gz", a)
    shutil.copy(FIX / "commonroad" / "USA_US101-26_1_T-1_cut.xml.gz", a)
    shutil.copy(FIX / "commonroad" / "USA_US101-9_1_T-1_cut.xml.gz", a)
    shutil.copy(FIX / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    return root


def _write_all(root: Path, out: Path, frame: str) -> list[Path]:
    paths = []
    for split in ("train", "val", "test"):
        paths += write_scenes(root, out / split, ScenesConfig(split=split, frame=frame), SplitConfig(),
                              progress=False).written
    return paths


def test_frenet_scenes_carry_lane_extents_the_reader_returns(data_root: Path, tmp_path: Path) -> None:
    paths = _write_all(data_root, tmp_path / "fr", "frenet")
    assert paths
    table9 = read_commonroad(data_root / "us101" / "commonroad_us101_T-1" / "USA_US101-9_1_T-1_cut.xml.gz",
                             frame="frenet")
    ending = [ln for ln in table9.lanes.lanes if ln.ends]
    assert len(ending) == 1
    merges = 0
    for p in paths:
        with safe_open(str(p), "np") as fh:
            meta = fh.metadata()
            tensors = {k: fh.get_tensor(k) for k in fh.keys()}
        assert tensors["lane_extent"].dtype == np.float64 and tensors["lane_extent_real"].dtype == np.uint8
        assert meta["schema"] == "nudge.scenario/2"
        sc = nudge.Scenario.load(p)
        assert sc.metadata["schema"] == "nudge.scenario/2"
        ext, real = sc.lane_extents, sc.lane_extent_real
        assert ext is not None and real is not None
        assert ext.shape == real.shape == (sc.lane_centres.shape[0], 2)
        np.testing.assert_array_equal(ext, tensors["lane_extent"])
        np.testing.assert_array_equal(real, tensors["lane_extent_real"].astype(bool))
        ego_x = sc.history[0, -1, 0]
        assert ext[sc.ego_lane, 0] - 0.5 <= ego_x <= ext[sc.ego_lane, 1] + 0.5
        if sc.metadata["scene"] == table9.scene and real[sc.ego_lane, 1]:
            # The ego's lane is scene 9's auxiliary lane: its end is that lane's end.
            assert ext[sc.ego_lane, 1] == ending[0].s_end
            assert int(sc.agent_ids[0]) == 434
            merges += 1
    assert merges > 0


def test_straightened_scenes_stay_version_1(data_root: Path, tmp_path: Path) -> None:
    paths = _write_all(data_root, tmp_path / "st", "straightened")
    assert paths
    for p in paths:
        sc = nudge.Scenario.load(p)
        assert sc.metadata["schema"] == "nudge.scenario/1"
        assert sc.lane_extents is None and sc.lane_extent_real is None
