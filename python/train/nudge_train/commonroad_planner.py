"""nudge as a planner for commonroad-io objects: :func:`plan` takes a ``commonroad`` ``Scenario``
and one of its ``PlanningProblem`` s and returns a ``commonroad`` ``Solution`` (a KS trajectory
of vehicle type 2) that the official solution checker accepts, goal included.

It lives in ``nudge_train`` (the ``commonroad`` extra), not in the ``nudge`` wheel: commonroad-io
pins a protobuf older than the one ray needs, so it stays out of the wheel's dependencies. The
planning itself is the ``nudge`` command's (``nudge simulate --commonroad FILE
--planning-problem ID``): the scenario is written to a temporary CommonRoad file, planned (the
goal's lane and time window, the curvilinear road frame on curved roads; see docs/commonroad.md)
and the solution file read back.

Example (in the environment of the ``commonroad`` extra, ``make test-commonroad``)::

    from commonroad.common.file_reader import CommonRoadFileReader
    from nudge_train.commonroad_planner import plan

    scenario, problems = CommonRoadFileReader("USA_US101-11_1_T-1.xml").open()
    solution = plan(scenario, problems.planning_problem_dict[125])
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

from nudge_train.errors import NudgeTrainError
from nudge_train.nudge_command import CHECK_WORLD, CommandError, _assets_args, find_nudge, run_solution

__all__ = ["GoalNotReached", "plan"]


class GoalNotReached(NudgeTrainError, RuntimeError):
    """nudge's closed loop did not reach the planning problem's goal: ``problem`` (its id),
    ``reason`` (the nearest state of the goal's time window and what it misses) and
    ``solution`` (the trajectory that was driven, a ``commonroad`` ``Solution``)."""

    def __init__(self, problem: int, reason: str, solution: Any) -> None:
        self.problem = problem
        self.reason = reason
        self.solution = solution
        super().__init__(f"planning problem {problem}: goal not reached: {reason}")


def plan(scenario: Any, planning_problem: Any, *, nudge: Path | None = None, seed: int = 0,
         world: str = CHECK_WORLD, neighbour_range: float | None = None, require_goal: bool = True,
         workdir: Path | None = None) -> Any:
    """Plans ``planning_problem`` in ``scenario`` (commonroad-io objects) with nudge's planner and
    returns the executed trajectory as a ``commonroad.common.solution.Solution``.

    ``nudge``: the ``nudge`` command (default :func:`~nudge_train.nudge_command.find_nudge`);
    ``seed``: the run's seed; ``world``: how the other vehicles move (``log_replay``, the default:
    as the scenario's recorded obstacles, which the checker judges against); ``neighbour_range``
    (m): the radius within which vehicles enter the scene (default: the command's, 60 m);
    ``workdir``: keep the scenario file and the run's outputs there (default: a temporary folder,
    removed). The solution ends at its first state inside the goal region.

    Raises:
        CommandError: the ``nudge`` command refused the problem (its message names the file, the
            planning problem and why: e.g. a goal beyond the map, a road it cannot represent).
        GoalNotReached: the run did not reach the goal (with ``require_goal``; the solution is on
            the exception).
    """
    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
    from commonroad.common.solution import CommonRoadSolutionReader
    from commonroad.planning.planning_problem import PlanningProblemSet

    nudge = find_nudge(nudge)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(workdir) if workdir is not None else Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        source = root / f"{scenario.scenario_id}.xml"
        CommonRoadFileWriter(scenario, PlanningProblemSet([planning_problem])).write_to_file(
            str(source), OverwriteExistingFile.ALWAYS)
        out = root / f"run-pp{planning_problem.planning_problem_id}-seed{seed}"
        for old in out.glob("solution_*"):
            old.unlink()
        command = [str(nudge), "simulate", "--commonroad", str(source), "--planning-problem",
                   str(planning_problem.planning_problem_id), "--world", world, "--seed", str(seed),
                   "--out", str(out), "--threads", "1", "--no-progress", *_assets_args()]
        if neighbour_range is not None:
            command += ["--neighbour-range", f"{neighbour_range:g}"]
        solution_file = run_solution(command, out)
        side = json.loads(solution_file.with_suffix(".json").read_text())
        solution = CommonRoadSolutionReader.open(str(solution_file))
    if require_goal and not side.get("goal_reached"):
        raise GoalNotReached(int(planning_problem.planning_problem_id), str(side.get("goal_missed")), solution)
    return solution
