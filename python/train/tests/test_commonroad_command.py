"""`nudge-train commonroad` drives the `nudge` command wherever it runs: the command and its
models are resolved by the package (not the working directory), and a failing command is a
typed error carrying its message (not a bare CalledProcessError)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from nudge_train import paths
from nudge_train.errors import NudgeTrainError
from nudge_train.experiments.commonroad_check import CommandError, _simulate, find_nudge, run_nudge, shipped_runs

NUDGE = Path(os.environ.get("NUDGE_CLI", paths.repo() / "target" / "release" / "nudge")).absolute()


@pytest.fixture()
def elsewhere(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working directory outside the checkout."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    return work


def test_the_command_is_found_without_the_working_directory(elsewhere: Path) -> None:
    if not (paths.repo() / "target" / "release" / "nudge").is_file():
        pytest.skip("the checkout's nudge command is not built (make build)")
    assert find_nudge() == paths.repo() / "target" / "release" / "nudge"
    with pytest.raises(CommandError, match="not found"):
        find_nudge(elsewhere / "missing" / "nudge")


def test_a_shipped_scene_plans_outside_the_checkout(elsewhere: Path) -> None:
    if not NUDGE.is_file():
        pytest.fail(f"{NUDGE} missing: build the nudge command (make build)")
    runs = shipped_runs(paths.shipped_scenes(), paths.ngsim())
    if not runs[0].source.exists():
        pytest.skip(f"{runs[0].source} missing (the shared NGSIM data; NUDGE_NGSIM)")
    sol = run_nudge(NUDGE, runs[0], elsewhere / "out")
    assert sol.is_file() and sol.parent == elsewhere / "out"
    assert (elsewhere / "out" / "provenance.json").is_file()


def test_a_failing_command_is_a_typed_error_with_its_message(elsewhere: Path) -> None:
    if not NUDGE.is_file():
        pytest.fail(f"{NUDGE} missing: build the nudge command (make build)")
    with pytest.raises(CommandError, match=r"exit status 1: .*missing\.xml") as info:
        _simulate(NUDGE, ["--ego", "1"], elsewhere / "missing.xml", elsewhere / "out")
    assert isinstance(info.value, NudgeTrainError)
