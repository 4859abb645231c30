"""nudge's CommonRoad solutions under the official drivability checker (``make test-commonroad``,
in the environment of the ``commonroad`` extra): a shipped scene planned by the ``nudge`` command
in its CommonRoad source file gives a KS-feasible, collision-free solution, and the same check
rejects a solution with a 0.5 m jump and one driven into another vehicle (so it can fail)."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import pytest

pytest.importorskip("commonroad_dc", reason="the commonroad extra is not installed (make test-commonroad)")

from nudge_train import paths  # noqa: E402
from nudge_train.experiments.commonroad_check import (  # noqa: E402
    E2E_PROBLEM,
    E2E_SOURCE,
    _simulate,
    check_solution,
    official_checks,
    run_nudge,
    shipped_runs,
)

# commonroad-io's generated protobuf modules use calls protobuf deprecates (third-party code).
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

NUDGE = Path(os.environ.get("NUDGE_CLI", paths.repo() / "target" / "release" / "nudge"))
RUNS = shipped_runs(paths.shipped_scenes(), paths.ngsim())


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    if not NUDGE.exists():
        pytest.fail(f"{NUDGE} missing: build the nudge command (make build)")
    run = RUNS[0]
    assert run.source.exists(), f"{run.source} missing (the shared NGSIM data; NUDGE_NGSIM)"
    out = tmp_path_factory.mktemp("cr")
    sol = run_nudge(NUDGE, run, out)
    return out, sol, json.loads(sol.with_suffix(".json").read_text())


def test_shipped_scene_solution_is_feasible_and_collision_free(solved: tuple[Path, Path, dict]) -> None:
    _, sol, side = solved
    res = check_solution(RUNS[0].source, sol, RUNS[0].ego, side)
    assert res.feasible, res.infeasible_steps
    assert not res.collision_official and not res.collision_footprint
    assert res.n_states == side["n_states"] > 10


def _edit_x(text: str, index: int, dx: float) -> str:
    """The solution text with the x of state ``index`` moved by ``dx`` (m)."""
    states = text.split("<ksState>")
    x = float(re.search(r"<x>([^<]+)</x>", states[index + 1]).group(1))
    states[index + 1] = re.sub(r"<x>[^<]+</x>", f"<x>{x + dx!r}</x>", states[index + 1], count=1)
    return "<ksState>".join(states)


def test_checker_rejects_a_jump(solved: tuple[Path, Path, dict], tmp_path: Path) -> None:
    _, sol, side = solved
    bad = tmp_path / sol.name
    bad.write_text(_edit_x(sol.read_text(), 5, 0.5))
    res = check_solution(RUNS[0].source, bad, RUNS[0].ego, side)
    assert not res.feasible and res.infeasible_steps


def test_checker_sees_a_collision(solved: tuple[Path, Path, dict], tmp_path: Path) -> None:
    """With the ego's own logged obstacle kept in the scene, its box overlaps the solution at
    the solution's first state."""
    _, sol, side = solved
    bad = tmp_path / sol.name
    shutil.copy(sol, bad)
    res = check_solution(RUNS[0].source, bad, None, side)
    assert res.collision_official and res.collision_footprint


def test_planning_problem_solution_passes_the_official_feasibility_and_collision_checks(
    tmp_path: pytest.TempPathFactory,
) -> None:
    """The end-to-end scenario (the ego from its planning problem's initial state) planned in the
    world the checker judges against (the recorded obstacles): the official solution checker's
    feasibility, start-state and obstacle-collision steps pass (goal and road boundary are not
    nudge's claims, see docs/results/commonroad.md)."""
    if not NUDGE.exists():
        pytest.fail(f"{NUDGE} missing: build the nudge command (make build)")
    source = paths.ngsim() / "us101" / E2E_SOURCE
    sol = _simulate(NUDGE, ["--planning-problem", str(E2E_PROBLEM)], source, tmp_path)
    checks = official_checks(source, sol)
    for step in ("solution_feasible", "starts_at_correct_state", "obstacle_collision"):
        (verdict,) = [v for k, v in checks.items() if f"({step})" in k]
        assert verdict == "passed", f"{step}: {verdict}"
