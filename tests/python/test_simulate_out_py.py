"""`nudge.simulate(..., out=DIR)` writes the record set of `nudge simulate --out` by the same
writer: the same files, the same records (wall-clock timings excepted), a manifest that verifies,
and a complete `provenance.json` (docs/records.md) saying what a Python call used."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import nudge

TIMING = {"mpc_s", "z_s", "z_median_s"}
RECORD_TIMING = {"mpc_s", "z_updates_s"}
FILES = {"steps.csv", "runs.csv", "collisions.csv", "records.json", "provenance.json", "outputs.sha256"}


def _cli(repo: Path) -> Path:
    exe = Path(os.environ.get("NUDGE_CLI", repo / "target" / "release" / "nudge"))
    assert exe.is_file(), f"the nudge CLI is not built at {exe} (cargo build --release, or set NUDGE_CLI)"
    return exe


def _csv_without_timing(path: Path) -> list[list[str]]:
    rows = list(csv.reader(io.StringIO(path.read_text())))
    keep = [i for i, name in enumerate(rows[0]) if name not in TIMING]
    return [[r[i] for i in keep] for r in rows]


def _records_without_timing(path: Path) -> list[dict]:
    runs = json.loads(path.read_text())
    for r in runs:
        for s in r["steps"]:
            for k in RECORD_TIMING:
                del s[k]
    return runs


def _manifest_verifies(folder: Path) -> set[str]:
    listed = set()
    for line in (folder / "outputs.sha256").read_text().splitlines():
        digest, name = line.split("  ", 1)
        assert hashlib.sha256((folder / name).read_bytes()).hexdigest() == digest, name
        listed.add(name)
    return listed


def test_python_and_cli_write_the_same_record_set(repo: Path, tmp_path: Path) -> None:
    scenes_dir = tmp_path / "scenes"
    scenes_dir.mkdir()
    for p in nudge.scene_paths()[:2]:
        shutil.copy(p, scenes_dir / p.name)
    cli_out, py_out = tmp_path / "cli", tmp_path / "py"
    args = [str(_cli(repo)), "simulate", "--scenes", str(scenes_dir), "--predictor", "student", "--world", "idm",
            "--seed", "3", "--runs", "2", "--max-steps", "5", "--threads", "1", "--out", str(cli_out),
            "--assets", str(nudge.assets_dir())]
    r = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    res = nudge.simulate(sorted(scenes_dir.glob("*.safetensors")), "student", world="idm", seed=3, runs=2,
                         max_steps=5, threads=1, out=py_out)
    assert len(res["runs"]["seed"]) == 4
    assert {p.name for p in py_out.iterdir()} == {p.name for p in cli_out.iterdir()} == FILES
    assert _manifest_verifies(py_out) == _manifest_verifies(cli_out) == FILES - {"outputs.sha256"}
    for name in ("runs.csv", "collisions.csv"):
        assert (py_out / name).read_bytes() == (cli_out / name).read_bytes(), name
    assert _csv_without_timing(py_out / "steps.csv") == _csv_without_timing(cli_out / "steps.csv")
    assert len(_csv_without_timing(py_out / "steps.csv")) > 4
    assert _records_without_timing(py_out / "records.json") == _records_without_timing(cli_out / "records.json")

    py, cli = (json.loads((d / "provenance.json").read_text()) for d in (py_out, cli_out))
    assert py.keys() == cli.keys()
    # The binary and the extension each record their own build's commit (the same in CI).
    differ = {"command", "cwd", "created_unix_s", "git_sha"}
    for k in py.keys() - differ:
        assert py[k] == cli[k], k
    assert py["git_sha"] == nudge.GIT_SHA
    assert py["command"] == [sys.executable, *sys.argv]
    assert py["cwd"] == os.getcwd()
    assert py["planner"] is None and py["settings_file"] is None and py["config_file"] is None
    assert py["predictor"]["file"]["sha256"] == hashlib.sha256(nudge.model_path("student").read_bytes()).hexdigest()
    assert py["seeds"] == {"base": 3, "runs_per_scene": 2, "runs": [3, 4, 5, 6]}
    assert py["threads"] == 1 and py["sim_config"]["max_steps"] == 5 and py["world"]["world"] == "idm"
    assert [Path(f["path"]).name for f in py["scenes"]["files"]] == sorted(p.name for p in scenes_dir.iterdir())


class Straight:
    """Keeps its lane at constant speed; counts its calls."""

    calls = 0

    def plan(self, obs: dict) -> dict:
        Straight.calls += 1
        return {"delta": [0.0] * obs["horizon"], "accel": [0.0] * obs["horizon"]}


def test_a_python_planner_and_predictor_are_named_in_provenance(scenes: list[Path], tmp_path: Path) -> None:
    nudge.simulate(scenes[:1], "constant_velocity", planner=Straight(), world="log_replay", max_steps=3,
                   out=tmp_path / "planner")
    p = json.loads((tmp_path / "planner" / "provenance.json").read_text())
    assert p["planner"] == "python:Straight"
    assert p["predictor"] == {"name": "constant_velocity", "file": None}
    records = json.loads((tmp_path / "planner" / "records.json").read_text())
    assert {s["decided_by"] for s in records[0]["steps"]} == {"external"}

    class Still:
        horizon = 6

        def predict(self, history, candidates):  # noqa: ANN001, ANN202
            import numpy as np

            h = np.asarray(history)
            return np.repeat(h[None, 1:, -1:, :], len(candidates), axis=0).repeat(6, axis=2)

    nudge.simulate(scenes[:1], Still(), world="log_replay", max_steps=2, out=tmp_path / "predictor")
    p = json.loads((tmp_path / "predictor" / "provenance.json").read_text())
    assert p["predictor"] == {"name": "python", "file": None} and p["planner"] is None


def test_an_out_that_cannot_be_a_folder_is_refused_before_any_run(scenes: list[Path], tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    Straight.calls = 0
    with pytest.raises(nudge.NudgeError, match="out .*file: exists and is not a directory"):
        nudge.simulate(scenes[:1], "constant_velocity", planner=Straight(), world="log_replay", max_steps=2,
                       out=blocker)
    assert Straight.calls == 0
