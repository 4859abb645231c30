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
    runs = nudge.simulate(nudge.scene_paths()[:1], trace=True)
    nudge.animate(runs, "out/animations")              # one GIF (and MP4 with ffmpeg) per run
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from nudge._native import (
    DEFAULTS,
    DT,
    MAX_AGENTS,
    SLOW_FRACTION,
    T_OBS,
    InputError,
    NudgeError,
    Planner,
    PlannerSettings,
    Predictor,
    PredictorError,
    ReentrancyError,
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
from nudge._native import animate as _animate
from nudge._native import assets_dir as _assets_dir
from nudge._native import find_ffmpeg
from nudge._native import model_path as _model_path
from nudge._native import scenes_dir as _scenes_dir
from nudge._native import simulate as _simulate

__all__ = [
    "DEFAULTS",
    "DT",
    "MAX_AGENTS",
    "SHIPPED_ASSETS",
    "SLOW_FRACTION",
    "T_OBS",
    "InputError",
    "NudgeError",
    "Planner",
    "PlannerSettings",
    "Predictor",
    "PredictorError",
    "ReentrancyError",
    "Scenario",
    "ScenarioError",
    "SettingsError",
    "SimConfig",
    "SolverError",
    "WeightsError",
    "WorldFileError",
    "__version__",
    "animate",
    "assets_dir",
    "commonroad_scenario",
    "commonroad_solution",
    "commonroad_tracks",
    "find_ffmpeg",
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
    trace: bool = False,
    on_error: str = "raise",
    **config_overrides: int | float | str,
) -> dict[str, Any]:
    """Closed-loop lane changes: :func:`nudge._native.simulate` with the named models
    (``"teacher"``, ``"student"``) and the ``idm`` world's driver population
    (``worlds/idm.json``) resolved under :func:`assets_dir`. Defaults come from Rust
    (:data:`DEFAULTS`, :meth:`SimConfig.default`); ``config_overrides`` are ``SimConfig``
    fields (``world="idm"``, ``max_steps=4``, ...). ``predictor`` may also be your own Python
    object with ``predict(history, candidates)`` (see ``nudge.Planner`` and
    ``docs/python_predictor.md``). ``trace=True`` adds ``"traces"`` (each step's plan and the
    predicted reaction to it, per run) for :func:`animate`. ``scene_paths`` is a sequence of
    paths; a single path raises ``TypeError`` (pass ``[path]``)."""
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
        trace=trace,
        on_error=on_error,
        assets=os.fspath(_assets_path()),
        **config_overrides,
    )


def animate(
    records: Mapping[str, Any],
    out_dir: str | os.PathLike[str],
    *,
    runs: Iterable[int] | None = None,
    mp4: bool | None = None,
    **settings: float,
) -> list[Path]:
    """Writes one animation per run of ``records`` (what :func:`simulate` returned with
    ``trace=True``) into ``out_dir``: ``<scenario>-seed<seed>.gif``, and ``.mp4`` when ffmpeg
    is on ``PATH`` (``mp4=None``; ``True`` requires it, ``False`` writes GIFs only). ``runs``:
    the run indices to draw (default: every run that ran). ``settings``: ``px_per_m``,
    ``behind_m``, ``ahead_m``, ``margin_m`` (m), ``frame_s`` (s). The renderer is the one of
    ``nudge simulate --animate`` (:func:`nudge._native.animate`). Returns the files written.

    Raises ``InputError`` when ``records`` holds no traces or a run index is out of range or
    its trace is malformed, ``SettingsError`` for a bad setting, ``NudgeError`` when writing
    fails or ``mp4=True`` without ffmpeg."""
    traces = records.get("traces") if isinstance(records, Mapping) else None
    table = records.get("runs") if isinstance(records, Mapping) else None
    if not isinstance(traces, list) or not isinstance(table, Mapping):
        raise InputError("records: no traces (pass what nudge.simulate(..., trace=True) returned)")
    try:
        names, seeds = list(table["scenario"]), [int(s) for s in table["seed"]]
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"records['runs']: needs the scenario and seed columns ({e})") from None
    if not len(names) == len(seeds) == len(traces):
        raise InputError(f"records: {len(traces)} traces for {len(names)} runs")
    chosen = [i for i, t in enumerate(traces) if t is not None] if runs is None else list(runs)
    ffmpeg = None if mp4 is False else find_ffmpeg()
    if mp4 is True and ffmpeg is None:
        raise NudgeError("mp4=True: ffmpeg not found on PATH")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for i in chosen:
        if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < len(traces):
            raise InputError(f"runs: {i!r} is not a run index in 0..{len(traces) - 1}")
        if traces[i] is None:
            raise InputError(f"runs: run {i} could not run (its error is in records['runs']['error'])")
        stem = out / f"{names[i]}-seed{seeds[i]}"
        video = stem.with_name(stem.name + ".mp4") if ffmpeg is not None else None
        w = _animate(traces[i], stem.with_name(stem.name + ".gif"), mp4=video, ffmpeg=ffmpeg, **settings)
        written.append(Path(w["gif"]))
        if w["mp4"] is not None:
            written.append(Path(w["mp4"]))
    return written
