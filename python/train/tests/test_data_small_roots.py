"""Small and irregular data roots: one or two overlap groups, scenes missing from the overlap
table, files that are not US-101 benchmark scenes. Each gives a reported decision (never a
traceback): too few groups to split -> every unit to ``test``; no overlap group or no benchmark id
-> the file is excluded with its reason; both are counted in the manifest, printed by the CLI and
listed by the dataset report."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from nudge_train.cli import main
from nudge_train.data.build import BuildConfig, build
from nudge_train.data.scene_cmd import ScenesConfig, write_scenes
from nudge_train.data.splits import SplitConfig

FIX = Path(__file__).parent / "fixtures"
OVERLAP = "commonroad_us101_scene_overlap_groups.csv"


def _root(tmp_path: Path, files: list[str], overlap_text: str | None = None) -> Path:
    root = tmp_path / "ngsim"
    d = root / "us101" / "commonroad_us101_T-1"
    d.mkdir(parents=True)
    for f in files:
        shutil.copy(FIX / "commonroad" / f, d)
    text = overlap_text if overlap_text is not None else (FIX / OVERLAP).read_text()
    (root / "us101" / OVERLAP).write_text(text)
    return root


@pytest.mark.parametrize("files", [
    ["USA_US101-1_1_T-1.xml.gz"],
    ["USA_US101-1_1_T-1.xml.gz", "USA_US101-26_1_T-1_cut.xml.gz"],
])
def test_one_or_two_groups_go_to_test_and_are_reported(tmp_path: Path, files: list[str],
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    root = _root(tmp_path, files)
    out = tmp_path / "o"
    rc = main(["data", "build", "--data-root", str(root), "--out", str(out), "--no-i80", "--no-progress"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    man = json.loads((out / "manifest.json").read_text())
    used = [s for s in man["sources"] if s["kind"] == "commonroad"]
    assert len(used) == len(files)
    assert all(s["split"] == "test" and s["rule"] == "too_few_groups" for s in used)
    assert all(f"only {len(files)} US-101 overlap group(s)" in s["reason"] for s in used)
    assert man["splits"]["test"]["windows"] == sum(s["windows"] for s in used) > 0
    assert man["splits"]["train"]["windows"] == 0 and man["splits"]["train"]["shards"] == []
    assert f"only {len(files)} US-101 overlap group" in cap.out and "every unit to test" in cap.out
    # The planner scenes of the same root: the same decision, no traceback.
    capsys.readouterr()
    rc = main(["data", "scenes", "--data-root", str(root), "--split", "test", "--out", str(tmp_path / "s"),
               "--no-progress"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert f"only {len(files)} US-101 overlap group" in cap.out
    assert list((tmp_path / "s").glob("*.safetensors"))


def test_missing_overlap_entry_excludes_that_file_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = (FIX / OVERLAP).read_text().splitlines()
    kept = [ln for ln in text if not ln.startswith("26,")]
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz", "USA_US101-26_1_T-1_cut.xml.gz"],
                 "\n".join(kept) + "\n")
    shutil.copy(FIX / "commonroad" / "USA_US101-7_1_T-1_cut.xml.gz", root / "us101" / "commonroad_us101_T-1")
    (root / "us101" / "commonroad_us101_T-1" / "notes.xml").write_text("<commonRoad/>")
    out = tmp_path / "o"
    rc = main(["data", "build", "--data-root", str(root), "--out", str(out), "--no-i80", "--no-progress"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    man = json.loads((out / "manifest.json").read_text())
    by_name = {s["name"]: s for s in man["sources"]}
    miss = by_name["USA_US101-26_1_T-1_cut.xml.gz"]
    assert miss["split"] == "excluded" and miss["rule"] == "no_overlap_group"
    assert OVERLAP in miss["reason"] and "scene 26" in miss["reason"]
    stray = by_name["notes.xml"]
    assert stray["split"] == "excluded" and stray["rule"] == "not_us101_benchmark"
    # The two remaining groups: too few to split, both to test.
    assert {by_name[n]["split"] for n in ("USA_US101-1_1_T-1.xml.gz", "USA_US101-7_1_T-1_cut.xml.gz")} == {"test"}
    assert "excluded 1 source(s) (no_overlap_group)" in cap.out
    assert "excluded 1 source(s) (not_us101_benchmark)" in cap.out
    # The dataset report lists every drop reason with its count.
    doc = tmp_path / "data.md"
    assert main(["data", "report", "--processed", str(out), "--doc", str(doc), "--figures", str(tmp_path / "f")]) == 0
    report = doc.read_text()
    assert "## Everything dropped, by reason" in report
    assert "| source excluded | no_overlap_group | 1 |" in report
    assert "| source excluded | not_us101_benchmark | 1 |" in report
    assert "| split decision | too_few_groups | 2 |" in report


def test_three_groups_still_split_three_ways(tmp_path: Path) -> None:
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz", "USA_US101-26_1_T-1_cut.xml.gz",
                            "USA_US101-7_1_T-1_cut.xml.gz"])
    man = build(BuildConfig(data_root=root, out=tmp_path / "o", include_i80=False), progress=False)
    assert {s["split"] for s in man["sources"]} == {"train", "val", "test"}
    assert not any("rule" in s for s in man["sources"])


def test_overlap_table_conflicts_and_garbage_are_data_errors(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    text = (FIX / OVERLAP).read_text().splitlines()
    row = next(ln for ln in text if ln.startswith("26,")).split(",")
    row[text[0].split(",").index("overlap_group")] = "99"
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz"], "\n".join(text + [",".join(row)]) + "\n")
    rc = main(["data", "build", "--data-root", str(root), "--out", str(tmp_path / "o"), "--no-i80", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert f"{OVERLAP}, row {len(text) + 1}: scene 26 listed twice" in err
    (root / "us101" / OVERLAP).write_text("scene,overlap_group\n1,one\n")
    rc = main(["data", "build", "--data-root", str(root), "--out", str(tmp_path / "o"), "--no-i80", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and f"{OVERLAP}, row 2" in err


def test_write_scenes_reports_source_decisions(tmp_path: Path) -> None:
    root = _root(tmp_path, ["USA_US101-1_1_T-1.xml.gz"])
    res = write_scenes(root, tmp_path / "s", ScenesConfig(split="train"), SplitConfig(), progress=False)
    assert res.written == [] and any("only 1 US-101 overlap group" in n for n in res.notes)
