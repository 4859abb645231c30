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
EXTENTS = {"lane_extent": np.float64, "lane_extent_real": np.uint8}
"""The tensors a ``nudge.scenario/2`` file (curvilinear frame) adds."""


def check_scenario(path: Path) -> dict[str, np.ndarray]:
    with safe_open(str(path), "np") as fh:
        meta = fh.metadata()
        t = {k: fh.get_tensor(k) for k in fh.keys()}
    v2 = meta.get("schema") == "nudge.scenario/2"
    spec = {**SPEC, **EXTENTS} if v2 else SPEC
    assert set(t) == set(spec)
    for k, dt in spec.items():
        assert t[k].dtype == dt, k
    assert set(meta) == META
    assert meta["schema"] in ("nudge.scenario/1", "nudge.scenario/2") and meta["dt"] == "0.3"
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
    if v2:  # every lane at the ego's x: where it begins and ends, the ego's x inside its own lane's extent
        ext, real = t["lane_extent"], t["lane_extent_real"]
        assert ext.shape == (lc.shape[0], 2) and real.shape == ext.shape and set(np.unique(real)) <= {0, 1}
        x = t["history"][0, -1, 0]
        assert np.all(ext[:, 0] <= x) and np.all(ext[:, 1] >= x)
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
        paths = write_scenes(data_root, out, ScenesConfig(split="test"), SplitConfig(), progress=False).written
        assert paths
        outs.append({p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths})
        for p in paths:
            check_scenario(p)
            with safe_open(str(p), "np") as fh:
                assert fh.metadata()["split"] == "test"
    assert outs[0] == outs[1]


def test_write_scenes_counts_merges_and_removes_stale_files(tmp_path: Path) -> None:
    """data scenes in the curvilinear frame (the default): summary.json counts the files written,
    and a scenario counts as a merge exactly when its ego, read back from the raw scene, is in a
    lane that ends ahead (``LaneMap.ending_lane`` of the reader, the independent truth); scenario
    files of an earlier run that this one does not write are removed, other files are kept."""
    import json

    from nudge_train.data.scenarios import is_merge_scenario

    root = tmp_path / "ngsim"
    a = root / "us101" / "commonroad_us101_T-1"
    a.mkdir(parents=True)
    for name in ("USA_US101-1_1_T-1.xml.gz", "USA_US101-26_1_T-1_cut.xml.gz", "USA_US101-9_1_T-1_cut.xml.gz"):
        shutil.copy(FIX / "commonroad" / name, a)
    shutil.copy(FIX / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    table9 = read_commonroad(a / "USA_US101-9_1_T-1_cut.xml.gz")
    total_merges = 0
    for split in ("train", "val", "test"):
        out = tmp_path / split
        out.mkdir()
        (out / "us101-0_0-t00.0-ego0.safetensors").write_bytes(b"stale")
        (out / "notes.txt").write_text("kept")
        res = write_scenes(root, out, ScenesConfig(split=split), SplitConfig(), progress=False)
        assert not (out / "us101-0_0-t00.0-ego0.safetensors").exists() and (out / "notes.txt").exists()
        assert res.removed == 1
        summary = json.loads((out / "summary.json").read_text())
        assert summary["road_frame"] == "frenet" and summary["scenarios"] == len(res.written)
        assert sorted(p.name for p in out.glob("us101-*.safetensors")) == sorted(p.name for p in res.written)
        assert summary["scenarios"] == sum(v["scenarios"] for v in summary["per_scene"].values())
        merges = 0
        for p in res.written:
            with safe_open(str(p), "np") as fh:
                t = {k: fh.get_tensor(k) for k in fh.keys()}
                scene = fh.metadata()["scene"]
            merge = is_merge_scenario(t)
            ego = t["history"][0, -1]
            want = scene == table9.scene and bool(table9.lanes.ending_lane(ego[:1], ego[1:])[0])
            assert merge == want, p.name
            merges += merge
        assert summary["merge_scenarios"] == merges == len(res.merges)
        total_merges += merges
    assert total_merges > 0  # vehicle 434 of scene 9 in the auxiliary lane that ends


def test_build_and_report_count_merge_windows_and_scenarios(tmp_path: Path) -> None:
    """data build (curvilinear frame by default) counts per source and split the windows with an
    agent in a lane that ends ahead, checked against the shards read back and the reader's lane
    map; data report shows those counts, each scene's mapping residual and the scenario counts
    that data scenes recorded."""
    import json

    from safetensors.numpy import load_file

    from nudge_train.cli import main

    root = tmp_path / "ngsim"
    a = root / "us101" / "commonroad_us101_T-1"
    a.mkdir(parents=True)
    for name in ("USA_US101-1_1_T-1.xml.gz", "USA_US101-26_1_T-1_cut.xml.gz", "USA_US101-9_1_T-1_cut.xml.gz"):
        shutil.copy(FIX / "commonroad" / name, a)
    shutil.copy(FIX / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    out = tmp_path / "p"
    assert main(["data", "build", "--data-root", str(root), "--out", str(out), "--no-i80", "--no-progress"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["config"]["road_frame"] == "frenet"
    tables = {name: read_commonroad(a / name) for name in (s["name"] for s in man["sources"] if s.get("windows"))}
    want: dict[str, int] = {}
    for split, sp in man["splits"].items():
        n_split = 0
        for sh in sp["shards"]:
            d = load_file(str(out / sh["file"]))
            for w in range(d["offsets"].shape[0] - 1):
                src = man["sources"][int(d["source"][w])]["name"]
                lo, hi = int(d["offsets"][w]), int(d["offsets"][w + 1])
                last = d["positions"][lo:hi, 7].astype(np.float64) + d["origin"][w].astype(np.float64)
                merge = bool(tables[src].lanes.ending_lane(last[:, 0], last[:, 1]).any())
                want[src] = want.get(src, 0) + merge
                n_split += merge
        assert sp["merge_windows"] == n_split, split
    for s in man["sources"]:
        if s.get("windows"):
            assert s["merge_windows"] == want.get(s["name"], 0), s["name"]
    assert want["USA_US101-9_1_T-1_cut.xml.gz"] > 0 and want["USA_US101-1_1_T-1.xml.gz"] == 0
    nine = next(s for s in man["sources"] if s["name"] == "USA_US101-9_1_T-1_cut.xml.gz")
    for split in ("train", "val", "test"):
        write_scenes(root, out / "scenes" / split, ScenesConfig(split=split), SplitConfig(), progress=False)
    doc = tmp_path / "data.md"
    assert main(["data", "report", "--processed", str(out), "--doc", str(doc), "--figures", str(tmp_path / "f")]) == 0
    text = doc.read_text()
    row = next(ln for ln in text.splitlines() if ln.startswith("| USA_US101-9_1_T-1_cut.xml.gz |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[5] == str(nine["merge_windows"])
    assert cells[6] == f"{nine['reader_notes']['lane_straightness_cm'] / 100:.2f}"
    assert "## Planner scenarios per split" in text
    summary = json.loads((out / "scenes" / nine["split"] / "summary.json").read_text())
    srow = next(ln for ln in text.splitlines() if ln.startswith(f"| {nine['split']} | frenet |"))
    assert f"| {summary['scenarios']} | {summary['merge_scenarios']} | {summary['ramp_scenarios']} |" in srow
    assert summary["merge_scenarios"] > 0


@pytest.mark.parametrize("frame", ["frenet", "straightened"])
def test_candidate_with_an_agent_off_the_road_is_dropped(frame: str) -> None:
    """A neighbour observed more than 2 m outside the road edges at the ego's x (the planner's
    scenario loader refuses such a file) drops the candidate as agent_off_road; 1.5 m outside
    (a shoulder) is kept."""
    from collections import Counter

    from nudge_train.data.scenarios import scenario_at

    table = read_commonroad(FIX / "commonroad" / "USA_US101-26_1_T-1_cut.xml.gz", frame=frame)
    grid = build_grid(table)
    cfg = ScenarioConfig()
    found = scene_scenarios(table, grid, cfg, "test", Counter(), "p")
    sc, f_last = next((s, f) for s, f in found if s.n_agents >= 2)
    ego_row = int(np.flatnonzero(grid.ids == sc.tensors["agent_ids"][0])[0])
    nb_row = int(np.flatnonzero(grid.ids == sc.tensors["agent_ids"][1])[0])
    left = float(sc.tensors["lane_bounds"][-1])
    stride = int(round(cfg.step_s / grid.dt))
    for beyond, kept in ((1.5, True), (2.5, False)):
        g = build_grid(table)
        g.pos[nb_row, f_last - 3 * stride, 1] = left + beyond
        drops: Counter = Counter()
        got = scenario_at(table, g, ego_row, f_last, cfg, "test", drops, "p")
        assert (got is not None) == kept and drops["agent_off_road"] == (0 if kept else 1)
