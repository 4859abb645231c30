"""python/train/scripts/closed_loop.py: the per-predictor summary agrees with the raw records."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

import nudge

SCRIPT = Path(__file__).resolve().parents[2] / "python" / "train" / "scripts" / "closed_loop.py"


def _module():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("closed_loop", SCRIPT)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["closed_loop"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_summary_matches_records(scenes: list[Path], tmp_path: Path) -> None:
    mod = _module()
    res = nudge.simulate(scenes[:3], "constant_velocity", world="teacher", world_predictor="teacher",
                         seed=2, runs=1, threads=1, max_steps=30)
    s = mod.summarise(res, nudge.DT)
    runs = res["runs"]
    assert s["runs"] == 3 and s["errors"] == 0
    assert s["success"] == np.mean(runs["success"])
    assert s["collisions"] == int(np.sum(runs["collision"]))
    assert s["agents_mean"] == np.mean(runs["n_agents"])
    assert s["steps"] == len(res["steps"]["run"]) == int(np.sum(runs["n_steps"]))
    first = res["steps"]["cost"][res["steps"]["run"] == 0].mean()
    assert s["mean_cost_per_run"][0] == first


def test_script_writes_the_table(repo: Path, tmp_path: Path) -> None:
    mod = _module()
    md, js = tmp_path / "t.md", tmp_path / "t.json"
    rc = mod.main(["--scenes", str(repo / "assets" / "scenes"), "--n", "2", "--predictors", "constant_velocity",
                   "student", "--threads", "1", "--markdown", str(md), "--json", str(js)])
    assert rc == 0
    rows = [line for line in md.read_text().splitlines() if line.startswith("| constant_velocity") or
            line.startswith("| student")]
    assert len(rows) == 2
    data = json.loads(js.read_text())
    assert set(data) == {"constant_velocity", "student"} and data["student"]["runs"] == 2
    assert mod.main(["--scenes", str(tmp_path), "--n", "2"]) == 2  # no scenario files: exit code 2
