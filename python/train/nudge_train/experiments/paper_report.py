"""Numbers, tables and figures of the paper's Figures 7–10 from the measurements of
:mod:`nudge_train.experiments.paper_runs` (``nudge-train paper``).

Every time comes from the simulator's step columns or the inference timer, in milliseconds:

* Z-update (Fig. 8): per planning step, ``z_s / z_updates`` (the mean time of one Z-update in
  that step; the columns hold the sum and the count, not every update), over the steps with at
  least one Z-update; the overall mean is ``Σ z_s / Σ z_updates`` (exact);
* planning step (Fig. 9): ``mpc_s``, one MPC call;
* cost (Fig. 10): ``cost``, the optimal cost of each step (finite values);
* outcomes: ``success``, ``collision`` / ``collisions_at_fault``, ``steps_to_target`` (× 0.3 s).

Box plots show the quartiles, the median as a red line (as the paper's) and whiskers at the 5th
and 95th percentiles, no outliers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from nudge_train.constants import DT
from nudge_train.experiments.paper_runs import INFER_ARMS

PAPER = {
    "infer_teacher_ms": (15.4, 18.9),
    "infer_student_ms": (2.3, 2.7),
    "z_ratio": 6.0,
    "hz_teacher": (0.5, 0.7),
    "hz_student": (2.0, 4.0),
    "step_ratio": 5.0,
    "hardware": "single-threaded Intel Xeon E5-2640 v4 @ 2.40 GHz",
    "z_updates": 11000,
    "steps": 1500,
}
"""The paper's reported values (Sec. Results) and its set-up."""
COLOURS = {"teacher": "tab:blue", "student": "tab:orange", "constant_velocity": "tab:gray"}


def arm_stats(payload: dict[str, Any]) -> dict[str, Any]:
    """The numbers of one (N, predictor) arm: runs, errors, success, collision runs, at-fault
    collision events, time to target (s, runs that reached it), steps, Z-updates; ``z_ms`` (per
    step mean Z-update time), ``step_ms`` (``mpc_s``), ``cost`` as arrays; their summaries."""
    runs, steps = payload["runs"], payload["steps"]
    ok = np.array([e is None for e in runs["error"]], dtype=bool)
    success = np.asarray(runs["success"], dtype=bool)[ok]
    stt = np.asarray(runs["steps_to_target"], dtype=np.int64)[ok]
    reached = stt[stt >= 0] * DT
    zu = np.asarray(steps["z_updates"], dtype=np.float64)
    zs = np.asarray(steps["z_s"], dtype=np.float64)
    z_ms = zs[zu > 0] / zu[zu > 0] * 1e3
    step_ms = np.asarray(steps["mpc_s"], dtype=np.float64) * 1e3
    cost = np.asarray(steps["cost"], dtype=np.float64)
    cost = cost[np.isfinite(cost)]
    per_run = np.asarray(runs["n_steps"], dtype=np.int64)[ok] if "n_steps" in runs else np.zeros(0, np.int64)
    return {
        "runs": int(ok.sum()), "errors": int((~ok).sum()),
        "success": float(success.mean()) if success.size else math.nan,
        "collision_runs": int(np.asarray(runs["collision"], dtype=bool)[ok].sum()),
        "at_fault": int(np.asarray(runs["collisions_at_fault"], dtype=np.int64)[ok].sum()),
        "not_at_fault": int(np.asarray(runs["collisions_not_at_fault"], dtype=np.int64)[ok].sum()),
        "reached": int(reached.size), "ttt_mean": float(reached.mean()) if reached.size else math.nan,
        "ttt_median": float(np.median(reached)) if reached.size else math.nan,
        "steps": int(step_ms.size), "z_updates": int(zu.sum()),
        "steps_per_run": [int(per_run.min()), float(per_run.mean()), int(per_run.max())] if per_run.size else None,
        "z_ms": z_ms, "step_ms": step_ms, "cost": cost,
        "z_mean_ms": float(zs.sum() / zu.sum() * 1e3) if zu.sum() > 0 else math.nan,
        "z_q": _quartiles(z_ms), "step_q": _quartiles(step_ms),
        "step_mean_ms": float(step_ms.mean()) if step_ms.size else math.nan,
        "cost_mean": float(cost.mean()) if cost.size else math.nan,
        "cost_std": float(cost.std()) if cost.size else math.nan,
        "wall_s": float(payload.get("wall_s", math.nan)), "cpu_s": float(payload.get("cpu_s", math.nan)),
        "load": payload.get("load"),
    }


def _quartiles(v: np.ndarray) -> tuple[float, float, float]:
    if v.size == 0:
        return (math.nan,) * 3
    q1, q2, q3 = np.percentile(v, [25, 50, 75])
    return float(q1), float(q2), float(q3)


def ratio(a: float, b: float) -> float:
    """a / b, NaN when either is not a positive finite number."""
    return a / b if math.isfinite(a) and math.isfinite(b) and b > 0 else math.nan


def _f(v: float, digits: int = 2) -> str:
    if not math.isfinite(v):
        return "–"
    if abs(v) >= 100:
        return f"{v:.0f}"
    if abs(v) >= 10:
        return f"{v:.1f}"
    return f"{v:.{digits}f}" if abs(v) >= 0.1 else f"{v:.{digits + 1}f}"


def _qtext(q: tuple[float, float, float]) -> str:
    return f"{_f(q[1])} [{_f(q[0])}, {_f(q[2])}]"


# ---- tables -------------------------------------------------------------------------------------
def inference_rows(infer: dict[int, dict[str, Any]]) -> list[dict[str, float]]:
    """Per N: the mean over timed scenes of each arm's per-scene median (ms) and the ratios."""
    rows = []
    for n, d in infer.items():
        m = {a: float(np.mean(d[a])) if d[a] else math.nan for a in INFER_ARMS}
        rows.append({"n": n, "scenes": len(d["scenes"]), **m,
                     "ratio_rust": ratio(m["teacher_rust"], m["student_rust"]),
                     "ratio_torch": ratio(m["teacher_torch"], m["student_torch"])})
    return rows


def inference_table(infer: dict[int, dict[str, Any]]) -> str:
    """Markdown of Fig. 7."""
    pt, ps = PAPER["infer_teacher_ms"], PAPER["infer_student_ms"]
    lines = ["| N | scenes timed | teacher Rust (ms) | student Rust (ms) | teacher / student Rust "
             "| teacher PyTorch (ms) | student PyTorch (ms) | teacher / student PyTorch | paper teacher (ms) "
             "| paper student (ms) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in inference_rows(infer):
        lines.append(f"| {r['n']} | {r['scenes']} | {_f(r['teacher_rust'], 3)} | {_f(r['student_rust'], 3)} "
                     f"| {_f(r['ratio_rust'], 1)}× | {_f(r['teacher_torch'])} | {_f(r['student_torch'])} "
                     f"| {_f(r['ratio_torch'], 1)}× | {pt[0]}–{pt[1]} | {ps[0]}–{ps[1]} |")
    return "\n".join(lines)


def z_table(stats: dict[int, dict[str, dict]], pools: dict[int, int]) -> str:
    """Markdown of Fig. 8: per-step mean Z-update time, median [Q1, Q3] (ms), the overall mean,
    and the teacher / student ratios."""
    preds = _preds(stats)
    head = "| N | real scenes with ≥ N vehicles | runs |"
    for p in preds:
        head += f" {p} median [Q1, Q3] (ms) | {p} mean (ms) | {p} Z-updates |"
    head += " teacher / student (medians) | teacher / student (means) | paper |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for n, arms in stats.items():
        runs = max(a["runs"] for a in arms.values())
        line = f"| {n} | {pools[n]} | {runs} |"
        for p in preds:
            a = arms.get(p)
            line += " – | – | – |" if a is None else f" {_qtext(a['z_q'])} | {_f(a['z_mean_ms'], 3)} | {a['z_updates']} |"
        t, s = arms.get("teacher"), arms.get("student")
        rm = ratio(t["z_q"][1], s["z_q"][1]) if t and s else math.nan
        rmean = ratio(t["z_mean_ms"], s["z_mean_ms"]) if t and s else math.nan
        line += f" {_f(rm, 1)}× | {_f(rmean, 1)}× | ≈ {PAPER['z_ratio']:g}× |"
        lines.append(line)
    return "\n".join(lines)


def step_table(stats: dict[int, dict[str, dict]]) -> str:
    """Markdown of Fig. 9: planning-step time median [Q1, Q3] (ms), rate (Hz = 1 / median) and
    the teacher / student ratio of the medians."""
    preds = _preds(stats)
    head = "| N |"
    for p in preds:
        head += f" {p} median [Q1, Q3] (ms) | {p} (Hz) | {p} steps |"
    head += " teacher / student (medians) | teacher / student (means) | paper teacher (Hz) | paper student (Hz) |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for n, arms in stats.items():
        line = f"| {n} |"
        for p in preds:
            a = arms.get(p)
            line += " – | – | – |" if a is None else \
                f" {_qtext(a['step_q'])} | {_f(ratio(1e3, a['step_q'][1]), 1)} | {a['steps']} |"
        t, s = arms.get("teacher"), arms.get("student")
        rm = ratio(t["step_q"][1], s["step_q"][1]) if t and s else math.nan
        rmean = ratio(t["step_mean_ms"], s["step_mean_ms"]) if t and s else math.nan
        ht, hs = PAPER["hz_teacher"], PAPER["hz_student"]
        line += f" {_f(rm, 1)}× | {_f(rmean, 1)}× | {ht[0]}–{ht[1]} | {hs[0]}–{hs[1]} |"
        lines.append(line)
    return "\n".join(lines)


def cost_table(stats: dict[int, dict[str, dict]]) -> str:
    """Markdown of Fig. 10: the optimal cost per planning step, mean ± std."""
    preds = _preds(stats)
    head = "| N |" + "".join(f" {p} cost mean ± std |" for p in preds) + " student − teacher (means) |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for n, arms in stats.items():
        line = f"| {n} |"
        for p in preds:
            a = arms.get(p)
            line += " – |" if a is None else f" {_f(a['cost_mean'])} ± {_f(a['cost_std'])} |"
        t, s = arms.get("teacher"), arms.get("student")
        line += f" {_f(s['cost_mean'] - t['cost_mean'])} |" if t and s else " – |"
        lines.append(line)
    return "\n".join(lines)


def outcome_table(stats: dict[int, dict[str, dict]]) -> str:
    """Markdown: success, collisions and time to target per N and predictor."""
    lines = ["| N | predictor | runs | errors | success | runs with a collision | collisions at fault "
             "| collisions not at fault | reached the target | time to target mean (s) | median (s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for n, arms in stats.items():
        for p in _preds(stats):
            a = arms.get(p)
            if a is None:
                continue
            lines.append(f"| {n} | {p} | {a['runs']} | {a['errors']} | {100 * a['success']:.0f} % "
                         f"| {a['collision_runs']} | {a['at_fault']} | {a['not_at_fault']} | {a['reached']} "
                         f"| {_f(a['ttt_mean'])} | {_f(a['ttt_median'])} |")
    return "\n".join(lines)


def _preds(stats: dict[int, dict[str, dict]]) -> list[str]:
    order = ("teacher", "student", "constant_velocity")
    seen = {p for arms in stats.values() for p in arms}
    return [p for p in order if p in seen] + sorted(seen - set(order))


# ---- figures ------------------------------------------------------------------------------------
def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _pool_labels(ns: Sequence[int], pools: dict[int, int], runs: dict[int, int]) -> list[str]:
    return [f"{n}\n({pools[n]} scenes,\n{runs[n]} runs)" for n in ns]


def plot_inference(infer: dict[int, dict[str, Any]], png: Path) -> None:
    """Fig. 7: mean inference time of one prediction vs N, four series, the paper's ranges."""
    plt = _pyplot()
    rows = inference_rows(infer)
    ns = [r["n"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    style = {"teacher_rust": ("tab:blue", "-", "o"), "student_rust": ("tab:orange", "-", "o"),
             "teacher_torch": ("tab:blue", "--", "s"), "student_torch": ("tab:orange", "--", "s")}
    names = {"teacher_rust": "teacher, Rust", "student_rust": "student, Rust", "teacher_torch": "teacher, PyTorch",
             "student_torch": "student, PyTorch"}
    for arm in INFER_ARMS:
        c, ls, mk = style[arm]
        ax.plot(ns, [r[arm] for r in rows], color=c, ls=ls, marker=mk, label=names[arm])
    for (lo, hi), c, lab in ((PAPER["infer_teacher_ms"], "tab:blue", "paper teacher"),
                             (PAPER["infer_student_ms"], "tab:orange", "paper student")):
        ax.axhspan(lo, hi, color=c, alpha=0.15, label=f"{lab} ({lo}–{hi} ms)")
    ax.set_yscale("log")
    ax.set_xlabel("vehicles N (ego included)")
    ax.set_ylabel("one prediction, t_plan = 6 (ms)")
    ax.set_title("Fig. 7: predictor inference time, one thread")
    ax.set_xticks(ns)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)


def plot_boxes(stats: dict[int, dict[str, dict]], pools: dict[int, int], field: str, ylabel: str, title: str,
               png: Path, bands: dict[str, tuple[float, float]] | None = None) -> None:
    """Figs. 8 and 9: box plots per N and predictor of ``field`` (``z_ms`` or ``step_ms``);
    quartile boxes, red median lines, whiskers at the 5th / 95th percentiles, no outliers;
    ``bands``: the paper's ranges (ms) per predictor, shaded."""
    plt = _pyplot()
    preds = _preds(stats)
    ns = list(stats)
    width = 0.8 / len(preds)
    fig, ax = plt.subplots(figsize=(max(6.4, 1.1 * len(ns) * len(preds) / 2 + 3), 4.4))
    for j, p in enumerate(preds):
        data = [stats[n][p][field] if p in stats[n] and stats[n][p][field].size else np.array([np.nan]) for n in ns]
        pos = np.arange(len(ns)) + (j - (len(preds) - 1) / 2) * width
        ax.boxplot(data, positions=pos, widths=width * 0.9, whis=(5, 95), showfliers=False, patch_artist=True,
                   boxprops={"facecolor": COLOURS.get(p, "white"), "alpha": 0.6},
                   medianprops={"color": "red", "linewidth": 1.5})
        ax.plot([], [], color=COLOURS.get(p, "k"), lw=8, alpha=0.6, label=p)
    for p, (lo, hi) in (bands or {}).items():
        ax.axhspan(lo, hi, color=COLOURS.get(p, "k"), alpha=0.12, label=f"paper {p} ({lo:.0f}–{hi:.0f} ms)")
    runs = {n: max(a["runs"] for a in stats[n].values()) for n in ns}
    ax.set_xticks(np.arange(len(ns)), _pool_labels(ns, pools, runs), fontsize=7)
    ax.set_yscale("log")
    ax.set_xlabel("vehicles N (real scenes with ≥ N vehicles; closed-loop runs per predictor)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)


def plot_cost(stats: dict[int, dict[str, dict]], png: Path) -> None:
    """Fig. 10: optimal cost per step, mean ± std per N and predictor."""
    plt = _pyplot()
    preds = _preds(stats)
    ns = list(stats)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for j, p in enumerate(preds):
        x = np.asarray(ns, dtype=float) + (j - (len(preds) - 1) / 2) * 0.25
        m = [stats[n][p]["cost_mean"] if p in stats[n] else np.nan for n in ns]
        s = [stats[n][p]["cost_std"] if p in stats[n] else np.nan for n in ns]
        ax.errorbar(x, m, yerr=s, fmt="o", capsize=3, color=COLOURS.get(p, "k"), label=p)
    ax.set_xticks(ns)
    ax.set_xlabel("vehicles N (ego included)")
    ax.set_ylabel("optimal cost per planning step")
    ax.set_title("Fig. 10: optimal cost, mean ± std")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)


def plot_outcomes(stats: dict[int, dict[str, dict]], png: Path) -> None:
    """Success rate, runs with a collision and mean time to target per N and predictor."""
    plt = _pyplot()
    preds = _preds(stats)
    ns = list(stats)
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.6))
    panels = (("success", 100.0, "success (%)"), ("collision_runs", 1.0, "runs with a collision"),
              ("ttt_mean", 1.0, "time to target, mean (s)"))
    for ax, (key, scale, label) in zip(axes, panels, strict=True):
        for p in preds:
            ax.plot(ns, [stats[n][p][key] * scale if p in stats[n] else np.nan for n in ns], marker="o",
                    color=COLOURS.get(p, "k"), label=p)
        ax.set_xticks(ns)
        ax.set_xlabel("vehicles N")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Closed-loop outcomes by vehicle count (teacher world)")
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)
