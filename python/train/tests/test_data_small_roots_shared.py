"""Small data roots made of real files of the shared NGSIM folder (copied into a temporary root):
one or two overlap groups, a scene without an overlap-table row, an unusable overlap table, a
root with no usable scene. Every case ends in a reported decision (exit 0, printed and counted in
the manifest) or a ``DataError`` naming the file (exit 2), never a traceback.

Skipped when ``paths.ngsim()`` (../shared/data/ngsim or $NUDGE_NGSIM) is not present; the same
rules are checked on the small committed fixtures by ``test_data_small_roots.py``."""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

import pytest

from nudge_train import paths
from nudge_train.cli import main
from nudge_train.data.sources import OVERLAP_CSV, US101_DIRS

SHARED = paths.ngsim()
CR = SHARED / US101_DIRS[0]
pytestmark = pytest.mark.skipif(not (SHARED / OVERLAP_CSV).exists(), reason="../shared/data/ngsim not present")


def _overlap_rows() -> list[dict[str, str]]:
    with open(SHARED / OVERLAP_CSV, newline="") as fh:
        return list(csv.DictReader(fh))


def _root(tmp_path: Path, files: list[str], drop_scenes: tuple[int, ...] = (),
          blank_group: tuple[int, ...] = (), overlap: bool = True) -> Path:
    """A data root holding copies of ``files`` (CommonRoad 2020a names) and of the real overlap
    table, without the rows of ``drop_scenes`` and with an empty overlap_group for ``blank_group``."""
    root = tmp_path / "ngsim"
    d = root / US101_DIRS[0]
    d.mkdir(parents=True)
    for f in files:
        shutil.copy(CR / f, d / f)
    if overlap:
        rows = _overlap_rows()
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        for r in rows:
            if int(r["scene"]) in drop_scenes:
                continue
            if int(r["scene"]) in blank_group:
                r = {**r, "overlap_group": ""}
            w.writerow(r)
        (root / OVERLAP_CSV).write_text(buf.getvalue())
    return root


def _cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(args)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _build(root: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    return _cli(["data", "build", "--data-root", str(root), "--out", str(out), "--no-i80", "--no-progress"], capsys)


def _scenes(root: Path, out: Path, split: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    return _cli(["data", "scenes", "--data-root", str(root), "--out", str(out), "--split", split,
                 "--no-progress"], capsys)


def test_one_group_with_a_variant_and_the_modified_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Scene 1 (two variants, one overlap group) and the criticality-modified 3_5: one group ->
    everything to test; the variant and 3_5 excluded, each counted with its rule."""
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz", "USA_US101-1_2_T-1.xml.gz", "USA_US101-3_5_T-1.xml.gz"])
    rc, out, err = _build(root, tmp_path / "o", capsys)
    assert rc == 0, err
    man = json.loads((tmp_path / "o" / "manifest.json").read_text())
    by = {s["name"]: s for s in man["sources"]}
    assert by["USA_US101-1_1_T-1.xml.gz"]["split"] == "test"
    assert by["USA_US101-1_1_T-1.xml.gz"]["rule"] == "too_few_groups"
    assert by["USA_US101-1_2_T-1.xml.gz"]["rule"] == "duplicate_variant"
    assert by["USA_US101-3_5_T-1.xml.gz"]["rule"] == "criticality_modified"
    # Scene 1 is 6.1 s of 2 vehicles: windows exist and all are in test.
    assert man["splits"]["test"]["windows"] == by["USA_US101-1_1_T-1.xml.gz"]["windows"] > 0
    assert man["splits"]["train"]["windows"] == man["splits"]["val"]["windows"] == 0
    assert "only 1 US-101 overlap group(s): every unit to test" in out
    assert "excluded 1 source(s) (duplicate_variant)" in out
    assert "excluded 1 source(s) (criticality_modified)" in out
    rc, out, err = _scenes(root, tmp_path / "s", "test", capsys)
    assert rc == 0, err
    assert "only 1 US-101 overlap group(s)" in out
    assert len(list((tmp_path / "s").glob("*.safetensors"))) > 0
    rc, out, err = _scenes(root, tmp_path / "s_train", "train", capsys)
    assert rc == 0, err
    assert "wrote 0 scenarios" in out and "every unit to test" in out


def test_two_groups_go_to_test(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz", "USA_US101-29_1_T-1.xml.gz"])
    rc, out, err = _build(root, tmp_path / "o", capsys)
    assert rc == 0, err
    man = json.loads((tmp_path / "o" / "manifest.json").read_text())
    used = [s for s in man["sources"] if s["split"] != "excluded"]
    assert sorted(s["group"] for s in used) == ["us101-group-01", "us101-group-17"]
    assert all(s["split"] == "test" and s["rule"] == "too_few_groups" for s in used)
    assert "only 2 US-101 overlap group(s): every unit to test" in out
    rc, out, err = _scenes(root, tmp_path / "s", "test", capsys)
    assert rc == 0, err
    assert "only 2 US-101 overlap group(s)" in out


def test_scene_missing_from_the_overlap_table_is_excluded_and_reported(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz", "USA_US101-29_1_T-1.xml.gz"], drop_scenes=(29,))
    rc, out, err = _build(root, tmp_path / "o", capsys)
    assert rc == 0, err
    man = json.loads((tmp_path / "o" / "manifest.json").read_text())
    miss = next(s for s in man["sources"] if s["name"] == "USA_US101-29_1_T-1.xml.gz")
    assert miss["split"] == "excluded" and miss["rule"] == "no_overlap_group"
    assert "scene 29 has no row in commonroad_us101_scene_overlap_groups.csv" in miss["reason"]
    assert "excluded 1 source(s) (no_overlap_group)" in out
    rc, out, err = _scenes(root, tmp_path / "s", "test", capsys)
    assert rc == 0, err
    assert "excluded 1 source(s) (no_overlap_group)" in out
    assert not any(p.name.startswith("us101-29_") for p in (tmp_path / "s").glob("*.safetensors"))


def test_no_usable_scene_gives_an_empty_reported_build(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Every scene missing from the overlap table: an empty build that says why, and a report of it."""
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz"], drop_scenes=(1,))
    rc, out, err = _build(root, tmp_path / "o", capsys)
    assert rc == 0, err
    assert "0 windows" in out and "excluded 1 source(s) (no_overlap_group)" in out
    man = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert man["counts"]["windows"] == 0 and all(man["splits"][s]["shards"] == [] for s in man["splits"])
    doc = tmp_path / "data.md"
    rc, out, err = _cli(["data", "report", "--processed", str(tmp_path / "o"), "--doc", str(doc),
                         "--figures", str(tmp_path / "f")], capsys)
    assert rc == 0, err
    assert "| source excluded | no_overlap_group | 1 |" in doc.read_text()


@pytest.mark.parametrize("cmd", ["build", "scenes"])
def test_unknown_group_is_a_data_error_naming_the_row(tmp_path: Path, cmd: str,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """A scene whose overlap_group is empty: its group is unknown, which no split can guess."""
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz"], blank_group=(29,))
    row = 2 + [int(r["scene"]) for r in _overlap_rows()].index(29)
    args = (["data", "build", "--data-root", str(root), "--out", str(tmp_path / "o"), "--no-i80"] if cmd == "build"
            else ["data", "scenes", "--data-root", str(root), "--out", str(tmp_path / "s")])
    rc, out, err = _cli(args + ["--no-progress"], capsys)
    assert rc == 2 and "Traceback" not in err
    assert f"{root / OVERLAP_CSV}, row {row}: bad scene/overlap_group value" in err


@pytest.mark.parametrize("cmd", ["build", "scenes"])
def test_missing_overlap_table_is_a_data_error_naming_it(tmp_path: Path, cmd: str,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz"], overlap=False)
    args = (["data", "build", "--data-root", str(root), "--out", str(tmp_path / "o"), "--no-i80"] if cmd == "build"
            else ["data", "scenes", "--data-root", str(root), "--out", str(tmp_path / "s")])
    rc, out, err = _cli(args + ["--no-progress"], capsys)
    assert rc == 2 and "Traceback" not in err
    assert f"{root / OVERLAP_CSV}: cannot read" in err
    assert not (tmp_path / "o" / "manifest.json").exists()
