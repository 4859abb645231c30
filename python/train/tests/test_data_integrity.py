"""Integrity of the processed-data build: shards and manifest written temp-then-rename (a failed
or killed build leaves no half file under a final name, stale temp files are removed by the next
build), and every shard's sha256 recorded in the manifest is verified when a split is loaded."""

from __future__ import annotations

import gzip
import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nudge_train.data import build as build_mod
from nudge_train.data.build import BuildConfig, build
from nudge_train.data.loader import load_split
from nudge_train.data.sources import COIFMAN
from nudge_train.errors import ArtefactError

FIX = Path(__file__).parent / "fixtures"


@pytest.fixture
def data_root(tmp_path: Path) -> Path:
    root = tmp_path / "ngsim"
    a = root / "us101" / "commonroad_us101_T-1"
    a.mkdir(parents=True)
    for f in ("USA_US101-1_1_T-1.xml.gz", "USA_US101-26_1_T-1_cut.xml.gz", "USA_US101-7_1_T-1_cut.xml.gz"):
        shutil.copy(FIX / "commonroad" / f, a)
    shutil.copy(FIX / "commonroad_us101_scene_overlap_groups.csv", root / "us101")
    (root / "i80").mkdir()
    with open(FIX / "i80" / "coifman_cut.csv", "rb") as src, gzip.GzipFile(root / COIFMAN, "wb", mtime=0) as dst:
        dst.write(src.read())
    return root


def _hashes(d: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(d.iterdir())}


def test_load_split_verifies_the_manifest_hash(data_root: Path, tmp_path: Path) -> None:
    out = tmp_path / "p"
    build(BuildConfig(data_root=data_root, out=out), progress=False)
    ws = load_split(out, "train")
    assert len(ws) > 0
    shard = sorted(out.glob("train-*.safetensors"))[0]
    b = bytearray(shard.read_bytes())
    b[-5] ^= 0x01  # the last float of the last tensor: still loads, silently different
    shard.write_bytes(bytes(b))
    with pytest.raises(ArtefactError, match=rf"{shard.name}: sha256 .* does not match") as ei:
        load_split(out, "train")
    assert ei.value.path == str(shard)


def test_a_failed_write_leaves_no_file_under_a_final_name(data_root: Path, tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "p"

    def failing(src: object, dst: object) -> None:
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError, match="simulated"):
        build(BuildConfig(data_root=data_root, out=out), progress=False)
    monkeypatch.undo()
    assert not list(out.glob("*.safetensors")) and not (out / "manifest.json").exists()
    assert not list(out.glob(".*tmp*"))


def test_stale_temp_files_are_removed_and_rebuild_is_identical(data_root: Path, tmp_path: Path) -> None:
    ref = tmp_path / "ref"
    build(BuildConfig(data_root=data_root, out=ref), progress=False)
    out = tmp_path / "p"
    out.mkdir()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    for name in (f".train-000.safetensors.tmp-{dead.stdout.strip()}", f".manifest.json.tmp-{dead.stdout.strip()}"):
        (out / name).write_bytes(b"half")
    build(BuildConfig(data_root=data_root, out=out), progress=False)
    assert _hashes(out) == _hashes(ref)
    assert np.array_equal(load_split(out, "train").positions, load_split(ref, "train").positions)
    assert build_mod.WINDOWS_SCHEMA == "nudge.windows/1"
