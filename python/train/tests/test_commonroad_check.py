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
    CommandError,
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
    feasibility, start-state, obstacle-collision and goal steps pass (the road boundary step needs
    the non-free triangle package, see docs/results/commonroad.md)."""
    if not NUDGE.exists():
        pytest.fail(f"{NUDGE} missing: build the nudge command (make build)")
    source = paths.ngsim() / "us101" / E2E_SOURCE
    sol = _simulate(NUDGE, ["--planning-problem", str(E2E_PROBLEM)], source, tmp_path)
    checks = official_checks(source, sol)
    for step in ("solution_feasible", "starts_at_correct_state", "obstacle_collision", "goal_reached"):
        (verdict,) = [v for k, v in checks.items() if f"({step})" in k]
        assert verdict == "passed", f"{step}: {verdict}"


# ---- nudge_train.commonroad_planner.plan on commonroad-io objects ---------------------------------
CURVED_SOURCE = "commonroad_us101_T-1/USA_US101-26_1_T-1.xml.gz"
"""A curved scene (refused as not straight before the curvilinear frame) with a rectangle goal."""
CURVED_PROBLEM = 33


@pytest.fixture(scope="module")
def curved() -> tuple:
    from nudge_train.experiments.commonroad_check import _open_scenario

    source = paths.ngsim() / "us101" / CURVED_SOURCE
    assert source.exists(), f"{source} missing (the shared NGSIM data; NUDGE_NGSIM)"
    scenario, problems = _open_scenario(source)
    return scenario, problems


def _official(scenario, problems, solution) -> dict[str, bool]:  # noqa: ANN001
    from commonroad_dc.feasibility import solution_checker as sc

    out = {"feasible": all(v[0] for v in sc.solution_feasible(solution, scenario.dt, problems).values()),
           "collision_free": not sc.obstacle_collision(scenario, problems, solution),
           "starts_right": bool(sc.starts_at_correct_state(solution, problems))}
    try:
        out["goal"] = bool(sc.goal_reached(scenario, problems, solution))
    except Exception as exc:  # the checker reports a missed goal as an exception
        assert "goal" in str(exc).lower(), exc
        out["goal"] = False
    return out


def test_plan_returns_a_solution_the_official_checker_accepts(curved: tuple) -> None:
    """plan(scenario, planning_problem) on commonroad-io objects of a curved scene: a
    commonroad Solution, KS-feasible, collision-free, starting at the initial state and reaching
    the goal under the official checker; it ends at its first state inside the goal region."""
    from commonroad.common.solution import Solution

    from nudge_train.commonroad_planner import plan

    scenario, problems = curved
    problem = problems.planning_problem_dict[CURVED_PROBLEM]
    solution = plan(scenario, problem, nudge=NUDGE)
    assert isinstance(solution, Solution)
    assert _official(scenario, problems, solution) == {
        "feasible": True, "collision_free": True, "starts_right": True, "goal": True}
    states = solution.planning_problem_solutions[0].trajectory.state_list
    assert problem.goal.is_reached(states[-1]) and not any(problem.goal.is_reached(s) for s in states[:-1])


def test_plan_reports_a_missed_goal_as_the_checker_does(curved: tuple) -> None:
    """A goal the ego cannot meet (the same region, but at most 1 m/s): GoalNotReached naming the
    problem and the missed condition, and the official checker rejects the solution it carries."""
    import copy

    from commonroad.common.util import Interval

    from nudge_train.commonroad_planner import GoalNotReached, plan

    scenario, problems = curved
    problem = copy.deepcopy(problems.planning_problem_dict[CURVED_PROBLEM])
    problem.goal.state_list[0].velocity = Interval(0.0, 1.0)
    with pytest.raises(GoalNotReached, match=rf"planning problem {CURVED_PROBLEM}: goal not reached: .*velocity") as err:
        plan(scenario, problem, nudge=NUDGE)
    from commonroad.planning.planning_problem import PlanningProblemSet

    assert _official(scenario, PlanningProblemSet([problem]), err.value.solution)["goal"] is False


def test_plan_refuses_a_goal_beyond_the_map(curved: tuple) -> None:
    """A goal moved 5 km away: a typed error naming the planning problem and why."""
    import copy

    import numpy as np
    from commonroad.geometry.shape import Rectangle

    from nudge_train.commonroad_planner import plan

    scenario, problems = curved
    problem = copy.deepcopy(problems.planning_problem_dict[CURVED_PROBLEM])
    problem.goal.state_list[0].position = Rectangle(2.4, 1.85, center=np.array([5000.0, -4000.0]))
    with pytest.raises(CommandError, match=rf"planning problem {CURVED_PROBLEM}: goal: .*beyond the map"):
        plan(scenario, problem, nudge=NUDGE)


def test_long_curved_run_is_ks_feasible(tmp_path: Path) -> None:
    """USA_US101-22_1, problem 686: 16 s along a curving reference path. The KS states are
    written with the file frame's speed and yaw rate (the path's curvature included), so every
    transition passes the official feasibility check (with the road frame's steering and speed
    the transition at time step 142 did not) and the goal is reached."""
    source = paths.ngsim() / "us101" / "commonroad_us101_T-1/USA_US101-22_1_T-1.xml.gz"
    sol = _simulate(NUDGE, ["--planning-problem", "686"], source, tmp_path)
    side = json.loads(sol.with_suffix(".json").read_text())
    assert side["n_states"] > 150
    checks = official_checks(source, sol)
    for step in ("solution_feasible", "obstacle_collision", "starts_at_correct_state", "goal_reached"):
        (verdict,) = [v for k, v in checks.items() if f"({step})" in k]
        assert verdict == "passed", f"{step}: {verdict}"
