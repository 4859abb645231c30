"""The two front ends report the same closed loop: the CLI's CSV (``nudge simulate``) and
``nudge.simulate``'s numpy columns come from the one records -> columns module of
``nudge-planner``, so the column names are identical and every value agrees (wall-clock timings
excepted). The CLI binary is ``$NUDGE_CLI``, else ``target/release/nudge`` (``make test`` builds
it)."""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import nudge

TIMING = {"mpc_s", "z_s", "z_median_s"}


def _cli(repo: Path) -> Path:
    exe = Path(os.environ.get("NUDGE_CLI", repo / "target" / "release" / "nudge"))
    assert exe.is_file(), f"the nudge CLI is not built at {exe} (cargo build --release, or set NUDGE_CLI)"
    return exe


def _read(path: Path) -> dict[str, list[str]]:
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    return {name: [r[i] for r in body] for i, name in enumerate(header)}


def _as_text(value: object) -> str:
    """A numpy/Python value as the CLI's CSV writes it (Rust's shortest round-trip form)."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if np.isnan(v):
            return "NaN"
        if np.isinf(v):
            return "inf" if v > 0 else "-inf"
        # Rust's Display: the shortest round-trip digits, never in exponent notation.
        return np.format_float_positional(v, unique=True, trim="-")
    return str(value)


@pytest.mark.parametrize(("predictor", "world"),
                         [("student", "teacher"), ("constant_velocity", "log_replay"), ("student", "idm")])
def test_cli_csv_and_python_columns_agree(repo: Path, tmp_path: Path, predictor: str, world: str) -> None:
    scenes_dir = tmp_path / "scenes"
    scenes_dir.mkdir()
    for p in nudge.scene_paths()[:2]:
        shutil.copy(p, scenes_dir / p.name)
    out = tmp_path / "out"
    args = [str(_cli(repo)), "simulate", "--scenes", str(scenes_dir), "--predictor", predictor, "--world", world,
            "--seed", "3", "--runs", "2", "--max-steps", "4", "--threads", "2", "--out", str(out),
            "--assets", str(nudge.assets_dir())]
    r = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    py = nudge.simulate(sorted(scenes_dir.glob("*.safetensors")), predictor, world=world, seed=3, runs=2,
                        max_steps=4, threads=1)
    for table, file in (("runs", "runs.csv"), ("steps", "steps.csv"), ("collisions", "collisions.csv")):
        cli = _read(out / file)
        columns = {k: v for k, v in py[table].items() if k != "ego"}
        assert list(cli) == list(columns), f"{file}: {list(cli)} vs {list(columns)}"
        for name, values in columns.items():
            if name in TIMING:
                continue
            assert cli[name] == [_as_text(v) for v in values], f"{table}.{name}"
    assert len(py["steps"]["run"]) > 0 and py["runs"]["world"][0] == world
