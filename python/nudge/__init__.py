"""nudge: interaction-aware motion planning with neural (teacher / distilled student) predictions.

The Rust core is compiled into :mod:`nudge._native`; this package re-exports it and adds
name resolution for the shipped models and scenes, which the package carries in its ``assets``
folder (``$NUDGE_ASSETS`` overrides it; :func:`assets_dir`). The ``nudge`` command of an
installed package is the Rust command line (:mod:`nudge.__main__`)::

    import nudge
    sc = nudge.Scenario.load(nudge.scene_paths()[0])
    teacher = nudge.Predictor.load(nudge.model_path("teacher"))
    out = teacher.predict(sc.history, cands)   # [agents, 8, 2], [batch, 6, 2] -> [batch, agents-1, 6, 2]
    plan = nudge.Planner(nudge.PlannerSettings.default(), teacher).plan_scenario(sc)
    rec = nudge.simulate(nudge.scene_paths(), "student", world="idm", max_steps=20)
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from nudge._native import (
    DEFAULTS,
    DT,
    MAX_AGENTS,
    T_OBS,
    InputError,
    NudgeError,
    Planner,
    PlannerSettings,
    Predictor,
    PredictorError,
    Scenario,
    ScenarioError,
    SettingsError,
    SimConfig,
    SolverError,
    WeightsError,
    WorldFileError,
    __version__,
    commonroad_scenario,
    commonroad_solution,
    commonroad_tracks,
)
from nudge._native import assets_dir as _assets_dir
from nudge._native import model_path as _model_path
from nudge._native import scenes_dir as _scenes_dir
from nudge._native import simulate as _simulate

__all__ = [
    "DEFAULTS",
    "DT",
    "MAX_AGENTS",
    "SHIPPED_ASSETS",
    "T_OBS",
    "InputError",
    "NudgeError",
    "Planner",
    "PlannerSettings",
    "Predictor",
    "PredictorError",
    "Scenario",
    "ScenarioError",
    "SettingsError",
    "SimConfig",
    "SolverError",
    "WeightsError",
    "WorldFileError",
    "__version__",
    "assets_dir",
    "commonroad_scenario",
    "commonroad_solution",
    "commonroad_tracks",
    "model_path",
    "scene_paths",
    "simulate",
]

MODEL_NAMES = ("teacher", "student")

SHIPPED_ASSETS = (Path(__file__).parent / "assets").resolve()
"""The assets this package ships: ``models/`` (teacher, student) and ``scenes/`` (real NGSIM
scenes). In a checkout, ``python/nudge/assets`` links to the repository's ``assets``."""


def _assets_path() -> Path:
    return Path(_assets_dir(SHIPPED_ASSETS))


def assets_dir() -> Path:
    """The assets in use: ``$NUDGE_ASSETS`` if set (and not empty), else :data:`SHIPPED_ASSETS`
    (the rule of every front end: ``nudge_predictor::assets_dir``)."""
    path = _assets_path()
    if not path.is_dir():
        raise NudgeError(f"assets directory not found: {path} (set NUDGE_ASSETS)")
    return path


def model_path(name: str | os.PathLike[str]) -> Path:
    """``"teacher"`` / ``"student"`` -> the shipped weights file (the Rust resolver's path);
    anything else is a path."""
    s = os.fspath(name)
    if s in MODEL_NAMES:
        return Path(_model_path(assets_dir(), s))
    return Path(s)


def scene_paths(directory: str | os.PathLike[str] | None = None) -> list[Path]:
    """Every ``*.safetensors`` scenario in ``directory`` (default: ``scenes/`` of :func:`assets_dir`),
    sorted."""
    d = Path(directory) if directory is not None else Path(_scenes_dir(assets_dir()))
    if not d.is_dir():
        raise ScenarioError(f"scenario directory not found: {d}")
    return sorted(d.glob("*.safetensors"))


def simulate(
    scene_paths: Sequence[str | os.PathLike[str]],
    predictor: str | os.PathLike[str] | Any = DEFAULTS["predictor"],
    *,
    world_predictor: str | os.PathLike[str] | None = None,
    idm: str | os.PathLike[str] | None = None,
    seed: int = DEFAULTS["seed"],
    scene_seeds: Sequence[int] | None = None,
    runs: int = DEFAULTS["runs"],
    threads: int | None = None,
    settings: PlannerSettings | None = None,
    config: SimConfig | None = None,
    record: bool = False,
    on_error: str = "raise",
    **config_overrides: int | float | str,
) -> dict[str, Any]:
    """Closed-loop lane changes: :func:`nudge._native.simulate` with the named models
    (``"teacher"``, ``"student"``) and the ``idm`` world's driver population
    (``worlds/idm.json``) resolved under :func:`assets_dir`. Defaults come from Rust
    (:data:`DEFAULTS`, :meth:`SimConfig.default`); ``config_overrides`` are ``SimConfig``
    fields (``world="idm"``, ``max_steps=4``, ...). ``predictor`` may also be your own Python
    object with ``predict(history, candidates)`` (see ``nudge.Planner`` and
    ``docs/python_predictor.md``). ``scene_paths`` is a sequence of paths; a single path raises
    ``TypeError`` (pass ``[path]``)."""
    if isinstance(scene_paths, (str, bytes, os.PathLike)):
        raise TypeError(
            f"scene_paths: expected a sequence of scenario paths, got the single path {scene_paths!r} "
            "(pass [path])"
        )
    return _simulate(
        [os.fspath(p) for p in scene_paths],
        os.fspath(predictor) if isinstance(predictor, (str, os.PathLike)) else predictor,
        world_predictor=None if world_predictor is None else os.fspath(world_predictor),
        idm=None if idm is None else os.fspath(idm),
        seed=seed,
        scene_seeds=None if scene_seeds is None else [int(s) for s in scene_seeds],
        runs=runs,
        threads=threads,
        settings=settings,
        config=config,
        record=record,
        on_error=on_error,
        assets=os.fspath(_assets_path()),
        **config_overrides,
    )
