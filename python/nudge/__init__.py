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
    frames = nudge.to_frames(rec)                      # pandas DataFrames: runs, steps, collisions
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from nudge._native import (
    DEFAULTS,
    DT,
    GIT_SHA,
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
    Session,
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
    "GIT_SHA",
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
    "Session",
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
    "to_frames",
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
    progress: bool | Callable[[int, int], object] = False,
    planner: Any = None,
    out: str | os.PathLike[str] | None = None,
    ray: bool | str | None = None,
    ray_chunk: int | None = None,
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
    paths; a single path raises ``TypeError`` (pass ``[path]``).

    ``planner``: your own planner in nudge's worlds and metrics, any object with
    ``plan(observation) -> {"delta": [T], "accel": [T]}`` (and optionally ``reset()``), driving
    the ego instead of nudge's planner (the same records; ``docs/python_planner.md``); its runs
    go one after another on one thread. ``predictor`` is then the predictor nudge's safety check
    judges its plans with (each step's ``status``: ``Converged`` when the roll-out passes,
    ``Unsafe`` when not).

    ``progress``: ``True`` shows the runs done and the time left while the batch runs (a tqdm
    bar when tqdm is installed, else a line on stderr redrawn in place); a callable is called as
    ``progress(done, total)`` instead (about every 50 ms while the count grows, and once at the
    end; an exception it raises stops the batch and is raised). Off by default. The results are
    the same either way. :func:`to_frames` turns the result into pandas DataFrames.

    ``out``: also write the record set into this folder, exactly as ``nudge simulate --out``
    does (the same writer: ``steps.csv``, ``runs.csv``, ``collisions.csv``, ``records.json`` and
    ``provenance.json`` as one atomic set with its manifest ``outputs.sha256``; docs/records.md).
    Provenance's ``command`` is this process's command line (``sys.executable`` and
    ``sys.argv``); its ``settings_file`` and ``config_file`` are null (settings come as
    objects).

    ``ray``: fan the runs out as Ray tasks (:mod:`nudge.distributed`, ``docs/ray.md``; needs
    ``pip install "nudge-planner[ray]"``): ``True`` uses the Ray this process has initialised, or
    starts a local one on every core; an address (``"auto"``, ``"ray://head:10001"``) connects
    to that cluster. Each task runs ``ray_chunk`` consecutive (scene, seed) runs (default
    :data:`nudge.distributed.DEFAULT_CHUNK`) on ``threads`` threads (default 1); the result is
    the same, run by run and in the same order, as without Ray (only the wall-time columns
    differ); ``progress`` then counts finished tasks. A failed task raises
    :class:`nudge.distributed.RayRunError` naming its scenes and seeds. The scene, model and
    world files must be readable at the same paths on every node. Not with ``record``,
    ``out``, or your own Python ``predictor`` / ``planner`` object."""
    if isinstance(scene_paths, (str, bytes, os.PathLike)):
        raise TypeError(
            f"scene_paths: expected a sequence of scenario paths, got the single path {scene_paths!r} "
            "(pass [path])"
        )
    if ray is not None and ray is not False:
        return _simulate_on_ray(
            scene_paths, predictor, ray=ray, chunk=ray_chunk, world_predictor=world_predictor, idm=idm,
            seed=seed, scene_seeds=scene_seeds, runs=runs, threads=threads, settings=settings, config=config,
            record=record, trace=trace, on_error=on_error, progress=progress, planner=planner, out=out,
            config_overrides=config_overrides,
        )
    if ray_chunk is not None:
        raise InputError("ray_chunk: only with ray (runs per Ray task)")
    if progress is True:
        n_runs = len(scene_paths) * runs if isinstance(runs, int) and not isinstance(runs, bool) else 0
        callback, close = _progress_display(n_runs)
    elif progress is False or progress is None:
        callback, close = None, None
    elif callable(progress):
        callback, close = progress, None
    else:
        raise InputError(f"progress: expected True, False or a callable progress(done, total), got {progress!r}")
    try:
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
            progress=callback,
            planner=planner,
            out=None if out is None else os.fspath(out),
            command=[sys.executable, *sys.argv] if out is not None else None,
            **config_overrides,
        )
    finally:
        if close is not None:
            close()


def _simulate_on_ray(
    scene_paths: Sequence[str | os.PathLike[str]],
    predictor: Any,
    *,
    ray: bool | str,
    chunk: int | None,
    world_predictor: str | os.PathLike[str] | None,
    idm: str | os.PathLike[str] | None,
    seed: int,
    scene_seeds: Sequence[int] | None,
    runs: int,
    threads: int | None,
    settings: PlannerSettings | None,
    config: SimConfig | None,
    record: bool,
    trace: bool,
    on_error: str,
    progress: bool | Callable[[int, int], object],
    planner: Any,
    out: Any,
    config_overrides: dict[str, Any],
) -> dict[str, Any]:
    """:func:`simulate` with ``ray``: one sweep fanned out (:func:`nudge.distributed.run_sweeps`)."""
    from nudge import distributed

    for name, value in (("record", record), ("out", out), ("planner", planner)):
        if value:
            raise InputError(f"{name}: not with ray (run without ray for it)")
    if not isinstance(predictor, (str, os.PathLike)):
        raise InputError("predictor: a Python predictor object cannot go to Ray tasks (pass a name or weights path)")
    if not (ray is True or isinstance(ray, str)):
        raise InputError(f"ray: expected True (local or this process's Ray) or a cluster address, got {ray!r}")
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise InputError(f"runs: expected an int >= 1, got {runs!r}")
    n = len(scene_paths)
    if n == 0:
        raise InputError("scene_paths: expected at least one scenario file")
    seeds = [int(s) for s in scene_seeds] if scene_seeds is not None else [seed + i * runs for i in range(n)]
    if len(seeds) != n:
        raise InputError(f"scene_seeds: expected one seed per scene ({n}), got {len(seeds)}")
    cfg = config if config is not None else SimConfig.default()
    if config_overrides:
        cfg = cfg.replace(**config_overrides)
    kwargs = {
        "predictor": os.fspath(predictor),
        "world_predictor": None if world_predictor is None else os.fspath(world_predictor),
        "idm": None if idm is None else os.fspath(idm),
        "settings": (settings if settings is not None else PlannerSettings.default()).to_json(),
        "config": cfg.to_json(),
        "trace": trace,
        "on_error": on_error,
    }
    sweep = distributed.Sweep(tuple(os.fspath(p) for p in scene_paths), tuple(seeds), runs, kwargs)
    task_threads = 1 if threads is None else threads
    chunk = distributed.DEFAULT_CHUNK if chunk is None else chunk
    distributed.split(0, chunk)  # a bad chunk is refused before Ray starts
    distributed.check([sweep], task_threads, progress)
    distributed.connect(ray if isinstance(ray, str) else None)
    merged, _ = distributed.run_sweeps([sweep], chunk=chunk, task_threads=task_threads, progress=progress)
    return merged[0]


def _progress_display(total: int) -> tuple[Callable[[int, int], None], Callable[[], None]]:
    """A progress callback and its closer: a tqdm bar on stderr when tqdm is installed, else a
    line ``done/total runs, elapsed, ~left`` redrawn in place on stderr."""
    try:
        from tqdm.auto import tqdm
    except ImportError:
        tqdm = None
    if tqdm is not None:
        bar = tqdm(total=total or None, unit="run", desc="nudge.simulate")

        def update(done: int, n: int) -> None:
            if bar.total != n:
                bar.total = n
            bar.update(done - bar.n)

        return update, bar.close
    t0 = time.perf_counter()
    drawn = [False]

    def line(done: int, n: int) -> None:
        elapsed = time.perf_counter() - t0
        left = f", ~{elapsed / done * (n - done):.0f} s left" if done else ""
        sys.stderr.write(f"\rnudge.simulate: {done}/{n} runs, {elapsed:.0f} s{left}   ")
        sys.stderr.flush()
        drawn[0] = True

    def close() -> None:
        if drawn[0]:
            sys.stderr.write("\n")
            sys.stderr.flush()

    return line, close


def to_frames(result: Mapping[str, Any]) -> dict[str, Any]:
    """The tables of a :func:`simulate` result as pandas DataFrames: ``{"runs": ..., "steps": ...,
    "collisions": ...}``, one column per documented column (``docs/records.md``), in order.
    ``steps``' ``ego`` (``[steps, 4]``, the columns ``x``, ``y``, ``psi``, ``v`` side by side)
    is left out: its values are in those four columns. Needs pandas (``pip install pandas``);
    raises ``ImportError`` naming it otherwise, ``InputError`` for something that is not a
    :func:`simulate` result."""
    try:
        import pandas as pd
    except ImportError as e:
        raise ImportError("nudge.to_frames needs pandas (pip install pandas)") from e
    if not isinstance(result, Mapping) or not all(isinstance(result.get(k), Mapping) for k in _TABLES):
        raise InputError(f"to_frames: expected what nudge.simulate returned (a dict with {list(_TABLES)})")
    frames = {}
    for name in _TABLES:
        cols = {k: v for k, v in result[name].items() if not (name == "steps" and k == "ego")}
        frames[name] = pd.DataFrame(cols)
    return frames


_TABLES = ("runs", "steps", "collisions")


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
