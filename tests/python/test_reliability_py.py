"""Reliability of the Python front end: no Rust panic reaches Python from any entry point of
``nudge._native`` (enumerated, so a new one cannot be forgotten), counts are bounded with a
typed error naming the argument, settings that do not fit the predictors are refused before
any run, the CLI and Python refuse the same bad arguments with the same message, and the minor
defects of argument handling (negative ints, a lone path, lists, masked arrays, repeated keys)."""

from __future__ import annotations

import inspect
import os
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import nudge
from nudge import _native

# ------------------------------------------------------------------------------------------
# Every entry point, with zero-sized and degenerate inputs.
# ------------------------------------------------------------------------------------------

Call = Callable[[dict[str, Any]], object]


def _entry_points() -> set[str]:
    """Every function of ``nudge._native`` and every public method, property and constructor of
    its classes, as ``"name"`` / ``"Class.name"``."""
    names: set[str] = set()
    for name, obj in vars(_native).items():
        if name.startswith("_"):
            continue
        if inspect.isclass(obj):
            if issubclass(obj, BaseException):
                continue
            names.add(f"{name}.__new__")
            names.update(f"{name}.{m}" for m in vars(obj) if not m.startswith("_"))
        elif callable(obj):
            names.add(name)
    return names


def _ctx() -> dict[str, Any]:
    sc = nudge.Scenario.load(nudge.scene_paths()[0])
    cv = nudge.Predictor.constant_velocity()
    return {
        "sc": sc,
        "cv": cv,
        "planner": nudge.Planner(None, cv),
        "settings": nudge.PlannerSettings.default(),
        "config": nudge.SimConfig.default(),
        "scene": str(nudge.scene_paths()[0]),
        "assets": str(nudge.assets_dir()),
    }


Z = np.zeros
CR_FIXTURE = str(Path(__file__).resolve().parents[2] / "python/train/tests/fixtures/commonroad/USA_US101-1_1_T-1.xml.gz")


def _still(n: int) -> dict[str, Any]:
    """A trace of no step: n agents standing on a one-lane road."""
    return {
        "title": "", "lane_bounds": np.array([0.0, 3.5]), "sizes": np.ones((n, 2)), "agents": Z((1, n, 3)),
        "speed": Z(1), "collision": Z(1, dtype=bool), "status": [], "mpc_s": Z(0), "plan": Z((0, 1, 4)),
        "predicted": Z((0, max(n - 1, 0), 0, 2)), "binding": Z(0, dtype=np.int64),
        "binding_step": Z(0, dtype=np.int64), "binding_b": Z(0), "semi_axes": Z((0, 0, 2)),
    }


def _plan(c: dict[str, Any], **kw: Any) -> object:
    args: dict[str, Any] = {
        "history": Z((2, 8, 2)), "sizes": np.ones((2, 2)), "ego": Z(4), "y_target": 0.0, "v_ref": 10.0,
        "road": (-2.0, 2.0),
    }
    args.update(kw)
    return c["planner"].plan(**args)


# Each entry point: calls with degenerate inputs. Every call must return a valid result or raise
# a NudgeError (Python's own TypeError/AttributeError where its semantics demand, listed per
# call); never pyo3's PanicException.
DEGENERATE: dict[str, list[Call]] = {
    "model_path": [
        lambda c: _native.model_path("", ""),
        lambda c: _native.model_path(c["assets"], "constant_velocity"),
        lambda c: _native.model_path("", "teacher"),
    ],
    "assets_dir": [lambda c: _native.assets_dir(""), lambda c: _native.assets_dir("/dev/null")],
    "scenes_dir": [lambda c: _native.scenes_dir(""), lambda c: _native.scenes_dir("/dev/null")],
    # The command line: no program name, nothing to run, a refusal, a usage error.
    "cli_main": [
        lambda c: _native.cli_main([], ""),
        lambda c: _native.cli_main(["nudge"], c["assets"]),
        lambda c: _native.cli_main(["nudge", "simulate", "--runs", "0"], c["assets"]),
        lambda c: _native.cli_main(["nudge", "simulate", "--scenes", ""], ""),
        lambda c: _native.cli_main(["nudge", "simulate", "--runs", "-1"], ""),
    ],
    # Animations: a trace of no step and one agent (one frame, drawn), of no agent, of no
    # state, empty; a GIF path that cannot be written; no ffmpeg where it is missing.
    "animate": [
        lambda c: _native.animate(_still(1), os.devnull),
        lambda c: _native.animate(_still(0), os.devnull),
        lambda c: _native.animate({**_still(1), "agents": Z((0, 1, 3))}, os.devnull),
        lambda c: _native.animate({}, os.devnull),
        lambda c: _native.animate(_still(1), ""),
        lambda c: _native.animate(_still(1), os.devnull, mp4=os.devnull, ffmpeg=""),
        lambda c: _native.animate(_still(1), os.devnull, px_per_m=0.0),
    ],
    "find_ffmpeg": [lambda c: _native.find_ffmpeg()],
    "simulate": [
        lambda c: _native.simulate([]),
        lambda c: _native.simulate([c["scene"]], runs=0),
        lambda c: _native.simulate([c["scene"]], threads=0),
        lambda c: _native.simulate([c["scene"]], max_steps=0),
        lambda c: _native.simulate([c["scene"]], scene_seeds=[]),
        lambda c: _native.simulate([], scene_seeds=[]),
        lambda c: _native.simulate([""], assets=c["assets"]),
        lambda c: _native.simulate([c["scene"]], "", assets=c["assets"]),
        lambda c: _native.simulate([c["scene"]], "constant_velocity", world="log_replay",
                                   settings=nudge.PlannerSettings(model={"horizon": 1}), max_steps=1, assets=c["assets"]),
        lambda c: _native.simulate([c["scene"]], "constant_velocity", world="log_replay", max_steps=1,
                                   assets="", runs=1, seed=2**64 - 1),
    ],
    "commonroad_scenario": [
        lambda c: _native.commonroad_scenario("", ego=1),
        lambda c: _native.commonroad_scenario("/dev/null", ego=1),
        lambda c: _native.commonroad_scenario(c["assets"], planning_problem=1),
        lambda c: _native.commonroad_scenario(CR_FIXTURE),
        lambda c: _native.commonroad_scenario(CR_FIXTURE, ego=-1),
        lambda c: _native.commonroad_scenario(CR_FIXTURE, ego=484, t0=float("nan")),
        lambda c: _native.commonroad_scenario(CR_FIXTURE, ego=484, t0=1e300),
        lambda c: _native.commonroad_scenario(CR_FIXTURE, ego=484, t0=-2.1),
        lambda c: _native.commonroad_scenario(CR_FIXTURE, ego=484, neighbour_range=float("nan")),
        lambda c: _native.commonroad_scenario(CR_FIXTURE, ego=484, neighbour_range=0.0),
    ],
    "commonroad_solution": [
        lambda c: _native.commonroad_solution(CR_FIXTURE, "/dev/null/s.xml", Z(0), Z(0), ego=484),
        lambda c: _native.commonroad_solution(CR_FIXTURE, "/dev/null/s.xml", Z(2), Z(2), ego=484),
        lambda c: _native.commonroad_solution(CR_FIXTURE, "/dev/null/s.xml", np.full(2, np.nan), Z(2), ego=484),
        lambda c: _native.commonroad_solution(CR_FIXTURE, "/dev/null/s.xml", Z(2), np.full(2, 1e300), ego=484),
        lambda c: _native.commonroad_solution("", "", Z(1), Z(2)),
    ],
    "commonroad_tracks": [
        lambda c: _native.commonroad_tracks(""),
        lambda c: _native.commonroad_tracks("/dev/null"),
        lambda c: _native.commonroad_tracks(c["assets"]),
    ],
    "Predictor.__new__": [lambda c: nudge.Predictor()],  # no constructor: TypeError
    "Predictor.load": [
        lambda c: nudge.Predictor.load(""),
        lambda c: nudge.Predictor.load("/dev/null"),
        lambda c: nudge.Predictor.load(c["assets"]),
    ],
    "Predictor.constant_velocity": [
        lambda c: nudge.Predictor.constant_velocity(0),
        lambda c: nudge.Predictor.constant_velocity(10**6),
    ],
    "Predictor.name": [lambda c: c["cv"].name],
    "Predictor.horizon": [lambda c: c["cv"].horizon],
    "Predictor.predict": [
        lambda c: c["cv"].predict(Z((1, 8, 2)), Z((1, 0, 2))),
        lambda c: c["cv"].predict(Z((0, 8, 2)), Z((1, 6, 2))),
        lambda c: c["cv"].predict(Z((2, 8, 2)), Z((0, 6, 2))),
        lambda c: c["cv"].predict(Z((1, 8, 2)), Z((1, 6, 2))),
        lambda c: c["cv"].predict(Z((0, 0, 0)), Z((0, 0, 0))),
        lambda c: c["cv"].predict(Z(0), Z(0)),
        lambda c: c["cv"].predict(Z((2, 8, 0)), Z((1, 6, 2))),
        lambda c: c["cv"].predict([], []),
        lambda c: c["cv"].predict(np.float64(0.0), np.float64(0.0)),
    ],
    "PlannerSettings.__new__": [
        lambda c: nudge.PlannerSettings(model={"horizon": 0}),
        lambda c: nudge.PlannerSettings(admm={"max_iter": 0}),
        lambda c: nudge.PlannerSettings(admm={"pgd_steps": 0}),
    ],
    "PlannerSettings.default": [lambda c: nudge.PlannerSettings.default()],
    "PlannerSettings.from_dict": [
        lambda c: nudge.PlannerSettings.from_dict({}),
        lambda c: nudge.PlannerSettings.from_dict({"model": {"horizon": 0}}),
        lambda c: nudge.PlannerSettings.from_dict([]),
    ],
    "PlannerSettings.from_json": [
        lambda c: nudge.PlannerSettings.from_json(""),
        lambda c: nudge.PlannerSettings.from_json("[]"),
        lambda c: nudge.PlannerSettings.from_json("{}"),
        lambda c: nudge.PlannerSettings.from_json('{"model": {"horizon": 0}}'),
    ],
    "PlannerSettings.to_dict": [lambda c: c["settings"].to_dict()],
    "PlannerSettings.to_json": [lambda c: c["settings"].to_json()],
    "PlannerSettings.describe": [lambda c: nudge.PlannerSettings.describe(), lambda c: c["settings"].describe()],
    "PlannerSettings.replace": [
        lambda c: c["settings"].replace(),
        lambda c: c["settings"].replace(model={"horizon": 0}),
    ],
    "SimConfig.__new__": [lambda c: nudge.SimConfig(max_steps=0), lambda c: nudge.SimConfig(settle_steps=0)],
    "SimConfig.default": [lambda c: nudge.SimConfig.default()],
    "SimConfig.from_dict": [lambda c: nudge.SimConfig.from_dict({}), lambda c: nudge.SimConfig.from_dict({"max_steps": 0})],
    "SimConfig.from_json": [
        lambda c: nudge.SimConfig.from_json(""),
        lambda c: nudge.SimConfig.from_json("[]"),
        lambda c: nudge.SimConfig.from_json("{}"),
    ],
    "SimConfig.to_dict": [lambda c: c["config"].to_dict()],
    "SimConfig.to_json": [lambda c: c["config"].to_json()],
    "SimConfig.describe": [lambda c: nudge.SimConfig.describe(), lambda c: c["config"].describe()],
    "SimConfig.replace": [lambda c: c["config"].replace(), lambda c: c["config"].replace(max_steps=0)],
    "Scenario.__new__": [lambda c: nudge.Scenario()],  # no constructor: TypeError
    "Scenario.load": [
        lambda c: nudge.Scenario.load(""),
        lambda c: nudge.Scenario.load("/dev/null"),
        lambda c: nudge.Scenario.load(c["assets"]),
    ],
    "Scenario.nearest": [lambda c: c["sc"].nearest(0), lambda c: c["sc"].nearest(0).nearest(0)],
    # Scenes from arrays: no agent, no observed step, no lane, an absurd lane index, a
    # broadcast view of 10^9 agents (refused by shape before copying), an empty scene.
    "Scenario.from_arrays": [
        lambda c: nudge.Scenario.from_arrays(Z((0, 8, 2)), Z((0, 2)), [0.0, 3.7], 0),
        lambda c: nudge.Scenario.from_arrays(Z((1, 0, 2)), np.ones((1, 2)), [0.0, 3.7], 0),
        lambda c: nudge.Scenario.from_arrays(Z((1, 8, 2)), np.ones((1, 2)), [], 0),
        lambda c: nudge.Scenario.from_arrays(Z((1, 8, 2)), np.ones((1, 2)), [0.0, 3.7], 2**64 - 1),
        lambda c: nudge.Scenario.from_arrays(np.broadcast_to(Z((1, 8, 2)), (10**9, 8, 2)), Z((0, 2)), [0.0], 0),
        lambda c: nudge.Scenario.from_arrays([], [], [], 0),
    ],
    # Writing a scene: to no path, to a directory, the ego alone.
    "Scenario.save": [
        lambda c: c["sc"].save(""),
        lambda c: c["sc"].save(c["assets"]),
        lambda c: c["sc"].nearest(0).save(os.devnull),
    ],
    "Scenario.target_lane": [lambda c: c["sc"].target_lane(0), lambda c: c["sc"].nearest(0).target_lane(2**64 - 1)],
    "Planner.__new__": [
        lambda c: nudge.Planner(None, c["cv"]),
        lambda c: nudge.Planner(nudge.PlannerSettings(model={"horizon": 1}), c["cv"]),
    ],
    "Planner.settings": [lambda c: c["planner"].settings],
    "Planner.predictor": [lambda c: c["planner"].predictor],
    "Planner.reset": [lambda c: c["planner"].reset()],
    "Planner.plan": [
        lambda c: _plan(c, history=Z((0, 8, 2)), sizes=Z((0, 2))),
        lambda c: _plan(c, history=Z((1, 0, 2)), sizes=np.ones((1, 2))),
        lambda c: _plan(c, history=Z((1, 8, 2)), sizes=np.ones((1, 2))),
        lambda c: _plan(c, sizes=Z((0, 2))),
        lambda c: _plan(c, ego=Z(0)),
        lambda c: _plan(c, road=(1.0, 1.0)),
        lambda c: _plan(c, road=(0.0, 0.0), y_target=0.0),
        lambda c: _plan(c, v_ref=0.0, ego=Z(4)),
        lambda c: _plan(c, y_retreat=float("nan")),
        lambda c: _plan(c, y_retreat=1e300),
        lambda c: _plan(c, y_retreat=-1.0),
    ],
    "Planner.plan_scenario": [
        lambda c: c["planner"].plan_scenario(c["sc"].nearest(0)),
        lambda c: c["planner"].plan_scenario(c["sc"], target_lane=99),
        lambda c: c["planner"].plan_scenario(c["sc"], seed=2**64 - 1),
    ],
}


def _session(c: dict[str, Any]) -> Any:
    """A closed-loop session (nudge.env's loop) over the first shipped scene, constant velocity."""
    return _native.Session([c["scene"]], "constant_velocity", assets=c["assets"])


def _started(c: dict[str, Any]) -> Any:
    s = _session(c)
    s.reset(0, 0)
    return s


# The closed-loop session: no scene, an unknown predictor, methods before a run starts, indices
# and seeds out of range, inputs of the wrong length, out of bounds or non-finite, steps after
# the run ended.
DEGENERATE.update({
    "Session.__new__": [
        lambda c: _native.Session([]),
        lambda c: _native.Session([""]),
        lambda c: _native.Session([c["scene"]], "no_such_model", assets=c["assets"]),
        lambda c: _native.Session([c["scene"]], "constant_velocity", assets=c["assets"], max_steps=0),
    ],
    "Session.scene_names": [lambda c: _session(c).scene_names],
    "Session.lane_counts": [lambda c: _session(c).lane_counts],
    "Session.settings": [lambda c: _session(c).settings],
    "Session.config": [lambda c: _session(c).config],
    "Session.predictor": [lambda c: _session(c).predictor],
    "Session.reset": [
        lambda c: _session(c).reset(1, 0),
        lambda c: _session(c).reset(-1, 0),
        lambda c: _session(c).reset(0, -1),
        lambda c: _session(c).reset(0, 2**64),
    ],
    "Session.observation": [lambda c: _session(c).observation(), lambda c: _started(c).observation()],
    "Session.target": [lambda c: _session(c).target(), lambda c: _started(c).target()],
    "Session.nudge_plan": [lambda c: _session(c).nudge_plan(), lambda c: _started(c).nudge_plan()],
    "Session.step": [
        lambda c: _session(c).step([0.0] * 6, [0.0] * 6),
        lambda c: _started(c).step([], []),
        lambda c: _started(c).step([0.0] * 5, [0.0] * 6),
        lambda c: _started(c).step([float("nan")] * 6, [0.0] * 6),
        lambda c: _started(c).step([0.0] * 6, [1e300] * 6),
        lambda c: [_s.step([0.0] * 6, [0.0] * 6) for _s in [_started(c)] for _ in range(200)],
    ],
})

# Getters of Scenario: on a scene reduced to the ego alone.
for _name in ("agent_ids", "ego_lane", "future", "future_valid", "heading", "history", "lane_bounds",
              "lane_centres", "lane_extent_real", "lane_extents", "metadata", "n_agents", "name", "path", "road",
              "size", "speed"):
    DEGENERATE[f"Scenario.{_name}"] = [lambda c, n=_name: getattr(c["sc"].nearest(0), n)]

# Entry points whose degenerate calls may raise Python's own exceptions: no constructor.
PYTHON_SEMANTICS: dict[str, tuple[type[BaseException], ...]] = {
    "Predictor.__new__": (TypeError,),
    "Scenario.__new__": (TypeError,),
}


def test_every_entry_point_has_degenerate_cases() -> None:
    """A new function, method or property of ``nudge._native`` must be added to DEGENERATE."""
    assert _entry_points() == set(DEGENERATE), (
        f"missing: {sorted(_entry_points() - set(DEGENERATE))}; stale: {sorted(set(DEGENERATE) - _entry_points())}"
    )


@pytest.mark.parametrize("entry", sorted(DEGENERATE))
def test_degenerate_inputs_never_panic(entry: str) -> None:
    ctx = _ctx()
    allowed = (nudge.NudgeError, *PYTHON_SEMANTICS.get(entry, ()))
    for i, call in enumerate(DEGENERATE[entry]):
        try:
            call(ctx)
        except allowed:
            pass
        except BaseException as e:  # noqa: BLE001 - PanicException derives from BaseException
            pytest.fail(f"{entry} case {i}: {type(e).__module__}.{type(e).__name__}: {e}")


def test_zero_sized_inputs_get_typed_errors_naming_the_input() -> None:
    cv = nudge.Predictor.constant_velocity()
    with pytest.raises(nudge.InputError, match="horizon 0"):
        nudge.Predictor.constant_velocity(0)
    with pytest.raises(nudge.InputError, match="candidates"):
        cv.predict(Z((1, 8, 2)), Z((1, 0, 2)))
    with pytest.raises(nudge.InputError, match="0 agents"):
        cv.predict(Z((0, 8, 2)), Z((1, 6, 2)))
    with pytest.raises(nudge.InputError, match="scene_paths"):
        nudge.simulate([])
    # One agent: nothing to predict, an empty prediction.
    assert cv.predict(Z((1, 8, 2)), Z((1, 6, 2))).shape == (1, 0, 6, 2)


# ------------------------------------------------------------------------------------------
# Counts and sizes.
# ------------------------------------------------------------------------------------------


def test_huge_counts_are_refused_naming_the_argument(scenes: list[Path]) -> None:
    one = scenes[:1]
    for kwargs, name in [
        ({"runs": 2**40}, "runs"),
        ({"runs": 2**70}, "runs"),
        ({"threads": 10**6}, "threads"),
        ({"threads": 2**70}, "threads"),
        ({"seed": 2**64}, "seed"),
        ({"scene_seeds": [2**64]}, "scene_seeds"),
    ]:
        with pytest.raises(nudge.InputError, match=name):
            nudge.simulate(one, "constant_velocity", **kwargs)
    with pytest.raises(nudge.SettingsError, match="max_steps"):
        nudge.simulate(one, "constant_velocity", max_steps=10**9)
    with pytest.raises(nudge.InputError, match="runs.*1000000"):
        nudge.simulate(one, "constant_velocity", runs=2**40)


def test_huge_arrays_are_refused_before_copying() -> None:
    """A broadcast view costs no memory in Python but would be copied whole: refused by shape."""
    cv = nudge.Predictor.constant_velocity()
    h = np.zeros((2, 8, 2))
    many = np.broadcast_to(np.zeros((1, 6, 2)), (10**9, 6, 2))
    with pytest.raises(nudge.InputError, match="candidates"):
        cv.predict(h, many)
    agents = np.broadcast_to(np.zeros((1, 8, 2)), (10**9, 8, 2))
    with pytest.raises(nudge.InputError, match="history"):
        cv.predict(agents, np.zeros((1, 6, 2)))
    planner = nudge.Planner(None, cv)
    with pytest.raises(nudge.InputError, match="history"):
        planner.plan(agents, np.ones((10**9, 2)), np.zeros(4), 0.0, 10.0, (-2.0, 2.0))


# ------------------------------------------------------------------------------------------
# Settings that do not fit the predictors: refused before any run.
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("overrides", "field", "predictor"), [
    ({"model.horizon": 7}, "model.horizon", "student"),
    ({"model.horizon": 10}, "model.horizon", "student"),
    ({"model.dt": 0.5}, "model.dt", "teacher"),
    ({"model.dt": 0.5}, "model.dt", "student"),
    ({"model.dt": 0.2}, "model.dt", "constant_velocity"),
])
def test_settings_that_do_not_fit_are_refused_before_any_run(scenes: list[Path], overrides: dict[str, Any],
                                                             field: str, predictor: str) -> None:
    s = nudge.PlannerSettings(**overrides)
    with pytest.raises(nudge.SettingsError, match=f"`{field}`"):
        nudge.simulate(scenes[:2], predictor, settings=s, on_error="skip", max_steps=1)


def test_planner_refuses_a_predictor_of_another_horizon_at_construction() -> None:
    with pytest.raises(nudge.SettingsError, match="`model.horizon`"):
        nudge.Planner(nudge.PlannerSettings(model={"horizon": 5}), nudge.Predictor.constant_velocity(6))
    with pytest.raises(nudge.SettingsError, match="`model.dt`"):
        nudge.Planner(nudge.PlannerSettings(model={"dt": 0.5}), nudge.Predictor.load(nudge.model_path("student")))


# ------------------------------------------------------------------------------------------
# CLI and Python refuse the same bad arguments with the same message.
# ------------------------------------------------------------------------------------------


def _cli(repo: Path) -> Path:
    exe = Path(os.environ.get("NUDGE_CLI", repo / "target" / "release" / "nudge"))
    exe = exe if exe.is_absolute() else repo / exe
    assert exe.is_file(), f"the nudge CLI is not built at {exe} (cargo build --release, or set NUDGE_CLI)"
    return exe


PARITY: list[tuple[str, list[str], dict[str, Any]]] = [
    ("runs 0", ["--runs", "0"], {"runs": 0}),
    ("runs huge", ["--runs", "1000000000000"], {"runs": 10**12}),
    ("threads 0", ["--threads", "0"], {"threads": 0}),
    ("threads huge", ["--threads", "100000"], {"threads": 100000}),
    ("max_steps 0", ["--max-steps", "0"], {"max_steps": 0}),
    ("max_steps huge", ["--max-steps", "1000000"], {"max_steps": 10**6}),
    ("settle_y", ["--settle-y=-1"], {"settle_y": -1.0}),
    ("world model", ["--world-predictor", "student"], {"world_predictor": "student"}),
    ("log replay model", ["--world", "log_replay", "--world-predictor", "teacher"],
     {"world": "log_replay", "world_predictor": "teacher"}),
    ("unknown predictor", ["--predictor", "constant-velocity"], {"predictor": "constant-velocity"}),
    ("missing weights", ["--predictor", "nope.safetensors"], {"predictor": "nope.safetensors"}),
]


@pytest.mark.parametrize(("what", "cli_args", "py_kwargs"), PARITY, ids=[p[0] for p in PARITY])
def test_cli_and_python_refuse_bad_arguments_alike(repo: Path, tmp_path: Path, what: str, cli_args: list[str],
                                                   py_kwargs: dict[str, Any]) -> None:
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    paths = nudge.scene_paths()[:1]
    for p in paths:
        (scenes / p.name).write_bytes(p.read_bytes())
    with pytest.raises(nudge.NudgeError) as info:
        nudge.simulate([scenes / p.name for p in paths], **py_kwargs)
    r = subprocess.run([str(_cli(repo)), "simulate", "--scenes", str(scenes), "--assets", str(nudge.assets_dir()),
                        *cli_args], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 1, f"{what}: exit {r.returncode}: {r.stdout}{r.stderr}"
    assert "runs " not in r.stdout, f"{what}: runs started: {r.stdout}"
    assert str(info.value) in r.stderr, f"{what}: Python says {info.value!s}, the CLI says {r.stderr}"


@pytest.mark.parametrize(("kind", "text", "key"), [
    ("settings", '{"w_y": 1.0, "w_y": 2.0}', "w_y"),
    ("config", '{"max_steps": 1, "max_steps": 2}', "max_steps"),
])
def test_cli_and_python_refuse_repeated_keys_alike(repo: Path, tmp_path: Path, kind: str, text: str, key: str) -> None:
    cls = nudge.PlannerSettings if kind == "settings" else nudge.SimConfig
    with pytest.raises(nudge.SettingsError, match=f"duplicate.*{key}") as info:
        cls.from_json(text)
    f = tmp_path / "s.json"
    f.write_text(text)
    r = subprocess.run([str(_cli(repo)), "simulate", "--scenes", str(nudge.assets_dir() / "scenes"),
                        "--assets", str(nudge.assets_dir()), f"--{kind}", str(f)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    assert str(info.value) in r.stderr, f"Python says {info.value!s}, the CLI says {r.stderr}"


# ------------------------------------------------------------------------------------------
# Minor argument handling.
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("call", "name"), [
    (lambda: nudge.simulate(nudge.scene_paths()[:1], runs=-1), "runs"),
    (lambda: nudge.simulate(nudge.scene_paths()[:1], seed=-1), "seed"),
    (lambda: nudge.simulate(nudge.scene_paths()[:1], threads=-1), "threads"),
    (lambda: nudge.simulate(nudge.scene_paths()[:1], scene_seeds=[-1]), "scene_seeds"),
    (lambda: _native.simulate([str(nudge.scene_paths()[0])], runs=-1), "runs"),
    (lambda: nudge.Predictor.constant_velocity(-1), "horizon"),
    (lambda: nudge.Scenario.load(nudge.scene_paths()[0]).target_lane(-1), "seed"),
    (lambda: nudge.Scenario.load(nudge.scene_paths()[0]).nearest(-1), "keep"),
    (lambda: nudge.Planner(None, nudge.Predictor.constant_velocity()).plan_scenario(
        nudge.Scenario.load(nudge.scene_paths()[0]), seed=-1), "seed"),
    (lambda: nudge.Planner(None, nudge.Predictor.constant_velocity()).plan_scenario(
        nudge.Scenario.load(nudge.scene_paths()[0]), target_lane=-1), "target_lane"),
])
def test_negative_ints_are_refused_naming_the_argument(call: Callable[[], object], name: str) -> None:
    with pytest.raises(nudge.InputError, match=f"{name}.*-1"):
        call()


def test_a_lone_path_is_not_iterated(scenes: list[Path]) -> None:
    for lone in (str(scenes[0]), scenes[0], os.fsencode(scenes[0])):
        with pytest.raises(TypeError, match="scene_paths"):
            nudge.simulate(lone, "constant_velocity", max_steps=1)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="scene_paths"):
        _native.simulate(str(scenes[0]))  # type: ignore[arg-type]


def test_predict_takes_nested_lists_like_arrays(teacher: nudge.Predictor, scenario: nudge.Scenario) -> None:
    from conftest import straight_candidates

    h = scenario.history
    c = straight_candidates(scenario, 2)
    want = teacher.predict(h, c)
    np.testing.assert_array_equal(teacher.predict(h.tolist(), c.tolist()), want)
    np.testing.assert_array_equal(teacher.predict(tuple(map(tuple, h.tolist())), c), want)
    for bad in (None, "abc", [["a"]], [[1.0, 2.0], [3.0]]):
        with pytest.raises(nudge.InputError, match="candidates"):
            teacher.predict(h, bad)  # type: ignore[arg-type]


def test_masked_arrays_are_refused(teacher: nudge.Predictor, scenario: nudge.Scenario) -> None:
    from conftest import straight_candidates

    h = np.ma.masked_array(scenario.history, mask=np.zeros_like(scenario.history, dtype=bool))
    h.mask[1, 3, 0] = True
    c = straight_candidates(scenario, 2)
    with pytest.raises(nudge.InputError, match="history.*masked"):
        teacher.predict(h, c)
    with pytest.raises(nudge.InputError, match="candidates.*masked"):
        teacher.predict(scenario.history, np.ma.masked_array(c))
    planner = nudge.Planner(None, teacher)
    with pytest.raises(nudge.InputError, match="sizes.*masked"):
        planner.plan(scenario.history, np.ma.masked_array(scenario.size), np.zeros(4), 0.0, 10.0, scenario.road)


def test_world_predictor_with_log_replay_is_refused(scenes: list[Path]) -> None:
    with pytest.raises(nudge.InputError, match="log_replay"):
        nudge.simulate(scenes[:1], "constant_velocity", world="log_replay", world_predictor="teacher")
    cfg = nudge.SimConfig(world="log_replay")
    with pytest.raises(nudge.InputError, match="log_replay"):
        nudge.simulate(scenes[:1], "constant_velocity", config=cfg, world_predictor="teacher")


@pytest.mark.parametrize("cls", [nudge.PlannerSettings, nudge.SimConfig])
def test_repeated_keys_are_refused_naming_the_key(cls: type) -> None:
    key = "max_iter" if cls is nudge.PlannerSettings else "settle_steps"
    with pytest.raises(nudge.SettingsError, match=f"duplicate.*`{key}`"):
        cls.from_json(f'{{"{key}": 3, "{key}": 4}}')


def test_plan_names_a_retreat_lane_off_the_road() -> None:
    c = {"planner": nudge.Planner(None, nudge.Predictor.constant_velocity())}
    x = np.arange(8.0) * 3.0
    history = np.stack([np.stack([x, np.zeros(8)], 1), np.stack([x + 20.0, np.zeros(8)], 1)])
    ego = np.array([21.0, 0.0, 0.0, 10.0])
    assert _plan(c, history=history, ego=ego, y_retreat=-1.0)["status"] != "SolverFailed"
    for bad in (5.0, float("nan")):
        with pytest.raises(nudge.NudgeError, match="y_retreat"):
            _plan(c, history=history, ego=ego, y_retreat=bad)
