"""`nudge-train closed-loop`: the per-predictor summary agrees with the raw records."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import nudge
from nudge_train.cli import main
from nudge_train.experiments.closed_loop import summarise


def test_summary_matches_records(scenes: list[Path], tmp_path: Path) -> None:
    res = nudge.simulate(scenes[:3], "constant_velocity", world="teacher", world_predictor="teacher",
                         seed=2, runs=1, threads=1, max_steps=30)
    s = summarise(res, nudge.DT)
    runs = res["runs"]
    assert s["runs"] == 3 and s["errors"] == 0
    assert s["success"] == np.mean(runs["success"])
    assert s["collisions"] == int(np.sum(runs["collision"]))
    assert s["agents_mean"] == np.mean(runs["n_agents"])
    assert s["steps"] == len(res["steps"]["run"]) == int(np.sum(runs["n_steps"]))
    first = res["steps"]["cost"][res["steps"]["run"] == 0].mean()
    assert s["mean_cost_per_run"][0] == first


def test_script_writes_the_table(repo: Path, tmp_path: Path) -> None:
    md, js = tmp_path / "t.md", tmp_path / "t.json"
    rc = main(["closed-loop", "--scenes", str(repo / "assets" / "scenes"), "--n", "2", "--predictors", "constant_velocity",
                   "student", "--threads", "1", "--markdown", str(md), "--json", str(js)])
    assert rc == 0
    rows = [line for line in md.read_text().splitlines() if line.startswith("| constant_velocity") or
            line.startswith("| student")]
    assert len(rows) == 2
    data = json.loads(js.read_text())
    assert set(data) == {"constant_velocity", "student"} and data["student"]["runs"] == 2
    assert main(["closed-loop", "--scenes", str(tmp_path), "--n", "2"]) == 2  # no scenario files: exit code 2
