"""Closed-loop runs fanned out as Ray tasks, merged run for run as one process runs them.

A *sweep* is one :func:`nudge.simulate` call: scenes, each with its seed, ``runs`` runs per
scene, and the rest of the call's arguments. Its runs, in the order one process runs them
(scene-major; run ``r`` of scene ``i`` draws seed ``scene_seeds[i] + r``), are cut into
*chunks* of ``chunk`` consecutive (scene, seed) runs; each chunk is one Ray task that calls
the native simulator on just those runs (``runs=1`` per listed scene, its seed given) with
``task_threads`` threads. The driver merges the chunks back in run order: the ``runs`` table's
rows, the ``steps`` and ``collisions`` rows with their ``run`` index shifted to the sweep's run
index, ``scene_index`` mapped back to the sweep's scene. Every run depends only on its scene,
its seed and the settings, so the merged tables equal those of one process, run by run (the
wall-time columns ``mpc_s``, ``z_s``, ``z_median_s`` measure the machine and differ between any
two executions).

A failed task raises :class:`RayRunError` naming its chunk (scenes and seeds) and the cause;
the other tasks are cancelled and nothing is returned. Used by ``nudge.simulate(..., ray=...)``
and by ``nudge-train closed-loop --ray``; ``docs/ray.md`` says how to run it on a cluster.
Needs Ray (``pip install "nudge-planner[ray]"``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nudge._native import InputError, NudgeError

__all__ = ["DEFAULT_CHUNK", "RayConnectError", "RayRunError", "Sweep", "build", "check", "connect", "merge", "run_sweeps", "split"]

DEFAULT_CHUNK = 8
"""Runs per Ray task by default: long enough (seconds) that the task overhead (milliseconds)
does not count, short enough that the tasks balance over the workers."""

TIMING_COLUMNS = {"steps": ("mpc_s", "z_s", "z_median_s")}
"""The columns that measure wall time (they differ between any two executions of a run)."""


class RayRunError(NudgeError):
    """A Ray task of a sweep failed. ``sweep``: the sweep's label; ``runs``: the (scene file
    name, seed) runs of the failed chunk, in run order; ``cause``: what failed (the task's
    exception, or Ray's message for a lost worker)."""

    def __init__(self, sweep: str, runs: list[tuple[str, int]], cause: str) -> None:
        self.sweep = sweep
        self.runs = runs
        self.cause = cause
        listed = ", ".join(f"{s} seed {d}" for s, d in runs)
        super().__init__(f"Ray task of {sweep} failed on the runs [{listed}]: {cause}")


class RayConnectError(NudgeError):
    """Ray could not be started or connected to. ``address``: the address (None: a local Ray);
    ``cause``: Ray's message."""

    def __init__(self, address: str | None, cause: str) -> None:
        self.address = address
        self.cause = cause
        where = f"the Ray cluster at {address}" if address else "a local Ray"
        super().__init__(f"cannot start or reach {where}: {cause}")


@dataclass(frozen=True)
class Sweep:
    """One :func:`nudge.simulate` call to fan out. ``scene_paths``: scenario files (as the
    workers see them); ``scene_seeds``: one seed per scene (run ``r`` draws ``seed + r``);
    ``runs``: runs per scene; ``kwargs``: the other keyword arguments of the native
    ``simulate`` (``predictor``, ``world_predictor``, ``idm``, ``on_error``, ``trace``, and
    ``settings`` / ``config`` as JSON text, rebuilt on the worker; named models resolve under
    the worker's own :func:`nudge.assets_dir`); ``label``: how errors name the sweep."""

    scene_paths: tuple[str, ...]
    scene_seeds: tuple[int, ...]
    runs: int
    kwargs: dict[str, Any] = field(default_factory=dict)
    label: str = "nudge.simulate"

    def specs(self) -> list[tuple[int, int]]:
        """(scene index, seed) of every run, in the order one process runs them."""
        return [(i, int(s) + r) for i, s in enumerate(self.scene_seeds) for r in range(self.runs)]


def split(n_runs: int, chunk: int) -> list[range]:
    """The run ranges of the tasks: consecutive, ``chunk`` runs each (the last may be shorter)."""
    if chunk < 1:
        raise InputError(f"ray chunk: expected at least 1 run per task, got {chunk}")
    return [range(a, min(a + chunk, n_runs)) for a in range(0, n_runs, chunk)]


def connect(address: str | None, num_cpus: int | None = None) -> str:
    """Ray for the tasks: one already initialised in this process is used as is; otherwise
    ``address`` (``"auto"``, ``"ray://host:10001"``, ``"host:6379"``) is connected to, or
    without one a local Ray is started with ``num_cpus`` CPUs (default: all cores). Returns
    what was used (the address, or ``"local (<its address>)"``). Raises
    :class:`RayConnectError` when Ray cannot be started or reached (e.g. a cluster with token
    authentication and no token here)."""
    import ray

    if not ray.is_initialized():
        try:
            if address:
                ray.init(address=address, log_to_driver=False)
            else:
                ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
        except Exception as err:  # noqa: BLE001 (Ray raises ConnectionError, RuntimeError, ValueError...)
            raise RayConnectError(address, _chain(err)) from err
    if address:
        return address
    ctx = ray.get_runtime_context()
    gcs = getattr(ctx, "gcs_address", None)
    return f"local ({gcs})" if gcs else "local"


def _run_chunk(paths: list[str], seeds: list[int], threads: int, kwargs: dict[str, Any]) -> tuple[dict, float, str]:
    """One task: the simulator on the runs (paths[k], seeds[k]), one run each; returns its
    result, its wall time (s) and the worker's nudge build (:func:`build`)."""
    import nudge

    kw = dict(kwargs)
    if kw.get("settings") is not None:
        kw["settings"] = nudge.PlannerSettings.from_json(kw["settings"])
    if kw.get("config") is not None:
        kw["config"] = nudge.SimConfig.from_json(kw["config"])
    t0 = time.perf_counter()
    res = nudge.simulate(paths, kw.pop("predictor"), scene_seeds=seeds, runs=1, threads=threads, **kw)
    return dict(res), time.perf_counter() - t0, build()


def build() -> str:
    """This process's nudge build: version and git commit (every worker must run the driver's)."""
    import nudge

    return f"{nudge.__version__} ({nudge.GIT_SHA})"


def _concat(parts: list[Any]) -> Any:
    if isinstance(parts[0], np.ndarray):
        return np.concatenate(parts, axis=0)
    out: list = []
    for p in parts:
        out.extend(p)
    return out


def merge(sweep: Sweep, chunks: list[range], results: list[dict]) -> dict[str, Any]:
    """The tables of a sweep from its chunks' results (in chunk order): rows concatenated,
    ``run`` shifted by each chunk's first run, ``scene_index`` mapped to the sweep's scene."""
    specs = sweep.specs()
    out: dict[str, Any] = {}
    for table in ("runs", "steps", "collisions"):
        columns: dict[str, list] = {}
        for rng, res in zip(chunks, results, strict=True):
            for name, col in res[table].items():
                if table == "runs" and name == "scene_index":
                    col = np.asarray([specs[rng.start + int(k)][0] for k in col], dtype=np.asarray(col).dtype)
                elif table != "runs" and name == "run":
                    col = np.asarray(col) + rng.start
                columns.setdefault(name, []).append(col)
        out[table] = {name: _concat(parts) for name, parts in columns.items()}
    if all("traces" in r for r in results):
        out["traces"] = _concat([r["traces"] for r in results])
    return out


def check(sweeps: Sequence[Sweep], task_threads: int, progress: object) -> None:
    """Raises InputError for arguments every task would fail on (before Ray is touched)."""
    if isinstance(task_threads, bool) or not isinstance(task_threads, int) or task_threads < 1:
        raise InputError(f"ray task threads: expected an int >= 1, got {task_threads!r}")
    if not (progress is True or progress is False or progress is None or callable(progress)):
        raise InputError(f"progress: expected True, False or a callable progress(done, total), got {progress!r}")
    for s in sweeps:
        if s.kwargs.get("on_error", "raise") not in ("raise", "skip"):
            raise InputError(f"on_error: expected \"raise\" or \"skip\", got {s.kwargs['on_error']!r}")


def run_sweeps(
    sweeps: Sequence[Sweep],
    *,
    chunk: int = DEFAULT_CHUNK,
    task_threads: int = 1,
    progress: bool | Callable[[int, int], object] = False,
) -> tuple[list[dict[str, Any]], list[float]]:
    """Runs every sweep on the Ray of this process (:func:`connect` first): all their chunks
    at once as tasks of ``task_threads`` CPUs each; returns each sweep's merged result
    (:func:`merge`) and the sum of its tasks' wall times (s). ``progress``: ``True`` draws a
    tqdm bar over the finished tasks on stderr; a callable is called as ``progress(done,
    total)`` in tasks. Raises :class:`RayRunError` when a task fails (the others cancelled)."""
    import ray

    check(sweeps, task_threads, progress)
    remote = ray.remote(num_cpus=task_threads, max_retries=0)(_run_chunk)
    plan = [(si, split(len(s.specs()), chunk)) for si, s in enumerate(sweeps)]
    pending: dict[Any, tuple[int, int]] = {}
    for si, chunks in plan:
        s = sweeps[si]
        specs = s.specs()
        for ci, rng in enumerate(chunks):
            paths = [s.scene_paths[specs[k][0]] for k in rng]
            seeds = [specs[k][1] for k in rng]
            pending[remote.remote(paths, seeds, task_threads, s.kwargs)] = (si, ci)
    total = len(pending)
    results: list[list[dict | None]] = [[None] * len(chunks) for _, chunks in plan]
    wall = [0.0] * len(sweeps)
    bar, report = _progress(progress, total)
    try:
        done = 0
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            si, ci = pending.pop(ready[0])
            try:
                res, dt, worker = ray.get(ready[0])
                if worker != build():
                    raise RuntimeError(f"the worker runs nudge {worker}, this process nudge {build()}")
            except Exception as err:  # noqa: BLE001 (a task's exception or a lost worker, named below)
                for ref in pending:
                    ray.cancel(ref, force=True)
                s = sweeps[si]
                specs = s.specs()
                runs = [(os.path.basename(s.scene_paths[specs[k][0]]), specs[k][1]) for k in plan[si][1][ci]]
                raise RayRunError(s.label, runs, _cause(err)) from None
            results[si][ci] = res
            wall[si] += dt
            done += 1
            if report is not None:
                report(done, total)
    finally:
        if bar is not None:
            bar.close()
    merged = [merge(sweeps[si], chunks, results[si]) for si, chunks in plan]  # type: ignore[arg-type]
    return merged, wall


def _cause(err: BaseException) -> str:
    """The task's own exception (type and message) when Ray carries one, else Ray's message."""
    inner = getattr(err, "cause", None)
    if isinstance(inner, BaseException):
        return f"{type(inner).__name__}: {inner}"
    return f"{type(err).__name__}: {str(err).strip().splitlines()[-1] if str(err).strip() else ''}"


def _chain(err: BaseException) -> str:
    """The last line of the message of ``err`` and of each exception that caused it."""
    parts = []
    e: BaseException | None = err
    while e is not None and len(parts) < 4:
        text = str(e).strip()
        parts.append(f"{type(e).__name__}: {text.splitlines()[-1] if text else ''}")
        e = e.__cause__
    return "; caused by ".join(parts)


def _progress(progress: bool | Callable[[int, int], object], total: int) -> tuple[Any, Callable | None]:
    if progress is True:
        try:
            from tqdm.auto import tqdm
        except ImportError:
            import nudge

            update, close = nudge._progress_display(total)  # a line on stderr (counts tasks)
            return _Closer(close), update
        bar = tqdm(total=total, unit="task", desc="ray tasks")

        def update(done: int, n: int) -> None:
            bar.update(done - bar.n)

        return bar, update
    if callable(progress):
        return None, progress
    return None, None


@dataclass
class _Closer:
    close: Callable[[], None]
