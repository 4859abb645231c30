"""End-to-end build on a data root assembled from the fixtures: format, splits, determinism.
Tests marked with the shared data run on the raw NGSIM folder (``paths.ngsim()``: ../shared/data/ngsim or
$NUDGE_NGSIM) when present and skip otherwise."""

from __future__ import annotations

import gzip
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from safetensors import safe_open
from safetensors.numpy import load_file

from nudge_train import paths
from nudge_train.cli import main
from nudge_train.data.build import BuildConfig, build, time_blocks
from nudge_train.data.coifman import read_coifman
from nudge_train.data.grid import build_grid
from nudge_train.data.sources import COIFMAN, us101_sources
from nudge_train.data.splits import SplitConfig, assign, read_overlap_groups, scene_number
from nudge_train.data.windows import WindowConfig, extract_windows

FIX = Path(__file__).parent / "fixtures"
SHARED = paths.ngsim()
needs_shared = pytest.mark.skipif(not (SHARED / COIFMAN).exists(), reason="../shared/data/ngsim not present")


@pytest.fixture
def data_root(tmp_path: Path) -> Path:
    root = tmp_path / "ngsim"
    a = root / "us101" / "commonroad_us101_T-1"
    b = root / "us101" / "commonroad_us101_2018b_extra"
    a.mkdir(parents=True)
    b.mkdir(parents=True)
    shutil.copy(FIX / "commonroad" / "USA_US101-1_1_T-1.xml.gz", a)
    shutil.copy(FIX / "commonroad" / "USA_US101-26_1_T-1_cut.xml.gz", a)
    shutil.copy(FIX / "commonroad" / "USA_US101-7_1_T-1_cut.xml.gz", b)
    shutil.copy(FIX / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    (root / "i80").mkdir()
    with open(FIX / "i80" / "coifman_cut.csv", "rb") as src, gzip.GzipFile(root / COIFMAN, "wb", mtime=0) as dst:
        dst.write(src.read())
    return root


def _hashes(d: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(d.iterdir())}


def test_build_format_and_determinism(data_root: Path, tmp_path: Path) -> None:
    raw = (FIX / "raw" / "peachtree_cut_25col.csv",)
    m1 = build(BuildConfig(data_root=data_root, out=tmp_path / "a", raw=raw), progress=False)
    m2 = build(BuildConfig(data_root=data_root, out=tmp_path / "b", raw=raw), progress=False)
    assert m1 == m2
    assert _hashes(tmp_path / "a") == _hashes(tmp_path / "b")
    man = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert man["schema"] == "nudge.dataset/1"
    total = 0
    for split, sp in man["splits"].items():
        for sh in sp["shards"]:
            path = tmp_path / "a" / sh["file"]
            assert hashlib.sha256(path.read_bytes()).hexdigest() == sh["sha256"]
            with safe_open(str(path), "np") as fh:
                assert fh.metadata() == {"schema": "nudge.windows/1", "split": split}
            d = load_file(str(path))
            w, a = sh["windows"], sh["agents"]
            assert d["offsets"].dtype == np.int64 and d["offsets"].shape == (w + 1,)
            assert d["offsets"][0] == 0 and d["offsets"][-1] == a and np.all(np.diff(d["offsets"]) >= 2)
            assert d["positions"].dtype == np.float32 and d["positions"].shape == (a, 14, 2)
            assert d["size"].shape == (a, 2) and d["agent_lane_change"].shape == (a,)
            assert d["interactive"].dtype == np.uint8 and d["interactive"].shape == (w,)
            assert d["source"].shape == (w,) and d["t0"].shape == (w,) and d["origin"].shape == (w, 2)
            # Ego (first agent) sits at the origin at the last observed step.
            egos = d["positions"][d["offsets"][:-1], 7]
            np.testing.assert_allclose(egos, 0.0, atol=1e-5)
            # interactive == any agent lane change in the window.
            lc = np.add.reduceat(d["agent_lane_change"].astype(np.int64), d["offsets"][:-1]) > 0
            assert np.array_equal(lc, d["interactive"].astype(bool))
            for s in np.unique(d["source"]):
                assert man["sources"][int(s)]["split"] == split
            total += w
    assert total == man["counts"]["windows"] > 0
    kinds = {s["kind"] for s in man["sources"] if s.get("windows")}
    assert kinds == {"commonroad", "coifman_block"}
    # The raw rows are read and recorded (too few overlapping vehicles for a 3.9 s window).
    raw_src = [s for s in man["sources"] if s["kind"] == "raw_block"]
    assert raw_src and all(s["reader_notes"]["duplicate_keys_in_file"] == 19 for s in raw_src)
    # Three overlap groups -> one per split.
    us = {s["split"] for s in man["sources"] if s["kind"] == "commonroad"}
    assert us == {"train", "val", "test"}


def test_cli_build_and_report(data_root: Path, tmp_path: Path) -> None:
    out = tmp_path / "p"
    assert main(["data", "build", "--data-root", str(data_root), "--out", str(out), "--no-progress", "--phases", "0"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["config"]["phases"] == [0]
    doc = tmp_path / "docs" / "data.md"
    assert main(["data", "report", "--processed", str(out), "--doc", str(doc), "--figures", str(tmp_path / "docs" / "figures")]) == 0
    text = doc.read_text()
    assert "## Windows per split and source" in text and "## What the filters dropped" in text
    assert (tmp_path / "docs" / "figures" / "data_distributions.png").stat().st_size > 1000


def test_assign_is_seeded_and_partitions() -> None:
    w = {f"g{i}": float(10 + i) for i in range(15)}
    a = assign(w, SplitConfig(seed=3), salt=1)
    assert a == assign(w, SplitConfig(seed=3), salt=1)
    assert set(a) == set(w) and set(a.values()) == {"train", "val", "test"}
    tot = sum(w.values())
    test = sum(w[k] for k, s in a.items() if s == "test") / tot
    val = sum(w[k] for k, s in a.items() if s == "val") / tot
    assert abs(test - 0.2) < 0.03 and abs(val - 0.08) < 0.03


def test_i80_blocks_windows_stay_inside() -> None:
    t = read_coifman(FIX / "i80" / "coifman_cut.csv")
    blocks = time_blocks(t, 3.0)
    assert blocks[0][0] == 1262 and blocks[-1][1] == 1325
    assert all(b[1] == c[0] for b, c in zip(blocks, blocks[1:]))
    ws_all = []
    for lo, hi in blocks:
        ws = extract_windows(build_grid(t, lo, hi), WindowConfig(step_s=0.1, n_obs=8, n_fut=6, phases=(0,)))
        for w in ws:
            first = w.t0 - 0.7
            last = w.t0 + 0.6
            assert lo * 0.1 - 1e-6 <= first and last <= (hi - 1) * 0.1 + 1e-6
        ws_all += ws
    assert ws_all


@needs_shared
def test_real_us101_groups_never_straddle_splits() -> None:
    entries = us101_sources(SHARED, SplitConfig())
    groups = read_overlap_groups(SHARED / "us101" / "commonroad_us101_scene_overlap_groups.csv")
    by_group: dict[str, set[str]] = {}
    for e in entries:
        if e.split == "excluded":
            continue
        scene, _ = scene_number(e.name)
        assert e.group == f"us101-group-{groups[scene]:02d}"
        by_group.setdefault(e.group, set()).add(e.split)
    assert all(len(s) == 1 for s in by_group.values())
    assert {s for v in by_group.values() for s in v} == {"train", "val", "test"}
    ex = {e.name: e.split for e in entries}
    assert ex["USA_US101-3_5_T-1.xml.gz"] == "excluded"
    # One variant per scene is used.
    used = [scene_number(e.name)[0] for e in entries if e.split != "excluded"]
    assert len(used) == len(set(used)) == 27


@needs_shared
def test_real_build_us101_counts(tmp_path: Path) -> None:
    man = build(BuildConfig(data_root=SHARED, out=tmp_path / "o", include_i80=False), progress=False)
    us = sum(s.get("windows", 0) for s in man["sources"])
    # ~1,200 windows of 14 steps with starts every 0.1 s (27 scenes; filters drop a few).
    assert 1100 <= us <= 1400
    for s in man["sources"]:
        if s["split"] == "excluded":
            assert "windows" not in s


@pytest.mark.skipif(not (SHARED / "raw_sample").exists(), reason="../shared/data/ngsim not present")
def test_real_raw_sample_gives_windows() -> None:
    from nudge_train.data.raw import read_raw_ngsim

    path = next((SHARED / "raw_sample").glob("*.csv.gz"))
    tables = read_raw_ngsim(path)
    assert sum(len(t) for t in tables) == 5000  # no duplicate rows within a period
    n = sum(len(extract_windows(build_grid(t), WindowConfig())) for t in tables)
    assert n > 100
