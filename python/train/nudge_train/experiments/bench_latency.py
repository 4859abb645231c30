"""``nudge-train bench latency``: the tail of the planning step in closed loop, on real scenes.

Not one cold call on one scene cut: every step of closed-loop runs (``nudge.simulate``, one
thread) on a seeded draw of a split's scenes counts. The draw and the scene seeds are those of
``nudge-train closed-loop`` (:func:`nudge_train.experiments.closed_loop.choose`), so the same
``--split``/``--n``/``--seed`` give the same scenes and target lanes there. Run::

    nudge-train bench latency [--split test] [--n 120] [--predictors student teacher constant_velocity]
                              [--world teacher] [--budget-ms X]

For every planning predictor it reports, from the step column ``mpc_s`` (the planner's own
wall time of one MPC call, measured in Rust):

* p50 / p90 / p99 / max (ms) over all steps and per agent-count bucket (``n_agents`` of the run,
  the ego included); percentiles are nearest-rank, so every reported value is an observed step;
* the share of every step status (``PlanStatus`` names);
* runs, success and collisions.

``--budget-ms X`` runs every predictor twice on the same (scene, seed) pairs, without a budget
and with ``PlannerSettings.budget_s = X / 1000``, and adds the count of steps above X + 1 ms and a
paired comparison of success and collisions. The arms of one scene chunk run one after the other
(chunk-major), so a change in the machine's load falls on every arm alike.

The report is a section of ``--out`` (default ``docs/results/latency.md``) between markers named
by the budget (``budget off`` / ``budget X ms``): a rerun replaces its own section and keeps the
rest of the file. It records the machine: CPU model, logical CPUs, niceness, and the load average
at the start and the end (one thread; the numbers are only as quiet as the machine was).
"""

from __future__ import annotations

import math
import os
import platform
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nudge_train import paths
from nudge_train.experiments.latency_config import N_EDGES, LatencyConfig

__all__ = [
    "N_EDGES",
    "STATUSES",
    "Arm",
    "ArmResult",
    "LatencyConfig",
    "budget_table",
    "bucket_labels",
    "collect",
    "latency_rows",
    "latency_table",
    "outcome_table",
    "outcomes",
    "paired",
    "percentiles",
    "report",
    "run",
    "slow_statuses",
    "status_shares",
    "status_table",
    "write_section",
]

STATUSES = ("Converged", "MaxIterations", "Refined", "Backtracked", "Fallback", "Unsafe", "BudgetExhausted",
            "SolverFailed")
"""Step statuses in the order of the report (``nudge_planner::StepStatus`` names); a status not
listed here gets its own column rather than being dropped."""
QUANTILES = (50, 90, 99)
"""Percentiles of the step time in the report (plus the maximum)."""


@dataclass(frozen=True)
class Arm:
    """One timed configuration: a planning predictor with or without a work budget (ms), at the
    default horizon or at ``horizon`` steps."""

    predictor: str
    budget_ms: float | None
    horizon: int | None = None

    @property
    def label(self) -> str:
        """``predictor`` or ``predictor, h = N`` (an arm at a chosen horizon)."""
        return self.predictor if self.horizon is None else f"{self.predictor}, h = {self.horizon}"

    def budget_label(self) -> str:
        """``off`` or ``X ms``."""
        return "off" if self.budget_ms is None else f"{self.budget_ms:g} ms"


@dataclass
class ArmResult:
    """The merged columns of one arm: run columns (``n_agents``, ``success``, ``collision``,
    ``collisions_at_fault``, ``collisions_not_at_fault``, ``scenario``, ``seed``, ``error``),
    step columns (``run`` (row of the run columns), ``mpc_s`` (s), ``status``), and the wall and
    process CPU time of its simulations (s; their ratio is the share of a core the runs got)."""

    arm: Arm
    runs: dict[str, list]
    steps: dict[str, list]
    wall_s: float = 0.0
    cpu_s: float = 0.0


RUN_KEEP = ("scenario", "seed", "n_agents", "success", "collision", "collisions_at_fault", "collisions_not_at_fault",
            "error")
STEP_KEEP = ("run", "mpc_s", "status")


# ---- the numbers -----------------------------------------------------------------------------------
def percentiles(values_ms: Sequence[float] | np.ndarray) -> dict[str, float]:
    """Nearest-rank percentiles (``p50``, ``p90``, ``p99``) and ``max`` of step times (ms): the
    p-th percentile is the smallest value with at least p % of the values at or below it, so it
    is always an observed value. NaN for no values; ValueError when a value is not finite."""
    v = np.asarray(values_ms, dtype=np.float64)
    keys = [f"p{q}" for q in QUANTILES] + ["max"]
    if v.size == 0:
        return dict.fromkeys(keys, math.nan)
    if not np.all(np.isfinite(v)):
        bad = int(np.flatnonzero(~np.isfinite(v))[0])
        raise ValueError(f"step time {bad} is not finite ({v[bad]})")
    q = np.percentile(v, QUANTILES, method="inverted_cdf")
    return dict(zip(keys, [float(x) for x in q] + [float(v.max())], strict=True))


def bucket_labels(edges: Sequence[int]) -> list[str]:
    """Labels of the agent-count buckets cut at ``edges`` (inclusive upper bounds):
    (8, 16) -> ``["N ≤ 8", "9–16", "N ≥ 17"]``."""
    labels = [f"N ≤ {edges[0]}"]
    labels += [f"{lo + 1}–{hi}" for lo, hi in zip(edges[:-1], edges[1:], strict=True)]
    return [*labels, f"N ≥ {edges[-1] + 1}"]


def bucket_index(n_agents: np.ndarray, edges: Sequence[int]) -> np.ndarray:
    """Bucket of every agent count (index into :func:`bucket_labels`)."""
    return np.searchsorted(np.asarray(edges), np.asarray(n_agents), side="left")


def latency_rows(result: ArmResult, edges: Sequence[int], over_ms: float | None = None) -> list[dict]:
    """Rows of the latency table of one arm: ``all`` first, then every non-empty agent-count
    bucket; each with ``bucket``, ``runs``, ``steps``, the :func:`percentiles` (ms) and, when
    ``over_ms`` is given, ``over`` (steps strictly above ``over_ms``)."""
    mpc_ms = np.asarray(result.steps["mpc_s"], dtype=np.float64) * 1e3
    run = np.asarray(result.steps["run"], dtype=np.int64)
    n_agents = np.asarray(result.runs["n_agents"], dtype=np.int64)
    if run.size and (run.min() < 0 or run.max() >= n_agents.size):
        raise ValueError(f"step column 'run' refers to run {int(run.max())}, but there are {n_agents.size} runs")
    ok = np.array([e is None for e in result.runs["error"]], dtype=bool)
    run_bucket = bucket_index(n_agents, edges)
    step_bucket = run_bucket[run]

    def row(label: str, run_mask: np.ndarray, step_mask: np.ndarray) -> dict:
        r = {"bucket": label, "runs": int((run_mask & ok).sum()), "steps": int(step_mask.sum()),
             **percentiles(mpc_ms[step_mask])}
        if over_ms is not None:
            r["over"] = int((mpc_ms[step_mask] > over_ms).sum())
        return r

    rows = [row("all", np.ones(n_agents.size, dtype=bool), np.ones(mpc_ms.size, dtype=bool))]
    for b, label in enumerate(bucket_labels(edges)):
        if (step_bucket == b).any():
            rows.append(row(label, run_bucket == b, step_bucket == b))
    return rows


def status_shares(statuses: Sequence[str]) -> dict[str, float]:
    """Share (0..1) of every status among the steps: every name of :data:`STATUSES` in order
    (0 when absent), then any other name found, in sorted order. Empty for no steps."""
    names, counts = np.unique(np.asarray(list(statuses), dtype=str), return_counts=True)
    total = int(counts.sum())
    if total == 0:
        return {}
    found = dict(zip(names.tolist(), counts.tolist(), strict=True))
    order = list(STATUSES) + sorted(set(found) - set(STATUSES))
    return {s: found.get(s, 0) / total for s in order}


def slow_statuses(result: ArmResult, over_ms: float) -> dict[str, int]:
    """How many steps strictly above ``over_ms`` ended with each status (statuses with none
    left out; the order of :data:`STATUSES`, then any other name)."""
    mpc_ms = np.asarray(result.steps["mpc_s"], dtype=np.float64) * 1e3
    slow = np.asarray(result.steps["status"], dtype=str)[mpc_ms > over_ms]
    names, counts = np.unique(slow, return_counts=True)
    found = dict(zip(names.tolist(), counts.tolist(), strict=True))
    order = list(STATUSES) + sorted(set(found) - set(STATUSES))
    return {s: found[s] for s in order if s in found}


def outcomes(result: ArmResult) -> dict[str, int]:
    """Runs, runs that could not run (``errors``), successes, runs with a collision and
    collision events (at fault + not at fault) of one arm."""
    ok = np.array([e is None for e in result.runs["error"]], dtype=bool)

    def total(name: str) -> int:
        return int(np.asarray(result.runs[name], dtype=np.int64)[ok].sum())

    return {"runs": int(ok.sum()), "errors": int((~ok).sum()), "success": total("success"),
            "collision_runs": total("collision"),
            "collisions": total("collisions_at_fault") + total("collisions_not_at_fault")}


def paired(off: ArmResult, on: ArmResult) -> dict[str, int]:
    """The budget arm against the arm without a budget on their common (scene, seed) runs:
    ``pairs``; successes and runs with a collision in each arm (``success_off`` / ``success_on``,
    ``collision_off`` / ``collision_on``); successes lost / gained and collision runs new / gone
    with the budget."""
    def index(r: ArmResult) -> dict[tuple[str, int], int]:
        return {(s, int(d)): i for i, (s, d, e) in
                enumerate(zip(r.runs["scenario"], r.runs["seed"], r.runs["error"], strict=True)) if e is None}
    ia, ib = index(off), index(on)
    common = sorted(set(ia) & set(ib))
    a = [ia[k] for k in common]
    b = [ib[k] for k in common]
    sa, sb = (np.asarray(off.runs["success"], dtype=bool)[a], np.asarray(on.runs["success"], dtype=bool)[b])
    ca, cb = (np.asarray(off.runs["collision"], dtype=bool)[a], np.asarray(on.runs["collision"], dtype=bool)[b])
    return {"pairs": len(common), "success_off": int(sa.sum()), "success_on": int(sb.sum()),
            "collision_off": int(ca.sum()), "collision_on": int(cb.sum()),
            "success_lost": int((sa & ~sb).sum()), "success_gained": int((~sa & sb).sum()),
            "collision_new": int((~ca & cb).sum()), "collision_gone": int((ca & ~cb).sum())}


# ---- the tables ------------------------------------------------------------------------------------
def _ms(x: float) -> str:
    return "–" if math.isnan(x) else f"{x:.1f}" if x >= 10 else f"{x:.2f}"


def latency_table(results: Sequence[ArmResult], edges: Sequence[int], budget_ms: float | None) -> str:
    """Markdown: one row per arm and agent-count bucket."""
    over = None if budget_ms is None else budget_ms + 1.0
    head = "| predictor | budget | N | runs | steps | p50 (ms) | p90 (ms) | p99 (ms) | max (ms) |"
    rule = "|---|---|---|---|---|---|---|---|---|"
    if over is not None:
        head += f" steps > {over:g} ms |"
        rule += "---|"
    lines = [head, rule]
    for res in results:
        for r in latency_rows(res, edges, over):
            line = (f"| {res.arm.label} | {res.arm.budget_label()} | {r['bucket']} | {r['runs']} | {r['steps']} "
                    f"| {_ms(r['p50'])} | {_ms(r['p90'])} | {_ms(r['p99'])} | {_ms(r['max'])} |")
            if over is not None:
                line += f" {r['over']} |"
            lines.append(line)
    return "\n".join(lines)


def status_table(results: Sequence[ArmResult]) -> str:
    """Markdown: the share (%) of every step status per arm."""
    shares = [status_shares(r.steps["status"]) for r in results]
    names = list(STATUSES) + sorted({s for sh in shares for s in sh} - set(STATUSES))
    lines = ["| predictor | budget | steps | " + " | ".join(names) + " |", "|---|---|---|" + "---|" * len(names)]
    for res, sh in zip(results, shares, strict=True):
        cells = " | ".join(f"{100 * sh.get(s, 0.0):.1f} %" for s in names)
        lines.append(f"| {res.arm.label} | {res.arm.budget_label()} | {len(res.steps['status'])} | {cells} |")
    return "\n".join(lines)


def outcome_table(results: Sequence[ArmResult]) -> str:
    """Markdown: runs, success and collisions per arm, the simulation wall time and the share of
    a core the simulations got (process CPU time / wall time)."""
    lines = ["| predictor | budget | runs | errors | success | runs with a collision | collision events | wall (s) "
             "| CPU / wall |", "|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        o = outcomes(res)
        share = f"{100 * res.cpu_s / res.wall_s:.0f} %" if res.wall_s > 0 else "–"
        lines.append(f"| {res.arm.label} | {res.arm.budget_label()} | {o['runs']} | {o['errors']} "
                     f"| {o['success']} | {o['collision_runs']} | {o['collisions']} | {res.wall_s:.0f} | {share} |")
    return "\n".join(lines)


def budget_table(results: Sequence[ArmResult], edges: Sequence[int], budget_ms: float) -> str:
    """Markdown: per predictor, the arm without a budget against the arm with ``budget_ms`` on
    the same runs: steps above ``budget_ms`` + 1 ms and maxima (all steps of each arm), success
    and collisions (the paired runs)."""
    over = budget_ms + 1.0
    by_pred: dict[str, dict[bool, ArmResult]] = {}
    for r in results:
        by_pred.setdefault(r.arm.label, {})[r.arm.budget_ms is not None] = r
    head = (f"| predictor | paired runs | steps > {over:g} ms (off → on) | max ms (off → on) "
            "| success (off → on) | successes lost / gained | runs with a collision (off → on) "
            "| collision runs new / gone |")
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    for pred, arms in by_pred.items():
        if False not in arms or True not in arms:
            continue
        off, on = arms[False], arms[True]
        ro, rb = latency_rows(off, edges, over)[0], latency_rows(on, edges, over)[0]
        p = paired(off, on)
        lines.append(f"| {pred} | {p['pairs']} | {ro['over']} → {rb['over']} | {_ms(ro['max'])} → {_ms(rb['max'])} "
                     f"| {p['success_off']} → {p['success_on']} | {p['success_lost']} / {p['success_gained']} "
                     f"| {p['collision_off']} → {p['collision_on']} | {p['collision_new']} / {p['collision_gone']} |")
    return "\n".join(lines)


# ---- the machine -----------------------------------------------------------------------------------
def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what :mod:`platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def load_average() -> tuple[float, float, float] | None:
    """The 1, 5 and 15 minute load averages, or None where the system has none."""
    try:
        return os.getloadavg()
    except OSError:
        return None


def _load(x: tuple[float, float, float] | None) -> str:
    return "n/a" if x is None else " / ".join(f"{v:.2f}" for v in x)


# ---- running -----------------------------------------------------------------------------------------
def _arms(cfg: LatencyConfig) -> list[Arm]:
    budgets: list[float | None] = [None] if cfg.budget_ms is None else [None, cfg.budget_ms]
    horizons: tuple[int | None, ...] = cfg.horizons or (None,)
    return [Arm(p, b, h) for p in cfg.predictors for h in horizons for b in budgets]


def collect(cfg: LatencyConfig, log: Callable[[str], None] = print) -> tuple[list[ArmResult], dict]:
    """Runs every arm on the chosen scenes, one thread, chunk-major (every arm on a chunk of
    scenes before the next chunk); returns the merged results and what was run (scenes, teacher
    subset, machine, load average at start and end, wall time)."""
    import nudge

    from nudge_train.experiments.closed_loop import EvalConfig, choose

    cfg.validate()
    draw = EvalConfig(scenes=Path(cfg.scenes), n=cfg.n, seeds=cfg.runs, seed=cfg.seed,
                      teacher_n=cfg.teacher_n if cfg.teacher_n is not None else sys.maxsize)
    scenes, scene_seeds, subset = choose(draw)
    if not scenes:
        raise FileNotFoundError(f"no scenario files in {cfg.scenes}")
    sim_cfg = nudge.SimConfig.default().replace(world=cfg.world)
    base = nudge.PlannerSettings.default()
    arms = _arms(cfg)
    results = [ArmResult(a, {k: [] for k in RUN_KEEP}, {k: [] for k in STEP_KEEP}) for a in arms]
    teacher_set = set(subset)
    chunks = [list(range(i, min(i + cfg.chunk, len(scenes)))) for i in range(0, len(scenes), cfg.chunk)]
    load_start, t_start = load_average(), time.perf_counter()
    for ci, chunk in enumerate(chunks):
        for res in results:
            arm = res.arm
            idx = [i for i in chunk if arm.predictor != "teacher" or i in teacher_set]
            if not idx:
                continue
            settings = base if arm.budget_ms is None else base.replace(budget={"seconds": arm.budget_ms / 1e3})
            if arm.horizon is not None:
                settings = settings.replace(model={"horizon": arm.horizon})
            t0, c0 = time.perf_counter(), time.process_time()
            out = nudge.simulate([scenes[i] for i in idx], arm.predictor, scene_seeds=[scene_seeds[i] for i in idx],
                                 runs=cfg.runs, threads=1, settings=settings, config=sim_cfg, on_error="skip")
            res.wall_s += time.perf_counter() - t0
            res.cpu_s += time.process_time() - c0
            offset = len(res.runs["error"])
            for k in RUN_KEEP:
                res.runs[k].extend(np.asarray(out["runs"][k]).tolist() if k != "error" else out["runs"][k])
            res.steps["run"].extend((np.asarray(out["steps"]["run"], dtype=np.int64) + offset).tolist())
            res.steps["mpc_s"].extend(np.asarray(out["steps"]["mpc_s"], dtype=np.float64).tolist())
            res.steps["status"].extend(list(out["steps"]["status"]))
        if cfg.progress:
            log(f"chunk {ci + 1}/{len(chunks)}: {chunk[-1] + 1}/{len(scenes)} scenes "
                f"({time.perf_counter() - t_start:.0f} s elapsed, load average {_load(load_average())})")
    meta = {"scenes": len(scenes), "teacher_scenes": len(subset), "runs": cfg.runs, "world": cfg.world,
            "cpu": cpu_model(), "cpus": os.cpu_count(), "nice": os.nice(0), "load_start": load_start,
            "load_end": load_average(), "wall_s": time.perf_counter() - t_start,
            "native": Path(nudge._native.__file__).name}
    return results, meta


def section_key(budget_ms: float | None, horizons: Sequence[int] = ()) -> str:
    """The name of a report's section in the output file: ``budget off`` / ``budget X ms``, with
    ``, horizons 6 10`` when the arms ran at chosen horizons."""
    key = "budget off" if budget_ms is None else f"budget {budget_ms:g} ms"
    return key + (f", horizons {' '.join(str(h) for h in horizons)}" if horizons else "")


def report(results: Sequence[ArmResult], meta: dict, cfg: LatencyConfig, command: str) -> str:
    """The markdown section of one run of the bench."""
    teacher = ""
    if "teacher" in cfg.predictors and meta["teacher_scenes"] < meta["scenes"]:
        teacher = f" (the teacher planner on a seeded subset of {meta['teacher_scenes']})"
    lines = [
        f"### {section_key(cfg.budget_ms, cfg.horizons).capitalize()}",
        "",
        f"`{command}`",
        "",
        f"- scenes: {meta['scenes']} of `{paths.repo_relative(Path(cfg.scenes))}` (seed {cfg.seed}){teacher}, "
        f"{meta['runs']} run(s) per scene, world `{meta['world']}`, default planner settings"
        + ("" if not cfg.horizons else
           " at each horizon " + ", ".join(f"{h} steps ({h * 0.3:.1f} s)" for h in cfg.horizons)
           + " (`horizon`, arms `predictor, h = N`; every arm on the same runs)")
        + ("" if cfg.budget_ms is None else f", and the same with `budget_s` = {cfg.budget_ms / 1e3:g}"),
        f"- machine: {meta['cpu']}, {meta['cpus']} logical CPUs, planner on 1 thread, niceness {meta['nice']}; "
        f"load average (1 / 5 / 15 min) {_load(meta['load_start'])} at the start, {_load(meta['load_end'])} "
        f"at the end; {meta['wall_s']:.0f} s in all",
        "",
        "Planning step time (`mpc_s`, nearest-rank percentiles; N = vehicles in the scene, the ego included):",
        "",
        latency_table(results, cfg.n_edges, cfg.budget_ms),
        "",
        "Step statuses (share of steps):",
        "",
        status_table(results),
        "",
        "Runs:",
        "",
        outcome_table(results),
    ]
    if cfg.budget_ms is not None:
        over = cfg.budget_ms + 1.0
        lines += ["", f"With the {cfg.budget_ms:g} ms budget against without, on the same (scene, seed) runs:", "",
                  budget_table(results, cfg.n_edges, cfg.budget_ms), "", f"Statuses of the steps above {over:g} ms:",
                  ""]
        for res in results:
            counts = ", ".join(f"{k} {v}" for k, v in slow_statuses(res, over).items()) or "none"
            lines.append(f"- {res.arm.label}, budget {res.arm.budget_label()}: {counts}")
    return "\n".join(lines) + "\n"


def write_section(path: Path, key: str, text: str, title: str = "# Planning-step latency in closed loop") -> None:
    """Writes ``text`` into ``path`` between the markers of ``key``: replaces that section when
    the file has it, else appends it (a new file starts with ``title``); the rest of the file
    is kept."""
    begin, end = f"<!-- bench latency: {key} -->", f"<!-- /bench latency: {key} -->"
    block = f"{begin}\n{text.rstrip()}\n{end}\n"
    old = path.read_text() if path.is_file() else f"{title}\n"
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end) + r"\n?", re.DOTALL)
    if pattern.search(old):
        new = pattern.sub(lambda _: block, old, count=1)
    else:
        new = old.rstrip("\n") + "\n\n" + block
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(new)


def command_line(argv: Sequence[str]) -> str:
    """The command as the report names it (no machine paths)."""
    return " ".join(["nudge-train", "bench", "latency", *argv])


def run(cfg: LatencyConfig, out: Path | None, command: str) -> int:
    """``nudge-train bench latency``: runs, prints the section and writes it into ``out``.
    Returns the exit status (2 when an argument is invalid or the folder holds no scenario)."""
    import nudge

    try:
        results, meta = collect(cfg, log=lambda s: print(s, flush=True))
    except (ValueError, FileNotFoundError, nudge.SettingsError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    text = report(results, meta, cfg, command)
    print(text)
    if out is not None:
        write_section(out, section_key(cfg.budget_ms, cfg.horizons), text)
        print(f"wrote {paths.repo_relative(out)}")
    return 0
