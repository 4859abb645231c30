"""CommonRoad solutions of nudge's closed-loop runs, checked by the official drivability checker.

For every shipped scene (``assets/scenes``: its CommonRoad source file, ego vehicle, t0 and
neighbour range are in its metadata) the ``nudge`` command plans in the CommonRoad source file
itself (``nudge simulate --commonroad FILE --ego ID --t0 S``) and writes the executed ego
trajectory as a CommonRoad KS solution; this module then checks each solution with
``commonroad-drivability-checker`` (the ``commonroad`` extra):

- **feasible**: ``feasibility_checker.trajectory_feasibility`` for the kinematic single-track
  model of CommonRoad vehicle type 2 (BMW 320i, the vehicle whose wheelbase is closest to
  nudge's), the scene's time step;
- **collision (official)**: the scenario's obstacles, the ego's own logged obstacle removed,
  against the solution as the official ``solution_checker.obstacle_collision`` builds it (the
  vehicle type's rectangle, 4.51 m x 1.61 m, at the KS state's position);
- **collision (footprint)**: the same obstacles against the ego's own logged box placed at its
  centre of gravity (rear axle + l_r along the heading), as nudge's closed loop judges it.

Nothing is loosened: the checker's default tolerances are used; every failure is reported with
its reason. Light: numpy, the standard library, commonroad-io and commonroad-dc (no torch).
"""

from __future__ import annotations

import gzip
import json
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nudge_train import paths
from nudge_train.errors import NudgeTrainError
from nudge_train.nudge_command import CHECK_WORLD, CommandError, _assets_args, find_nudge, run_solution


@dataclass(frozen=True)
class SceneRun:
    """One shipped scene as a CommonRoad run: source file, ego id, t0 (s), neighbour range (m)."""

    name: str
    source: Path
    ego: int
    t0: float
    range_m: float


def _metadata(path: Path) -> dict[str, str]:
    """The string metadata of a safetensors file (its JSON header; no safetensors package)."""
    with path.open("rb") as fh:
        (n,) = struct.unpack("<Q", fh.read(8))
        header = json.loads(fh.read(n))
    return dict(header.get("__metadata__", {}))


def _ids(path: Path) -> int:
    """The ego's id (first entry of ``agent_ids``, I64) of a scenario file."""
    with path.open("rb") as fh:
        (n,) = struct.unpack("<Q", fh.read(8))
        header = json.loads(fh.read(n))
        start = header["agent_ids"]["data_offsets"][0]
        fh.seek(8 + n + start)
        return int(struct.unpack("<q", fh.read(8))[0])


def shipped_runs(scenes: Path, ngsim: Path) -> list[SceneRun]:
    """The shipped scenes under ``scenes`` as CommonRoad runs on the source files under
    ``ngsim`` (2020a first, else the 2018b folder)."""
    out = []
    for p in sorted(scenes.glob("*.safetensors")):
        meta = _metadata(p)
        us = ngsim / "us101"
        src = us / "commonroad_us101_T-1" / meta["source"]
        if not src.exists():
            src = us / "commonroad_us101_2018b_extra" / meta["source"]
        range_m = float(meta["provenance"].split("neighbours within ")[1].split(" ")[0])
        out.append(SceneRun(p.stem, src, _ids(p), float(meta["t0_s"]), range_m))
    return out


E2E_SOURCE = "commonroad_us101_T-1/USA_US101-11_1_T-1.xml.gz"
"""The scenario planned end to end from its planning problem (under ``<ngsim>/us101``)."""
E2E_PROBLEM = 125
"""Its planning problem."""


def run_nudge(nudge: Path, run: SceneRun, out: Path) -> Path:
    """Plans ``run`` with the ``nudge`` command (student planner, ``log_replay`` world, seed 0,
    one thread) and returns its solution file."""
    return _simulate(nudge, ["--ego", str(run.ego), "--t0", f"{run.t0:.1f}", "--neighbour-range",
                             f"{run.range_m:g}"], run.source, out)


"""The closed-loop world of every checked solution: the checker judges a solution against the
scenario's recorded obstacles, so the others must move as recorded while nudge plans (in the
``teacher`` or ``idm`` world they react to the ego and a collision-free run there can collide
with the recording)."""


def _simulate_args(source: Path, ego_args: list[str], out: Path) -> list[str]:
    return ["simulate", "--commonroad", str(source), *ego_args, "--world", CHECK_WORLD, "--out", str(out),
            "--threads", "1", "--no-progress"]


def _simulate(nudge: Path, ego_args: list[str], source: Path, out: Path) -> Path:
    """Runs ``nudge simulate --commonroad source`` with ``ego_args`` into ``out`` (the models
    under the checkout's assets, whatever the working directory); its solution. Raises
    :class:`CommandError` with the command's stderr when it fails."""
    command = [str(nudge), *_simulate_args(source, ego_args, out), *_assets_args()]
    return run_solution(command, out)


@dataclass
class Check:
    """The checker's verdict on one solution."""

    feasible: bool
    infeasible_steps: list[int]
    collision_official: bool
    collision_footprint: bool
    n_states: int
    note: str = ""


def _open_scenario(scenario_file: Path):  # noqa: ANN202 (commonroad types are imported lazily)
    """The scenario and planning problems of a CommonRoad file (gunzipped first when .gz: the
    reader takes plain .xml only)."""
    from commonroad.common.file_reader import CommonRoadFileReader

    if scenario_file.suffix != ".gz":
        return CommonRoadFileReader(str(scenario_file)).open()
    with tempfile.TemporaryDirectory() as tmp:
        plain = Path(tmp) / scenario_file.stem
        plain.write_bytes(gzip.decompress(scenario_file.read_bytes()))
        return CommonRoadFileReader(str(plain)).open()


def official_checks(scenario_file: Path, solution_file: Path) -> dict[str, str]:
    """The official ``solution_checker`` steps on a planning-problem solution, each
    ``passed`` / ``failed: <reason>`` / ``not checked: <reason>``: feasibility, obstacle
    collision, start state, goal, road boundary."""
    from commonroad.common.solution import CommonRoadSolutionReader
    from commonroad_dc.feasibility import solution_checker as sc

    scenario, pps = _open_scenario(scenario_file)
    sol = CommonRoadSolutionReader.open(str(solution_file))
    steps = {
        "KS feasible (solution_feasible)": lambda: all(v[0] for v in sc.solution_feasible(sol, scenario.dt, pps).values()),
        "no obstacle collision (obstacle_collision)": lambda: not sc.obstacle_collision(scenario, pps, sol),
        "starts at the initial state (starts_at_correct_state)": lambda: sc.starts_at_correct_state(sol, pps),
        "goal reached (goal_reached)": lambda: sc.goal_reached(scenario, pps, sol),
        "no road-boundary collision (boundary_collision)": lambda: not sc.boundary_collision(scenario, pps, sol),
    }
    out = {}
    for name, step in steps.items():
        try:
            out[name] = "passed" if step() else "failed"
        except Exception as exc:  # the checker reports failures as exceptions
            why = str(exc).splitlines()[0][:200]
            kind = "not checked" if "triangle" in why else "failed"
            out[name] = f"{kind}: {type(exc).__name__}: {why}"
    return out


def check_solution(scenario_file: Path, solution_file: Path, ego: int | None, sidecar: dict) -> Check:
    """Checks ``solution_file`` against ``scenario_file`` (the ego obstacle ``ego`` removed;
    ``None``: every obstacle kept)."""
    from commonroad.common.solution import CommonRoadSolutionReader
    from commonroad.geometry.shape import Rectangle
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.state import CustomState
    from commonroad.scenario.trajectory import Trajectory
    from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import create_collision_object
    from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import create_collision_checker
    from commonroad_dc.feasibility import feasibility_checker
    from commonroad_dc.feasibility.vehicle_dynamics import VehicleDynamics, VehicleType

    scenario, _ = _open_scenario(scenario_file)
    solution = CommonRoadSolutionReader.open(str(solution_file))
    pp_solution = solution.planning_problem_solutions[0]
    traj = pp_solution.trajectory
    dyn = VehicleDynamics.KS(VehicleType(pp_solution.vehicle_type))  # the solution's own (KS2)
    bad = []
    for k in range(len(traj.state_list) - 1):
        ok, _ = feasibility_checker.state_transition_feasibility(
            traj.state_list[k], traj.state_list[k + 1], dyn, scenario.dt)
        if not ok:
            bad.append(int(traj.state_list[k].time_step))
    if ego is not None:
        scenario.remove_obstacle(scenario.obstacle_by_id(ego))
    checker = create_collision_checker(scenario)
    official = checker.collide(create_collision_object(TrajectoryPrediction(traj, dyn.shape)))
    # The KS position is the rear axle + b (the vehicle type's); nudge's centre of gravity is
    # the rear axle + l_r.
    ahead = float(sidecar["l_r_m"]) - dyn.parameters.b
    length, width = sidecar["ego_size_m"]
    centre = [CustomState(position=s.position + ahead * np.array([np.cos(s.orientation), np.sin(s.orientation)]),
                          orientation=s.orientation, time_step=s.time_step) for s in traj.state_list]
    box = TrajectoryPrediction(Trajectory(centre[0].time_step, centre), Rectangle(length, width))
    footprint = checker.collide(create_collision_object(box))
    return Check(feasible=not bad, infeasible_steps=bad, collision_official=bool(official),
                 collision_footprint=bool(footprint), n_states=len(traj.state_list))


def markdown(rows: list[tuple[SceneRun, Check | str, dict]], command: str) -> str:
    """The results page."""
    lines = [
        "# CommonRoad solutions of the shipped scenes, checked by the drivability checker",
        "",
        "Each shipped scene planned in its CommonRoad source file by the `nudge` command (student",
        "planner, `log_replay` world so that the others move as the checker's recorded obstacles do,",
        "seed 0, one thread), the executed ego trajectory written as a",
        "CommonRoad KS solution (vehicle type 2, BMW 320i: wheelbase 2.58 m, nearest to nudge's",
        "2.8 m) and checked by `commonroad-drivability-checker` 2025.4.0 with its default",
        "tolerances (position 2 cm, orientation 0.03 rad per time step). Regenerate with",
        "",
        f"    {command}",
        "",
        "Columns: *states* the solution's states (one per 0.1 s); *KS feasible* every transition passes",
        "`feasibility_checker.state_transition_feasibility`; *collision (official box)* the vehicle",
        "type's 4.51 m x 1.61 m box at the solution's positions, as `solution_checker.obstacle_collision`",
        "builds it; *collision (ego footprint)* the ego's own logged box at nudge's centre of gravity;",
        "both against every other obstacle of the scenario (the ego's own logged track removed). *m from",
        "closed loop*: the solution integrates the executed (steering, acceleration) of each 0.3 s step",
        "with the continuous bicycle, while nudge's closed loop advances its ego by one forward-Euler step",
        "of 0.3 s; this is their largest distance at the 0.3 s steps (Euler's position lags by a dt^2 / 2",
        "per step under acceleration a).",
        "",
        "| scene | source | ego | t0 (s) | states | KS feasible | infeasible transitions (time steps) "
        "| collision (official box) | collision (ego footprint) | m from closed loop |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    n_feas = n_free = n_ok = 0
    for run, res, side in rows:
        if isinstance(res, str):
            lines.append(f"| {run.name} | {run.source.name} | {run.ego} | {run.t0:.1f} | - | - | {res} | - | - | - |")
            continue
        n_ok += 1
        n_feas += res.feasible
        n_free += not res.collision_footprint and not res.collision_official
        steps = ", ".join(map(str, res.infeasible_steps)) or "none"
        lines.append(
            f"| {run.name} | {run.source.name} | {run.ego} | {run.t0:.1f} | {res.n_states} | "
            f"{'yes' if res.feasible else 'no'} | {steps} | {'yes' if res.collision_official else 'no'} | "
            f"{'yes' if res.collision_footprint else 'no'} | {side.get('max_dev_m', float('nan')):.3f} |")
    lines += ["", f"**{n_feas} of {n_ok} checked solutions KS-feasible; {n_free} of {n_ok} collision-free "
              f"(both checks); {len(rows) - n_ok} not checked.**", ""]
    return "\n".join(lines)


def end_to_end(nudge: Path, out: Path) -> str:
    """The page's section on one scenario planned from its planning problem and checked by the
    official solution checker's steps."""
    source = paths.ngsim() / "us101" / E2E_SOURCE
    for f in out.glob("solution_*"):
        f.unlink()
    sol = _simulate(nudge, ["--planning-problem", str(E2E_PROBLEM)], source, out)
    shown = " ".join(["target/release/nudge", *_simulate_args(
        Path("../shared/data/ngsim/us101") / E2E_SOURCE, ["--planning-problem", str(E2E_PROBLEM)],
        Path("runs/commonroad/e2e"))])
    side = json.loads(sol.with_suffix(".json").read_text())
    lines = [
        "## One scenario end to end from its planning problem", "",
        f"`{source.name}`, planning problem {E2E_PROBLEM} (the ego starts at the problem's initial state at",
        "t = 0 s; the other vehicles' histories before the scene's first step are extrapolated at constant",
        "speed and heading), planned by the `nudge` command (`make build` first):", "",
        f"    {shown}", "",
        f"The solution ({side['n_states']} states, {side['benchmark_id']}) under the official",
        "`commonroad_dc.feasibility.solution_checker` steps:", "",
        "| check | result |", "|---|---|",
    ]
    lines += [f"| {k} | {v} |" for k, v in official_checks(source, sol).items()]
    lines += ["", f"nudge aims at the problem's goal region (lane {side.get('goal_lane')} of the road frame; the goal is",
              "a 2.2 m x 1.7 m box at time steps 62-72 with velocity and orientation intervals) and the solution",
              f"ends at its first state inside it (time step {side.get('goal_time_step')}); the road boundary check needs the non-free",
              "`triangle` package, which the `commonroad` extra does not install.", ""]
    return "\n".join(lines)


def us101_files(ngsim: Path) -> list[Path]:
    """The 62 US-101 CommonRoad files of the shared data: the 60 of ``commonroad_us101_T-1``
    then the 2 of ``commonroad_us101_2018b_extra`` (each sorted by name)."""
    us = ngsim / "us101"
    return (sorted((us / "commonroad_us101_T-1").glob("*.xml.gz"))
            + sorted((us / "commonroad_us101_2018b_extra").glob("*.xml.gz")))


GOAL_STEP = "goal reached (goal_reached)"
"""The official check that the solution reaches its planning problem's goal."""
CHECKED_STEPS = ("KS feasible (solution_feasible)", "no obstacle collision (obstacle_collision)",
                 "starts at the initial state (starts_at_correct_state)", GOAL_STEP)
"""The official steps a solution must pass (the road-boundary step needs the non-free
``triangle`` package and is reported, not counted)."""


@dataclass
class ProblemRow:
    """One planning problem planned by the ``nudge`` command and checked: ``refused`` the
    command's error (then ``checks`` is empty), else the official steps' verdicts."""

    source: Path
    problem: int
    refused: str = ""
    checks: dict[str, str] | None = None

    @property
    def passed(self) -> bool:
        """Every counted official step passed (goal included)."""
        return bool(self.checks) and all(self.checks[k] == "passed" for k in CHECKED_STEPS)

    @property
    def reason(self) -> str:
        """Why it did not pass: the refusal's kind or the first failed step ("" when passed)."""
        if self.refused:
            for key, kind in (("road shape", "refused: lanes not straight"), ("goal:", "refused: goal cannot be planned"),
                              ("logged future", "refused: too short a logged future")):
                if key in self.refused:
                    return kind
            return "refused: other"
        failed = [k for k in CHECKED_STEPS if self.checks and self.checks[k] != "passed"]
        return f"failed: {failed[0]}" if failed else ""


def problem_ids(source: Path) -> list[int]:
    """The planning problem ids of a CommonRoad file (commonroad-io's reader)."""
    _, pps = _open_scenario(source)
    return sorted(int(k) for k in pps.planning_problem_dict)


def all_problems(nudge: Path | None, out: Path, files: list[Path] | None = None) -> list[ProblemRow]:
    """Plans every planning problem of ``files`` (default: the 62 US-101 files,
    :func:`us101_files`) with the ``nudge`` command (``--planning-problem``, ``log_replay``
    world, seed 0, one thread) and checks each solution with the official solution checker's
    steps (:func:`official_checks`). A refused problem is a row with the command's error."""
    nudge = find_nudge(nudge)
    rows = []
    for source in files if files is not None else us101_files(paths.ngsim()):
        for pp in problem_ids(source):
            d = out / f"{source.name.split('.')[0]}-pp{pp}"
            for f in d.glob("solution_*"):
                f.unlink()
            try:
                sol = _simulate(nudge, ["--planning-problem", str(pp)], source, d)
            except (CommandError, RuntimeError) as exc:
                rows.append(ProblemRow(source, pp, refused=str(exc).splitlines()[0]))
                continue
            rows.append(ProblemRow(source, pp, checks=official_checks(source, sol)))
    return rows


def problems_markdown(rows: list[ProblemRow], command: str) -> str:
    """The section on every planning problem: counts, then one row per problem."""
    planned = [r for r in rows if not r.refused]
    goal = sum(bool(r.checks) and r.checks[GOAL_STEP] == "passed" for r in rows)
    reasons: dict[str, int] = {}
    for r in rows:
        if not r.passed:
            reasons[r.reason] = reasons.get(r.reason, 0) + 1
    lines = [
        f"## Every planning problem of the {len({r.source for r in rows})} US-101 files", "",
        "Each file's planning problem planned from its initial state by the `nudge` command (student planner,",
        "`log_replay` world, seed 0, one thread; the run aims at the goal's lane and time window), the",
        "solution checked by the official `solution_checker` steps (KS feasibility, obstacle collision,",
        "start state, goal; the road-boundary step needs the non-free `triangle` package and is not",
        "counted). Regenerate with", "", f"    {command}", "",
        "| | problems |", "|---|---|",
        f"| planning problems | {len(rows)} |",
        f"| planned (a solution written) | {len(planned)} |",
        f"| goal reached (`goal_reached`) | {goal} |",
        f"| every counted check passed | {sum(r.passed for r in rows)} |",
    ]
    lines += [f"| {k} | {v} |" for k, v in sorted(reasons.items())]
    lines += ["", "| file | problem | result | reason |", "|---|---|---|---|"]
    for r in rows:
        why = r.refused or "; ".join(f"{k}: {v}" for k, v in (r.checks or {}).items()
                                     if v != "passed" and k in CHECKED_STEPS)
        why = why.replace("|", "/")[:220]
        lines.append(f"| {r.source.name} | {r.problem} | {'passed' if r.passed else r.reason} | {why} |")
    return "\n".join(lines + [""])


def run(nudge: Path | None, out: Path, md: Path | None) -> str:
    """Plans and checks every shipped scene with the ``nudge`` command (``find_nudge(nudge)``);
    writes ``md`` (when given) and returns the page."""
    nudge = find_nudge(nudge)
    rows: list[tuple[SceneRun, Check | str, dict]] = []
    for r in shipped_runs(paths.shipped_scenes(), paths.ngsim()):
        d = out / r.name
        for f in d.glob("solution_*"):
            f.unlink()
        try:
            sol = run_nudge(nudge, r, d)
            side = json.loads(sol.with_suffix(".json").read_text())
            rows.append((r, check_solution(r.source, sol, r.ego, side), side))
        except Exception as exc:  # reported per scene in the table, never hidden
            rows.append((r, f"not checked: {type(exc).__name__}: {str(exc).splitlines()[0][:160]}", {}))
    page = (markdown(rows, "make commonroad") + "\n" + end_to_end(nudge, out / "e2e") + "\n"
            + problems_markdown(all_problems(nudge, out / "problems"), "make commonroad"))
    if md is not None:
        md.write_text(page)
    return page
