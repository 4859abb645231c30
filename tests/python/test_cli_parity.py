"""The Python path (nudge.simulate) and the Rust CLI (`nudge simulate`, src/cli/simulate.rs)
give identical records for the same scenes and seeds (wall-clock timings excepted).

The CLI runs ``--runs R`` runs where run r uses scenario r mod #scenes (sorted directory order)
and seed ``--seed + r``; the same runs in Python are ``scene_seeds=[seed + r]``. The CLI binary
is ``$NUDGE_CLI``, else ``cargo run --release --bin nudge``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import nudge

REPO = Path(__file__).resolve().parents[2]


def _cli() -> list[str]:
    """``$NUDGE_CLI``, else ``cargo run --release`` (rebuilds the binary if it is older than the
    sources, so it runs the same planner code as the freshly built extension)."""
    exe = os.environ.get("NUDGE_CLI")
    if exe:
        return [exe]
    return ["cargo", "run", "--quiet", "--release", "--bin", "nudge", "--"]


@pytest.mark.parametrize(("predictor", "world"), [("student", "teacher"), ("teacher", "log-replay")])
def test_cli_and_python_give_identical_records(tmp_path: Path, predictor: str, world: str) -> None:
    scenes_dir = tmp_path / "scenes"
    scenes_dir.mkdir()
    picked = nudge.scene_paths()[:3]
    for p in picked:
        shutil.copy(p, scenes_dir / p.name)
    out = tmp_path / "out"
    seed, max_steps = 3, 4
    args = [*_cli(), "simulate", "--scenes", str(scenes_dir), "--predictor", predictor,
            "--weights", str(nudge.model_path(predictor)), "--world", world,
            "--world-weights", str(nudge.model_path("teacher")), "--seed", str(seed),
            "--runs", str(len(picked)), "--max-steps", str(max_steps), "--threads", "2", "--out", str(out)]
    r = subprocess.run(args, cwd=REPO, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr
    rust_runs = json.loads((out / "records.json").read_text())
    py = nudge.simulate(sorted(scenes_dir.glob("*.safetensors")), predictor,
                        world="predictor" if world == "teacher" else "log_replay",
                        world_predictor="teacher" if world == "teacher" else None,
                        scene_seeds=[seed + i for i in range(len(picked))], max_steps=max_steps, threads=1)
    runs, steps = py["runs"], py["steps"]
    assert [rr["scenario"] for rr in rust_runs] == runs["scenario"]
    for i, rr in enumerate(rust_runs):
        assert rr["seed"] == runs["seed"][i]
        assert rr["predictor"] == runs["predictor"][i] and rr["world"] == runs["world"][i]
        assert rr["target_lane"] == runs["target_lane"][i] and rr["y_target"] == runs["y_target"][i]
        assert rr["success"] == bool(runs["success"][i]) and rr["collision"] == bool(runs["collision"][i])
        assert (rr["steps_to_target"] if rr["steps_to_target"] is not None else -1) == runs["steps_to_target"][i]
        rows = np.flatnonzero(steps["run"] == i)
        assert len(rr["steps"]) == len(rows)
        for st, k in zip(rr["steps"], rows):
            # Bit-identical: the same Rust code on the same inputs.
            for f in ("step", "iterations", "predictor_calls", "status", "collision", "delta", "accel"):
                assert st[f] == steps[f][k], (i, int(k), f)
            for f in ("cost", "primal_residual"):
                assert st[f] == steps[f][k] or (st[f] is None and np.isnan(steps[f][k])), (i, int(k), f)
            mb = steps["min_b"][k]
            assert (st["min_b"] is None and np.isnan(mb)) or st["min_b"] == mb
            np.testing.assert_array_equal(np.asarray(st["ego"]), steps["ego"][k])
            assert len(st["z_updates_s"]) == steps["z_updates"][k]
