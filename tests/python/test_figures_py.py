"""nudge.figures (the wheel's `nudge-figures`, the `figures` extra): draws the runs `nudge
simulate --out` wrote as one PNG, and refuses a folder without records by name."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

import nudge
from nudge import figures

pytest.importorskip("matplotlib")
REPO = Path(__file__).resolve().parents[2]
NUDGE = Path(os.environ.get("NUDGE_CLI", REPO / "target" / "release" / "nudge"))


def test_runs_are_drawn_from_the_records(tmp_path: Path) -> None:
    if not NUDGE.is_file():
        pytest.fail(f"{NUDGE} missing: build the nudge command (make build)")
    out = tmp_path / "out"
    subprocess.run([str(NUDGE), "simulate", "--max-steps", "3", "--threads", "1", "--out", str(out)],
                   check=True, capture_output=True, cwd=REPO)
    png = tmp_path / "runs.png"
    assert figures.main(["runs", str(out), "--png", str(png), "--max-runs", "2"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    # The default scenes are the shipped ones (the package's assets).
    assert figures.plot_runs(records_dir=out, max_runs=1) == 0 and (out / "runs.png").is_file()


def test_a_folder_without_records_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert figures.main(["runs", str(tmp_path)]) == 2
    assert "records.json not found" in capsys.readouterr().err
    (tmp_path / "records.json").write_text('[{"a": 1, "a": 2}]')
    assert figures.main(["runs", str(tmp_path)]) == 2
    assert "duplicate key 'a'" in capsys.readouterr().err
    assert nudge.figures is figures
