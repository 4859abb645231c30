"""nudge: interaction-aware motion planning with neural (teacher / distilled student) predictions.

The Rust core is compiled into :mod:`nudge._native`; this package re-exports it and adds
name resolution for the shipped models and scenes::

    import nudge
    sc = nudge.Scenario.load(nudge.scene_paths()[0])
    teacher = nudge.Predictor.load(nudge.model_path("teacher"))
    out = teacher.predict(sc.history, cands)   # [agents, 8, 2], [batch, 6, 2] -> [batch, agents-1, 6, 2]
    plan = nudge.Planner(nudge.PlannerSettings.default(), teacher).plan_scenario(sc)
    rec = nudge.simulate(nudge.scene_paths(), "student", world="predictor", world_predictor="teacher")
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from nudge._native import (
    DT,
    MAX_AGENTS,
    T_OBS,
    InputError,
    NudgeError,
    Planner,
    PlannerSettings,
    Predictor,
    Scenario,
    ScenarioError,
    SettingsError,
    SolverError,
    WeightsError,
    __version__,
)
from nudge._native import simulate as _simulate

__all__ = [
    "DT",
    "MAX_AGENTS",
    "T_OBS",
    "InputError",
    "NudgeError",
    "Planner",
    "PlannerSettings",
    "Predictor",
    "Scenario",
    "ScenarioError",
    "SettingsError",
    "SolverError",
    "WeightsError",
    "__version__",
    "assets_dir",
    "model_path",
    "scene_paths",
    "simulate",
]

MODEL_NAMES = ("teacher", "student")


def assets_dir() -> Path:
    """The shipped assets: ``$NUDGE_ASSETS`` if set, else ``<repo>/assets`` of this checkout."""
    env = os.environ.get("NUDGE_ASSETS")
    path = Path(env) if env else Path(__file__).resolve().parents[2] / "assets"
    if not path.is_dir():
        raise NudgeError(f"assets directory not found: {path} (set NUDGE_ASSETS)")
    return path


def model_path(name: str) -> Path:
    """``"teacher"`` / ``"student"`` -> the shipped weights file; anything else is a path."""
    if name in MODEL_NAMES:
        return assets_dir() / "models" / f"{name}.safetensors"
    return Path(name)


def scene_paths(directory: str | os.PathLike[str] | None = None) -> list[Path]:
    """Every ``*.safetensors`` scenario in ``directory`` (default: the shipped scenes), sorted."""
    d = Path(directory) if directory is not None else assets_dir() / "scenes"
    if not d.is_dir():
        raise ScenarioError(f"scenario directory not found: {d}")
    return sorted(d.glob("*.safetensors"))


def _resolve(predictor: str | os.PathLike[str]) -> str:
    s = os.fspath(predictor)
    return s if s == "constant_velocity" else str(model_path(s))


def simulate(
    scene_paths: Sequence[str | os.PathLike[str]],
    predictor: str | os.PathLike[str] = "teacher",
    *,
    world: str = "log_replay",
    world_predictor: str | os.PathLike[str] | None = None,
    seed: int = 0,
    scene_seeds: Sequence[int] | None = None,
    runs: int = 1,
    threads: int | None = None,
    settings: PlannerSettings | None = None,
    max_steps: int = 30,
    abort_after: int = 4,
    abort_hold: int = 3,
    record: bool = False,
    on_error: str = "raise",
) -> dict[str, Any]:
    """:func:`nudge._native.simulate` accepting ``"teacher"`` / ``"student"`` /
    ``"constant_velocity"`` or weight paths for ``predictor`` and ``world_predictor``."""
    return _simulate(
        [os.fspath(p) for p in scene_paths],
        _resolve(predictor),
        world=world,
        world_predictor=None if world_predictor is None else _resolve(world_predictor),
        seed=seed,
        scene_seeds=None if scene_seeds is None else [int(s) for s in scene_seeds],
        runs=runs,
        threads=threads,
        settings=settings,
        max_steps=max_steps,
        abort_after=abort_after,
        abort_hold=abort_hold,
        record=record,
        on_error=on_error,
    )
