"""Results people can load: nudge.to_frames (pandas DataFrames with the documented columns of
docs/records.md) and nudge.simulate(progress=...)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import nudge

REPO = Path(__file__).resolve().parents[2]
TIMING = {"mpc_s", "z_s", "z_median_s"}


def _documented(file: str) -> list[str]:
    """The column names of the section of ``file`` in docs/records.md, in order."""
    text = (REPO / "docs" / "records.md").read_text()
    body = text.split(f"## `{file}`", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `([^`]+)`", body, flags=re.M)


@pytest.fixture(scope="module")
def result(scenes: list[Path]) -> dict:
    return nudge.simulate(scenes[:2], "constant_velocity", runs=2, threads=2, max_steps=3)


def test_the_raw_steps_table_is_not_a_frame_but_to_frames_is(result: dict) -> None:
    # The reason for to_frames: the steps hold the 2-D ego column.
    with pytest.raises(ValueError):
        pd.DataFrame(result["steps"])
    frames = nudge.to_frames(result)
    assert set(frames) == {"runs", "steps", "collisions"}
    for name in frames:
        assert list(frames[name].columns) == _documented(f"{name}.csv"), name
    runs, steps = frames["runs"], frames["steps"]
    assert len(runs) == 4 and len(steps) == int(result["runs"]["n_steps"].sum())
    np.testing.assert_array_equal(steps["v"].to_numpy(), result["steps"]["ego"][:, 3])
    assert runs["scenario"].tolist() == result["runs"]["scenario"]
    assert runs["error"].isna().all()
    # Per-run aggregation works as on any frame.
    per_run = steps.groupby("run")["step"].count()
    np.testing.assert_array_equal(per_run.to_numpy(), result["runs"]["n_steps"])


def test_to_frames_refuses_what_is_not_a_result() -> None:
    with pytest.raises(nudge.InputError, match="to_frames"):
        nudge.to_frames({"runs": {}})


def test_a_progress_callable_sees_every_run_and_changes_nothing(scenes: list[Path], result: dict) -> None:
    calls: list[tuple[int, int]] = []
    r = nudge.simulate(scenes[:2], "constant_velocity", runs=2, threads=2, max_steps=3,
                       progress=lambda done, total: calls.append((done, total)))
    assert calls and calls[-1] == (4, 4)
    assert all(total == 4 for _, total in calls)
    done = [d for d, _ in calls]
    assert done == sorted(done) and len(set(done)) == len(done)
    for table in ("runs", "steps"):
        for k, v in result[table].items():
            if k not in TIMING:
                np.testing.assert_array_equal(np.asarray(r[table][k]), np.asarray(v), err_msg=k)


def test_a_failing_progress_callable_stops_the_batch(scenes: list[Path]) -> None:
    def boom(done: int, total: int) -> None:
        raise RuntimeError(f"stop at {done}/{total}")

    with pytest.raises(RuntimeError, match="stop at"):
        nudge.simulate(scenes[:2], "constant_velocity", max_steps=3, progress=boom)


@pytest.mark.parametrize("bad", ["yes", 3])
def test_progress_must_be_a_flag_or_a_callable(scenes: list[Path], bad: object) -> None:
    with pytest.raises(nudge.InputError, match="progress"):
        nudge.simulate(scenes[:1], "constant_velocity", max_steps=2, progress=bad)
    with pytest.raises(nudge.InputError, match="progress"):
        nudge._native.simulate([str(scenes[0])], "constant_velocity", max_steps=2, progress=bad)


def test_progress_true_draws_on_stderr_without_tqdm(scenes: list[Path], capsys: pytest.CaptureFixture,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "tqdm.auto", None)  # import fails: the plain line
    nudge.simulate(scenes[:2], "constant_velocity", max_steps=2, progress=True)
    err = capsys.readouterr().err
    assert "nudge.simulate: 2/2 runs" in err and err.endswith("\n")


def test_progress_true_uses_tqdm_when_installed(scenes: list[Path], capsys: pytest.CaptureFixture) -> None:
    pytest.importorskip("tqdm")
    nudge.simulate(scenes[:2], "constant_velocity", max_steps=2, progress=True)
    assert "2/2" in capsys.readouterr().err
