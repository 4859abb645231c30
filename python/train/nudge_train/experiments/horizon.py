"""``nudge-train horizon``: the teacher over a 3 s horizon, written to ``docs/results/horizon.md``.

The teacher predicts one 0.3 s step per call; a longer planning horizon is the same network rolled
out longer (``Teacher::set_horizon``, ``teacher_interactive(..., horizon=)``). This measures what
that roll-out is worth on real data, beside the 1.8 s the planner used so far:

1. **Accuracy**: ADE / FDE at 1.8 s (6 steps) and 3.0 s (10 steps) on the test windows whose
   future holds >= 10 steps (a build with ``nudge-train data build --n-fut 10 --out DIR``: the same
   tracks, filters and split assignment, windows 8 + 10 steps long), recursive mode as
   docs/results/teacher.md (the ego set to its logged future after every step, the other agents
   scored; fixed z and best of 20), against constant velocity on the same agents.
2. **Reaction on real cut-ins** (``assets/worlds/cutins.json``): the real follower's fall-back and
   the teacher's predicted fall-back and reaction at 1.8 s and at 3.0 s after the prediction start
   (definitions: :mod:`nudge_train.experiments.reaction_cutins`), the cut-in vehicle's logged path
   over 3 s as the candidate; events whose intruder is not observed for those 3 s are left out.
3. **Cost**: the section of ``nudge-train bench latency --horizons 6 10`` in ``--latency``
   (``docs/results/latency.md``), when given.

Everything also goes to ``--json``. The report keeps whatever is written below its
``<!-- notes -->`` marker.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

import numpy as np
import torch

from nudge_train import paths
from nudge_train.constants import DT
from nudge_train.data.loader import load_split
from nudge_train.idm.cutins import TAUS, Tracks, control_fall_backs, read_config, read_events
from nudge_train.idm.pipeline import median_ci
from nudge_train.idm.sources import load_sources
from nudge_train.provenance import git_commit, sha256_file
from nudge_train.training.evaluate import Metrics, evaluate_constant_velocity_at, evaluate_generator_at
from nudge_train.training.export import load_generator
from nudge_train.training.reaction_measure import model_predictor

from .reaction_cutins import cutin_case, cutin_reactions

__all__ = ["HORIZONS", "run"]

HORIZONS = (6, 10)
"""Steps scored: 1.8 s (the planner's default horizon) and 3.0 s."""
CUTIN_LEADS = (0.9, 0.0)
"""Prediction start before the centre crossing (s) of the real cut-ins (as docs/results/reaction.md)."""
MARKER = "<!-- notes -->"


def _s(h: int) -> str:
    return f"{h * DT:.1f} s"


def accuracy_section(data: Path, teacher: Path, samples: int, best_of_n: int, seed: int, res: dict) -> list[str]:
    """ADE / FDE at every horizon of :data:`HORIZONS`, teacher and constant velocity: fixed z on every
    (and every interactive) test window, best of ``samples`` on a seeded draw of ``best_of_n`` of them
    (each draw costs a full roll-out)."""
    test = load_split(data, "test")
    if test.pred_len < max(HORIZONS):
        raise ValueError(f"{data}: windows hold {test.pred_len} future steps, {max(HORIZONS)} needed "
                         f"(build them with `nudge-train data build --n-fut {max(HORIZONS)} --out DIR`)")
    gen = load_generator(teacher)
    inter = np.flatnonzero(test.interactive.astype(bool))
    head = " | ".join(f"ADE@{_s(h)} | FDE@{_s(h)}" for h in HORIZONS)
    lines = ["## 1. Accuracy over 1.8 s and 3.0 s (test windows with a 3 s future)", "",
             f"Windows: {len(test)} test windows of `{paths.repo_relative(data)}` ({len(inter)} interactive), "
             f"8 observed + {test.pred_len} future steps. Recursive mode as docs/results/teacher.md: one teacher "
             "call per step with the ego set to its logged future, the other agents scored (constant velocity on "
             "the same agents). *fixed z*: the weights' noise, the planner's single sample; *best of "
             f"{samples}*: per scene the z draw (held over the roll-out) with the lowest summed ADE up to that "
             f"horizon, on a seeded draw of {best_of_n} test windows (seed {seed}; with fixed z and constant "
             "velocity on the same windows). Metres.", ""]
    res["accuracy"] = {"windows": len(test), "interactive": int(len(inter)), "pred_len": test.pred_len}
    drawn = np.sort(np.random.default_rng(seed).permutation(len(test))[:best_of_n])
    subsets = (("all test windows", None, False), ("interactive test windows", inter, False),
               (f"{len(drawn)} test windows drawn (best of {samples})", drawn, True))
    for title, subset, best in subsets:
        t0 = time.perf_counter()
        rows: list[tuple[str, dict[int, Metrics]]] = [
            ("constant velocity", evaluate_constant_velocity_at(test, HORIZONS, skip_ego=True, subset=subset)),
            ("teacher, fixed z", evaluate_generator_at(gen, test, HORIZONS, samples=1, subset=subset)),
        ]
        if best:
            rows.append((f"teacher, best of {samples}", evaluate_generator_at(gen, test, HORIZONS, samples=samples,
                                                                              subset=subset)))
        lines += [f"### {title}", "", f"| model | {head} | scenes | agents |",
                  "|---|" + "---|" * (2 * len(HORIZONS)) + "---|---|"]
        for label, m in rows:
            cells = " | ".join(f"{m[h].ade6:.3f} | {m[h].fde6:.3f}" for h in HORIZONS)
            lines.append(f"| {label} | {cells} | {m[HORIZONS[0]].scenes} | {m[HORIZONS[0]].agents} |")
            res["accuracy"].setdefault(title, {})[label] = {h: vars(m[h]) for h in HORIZONS}
        cv, fz = rows[0][1], rows[1][1]
        lines += ["", "Teacher (fixed z) against constant velocity: "
                  + "; ".join(f"FDE@{_s(h)} {fz[h].fde6 / cv[h].fde6:.2f}×, ADE@{_s(h)} "
                              f"{fz[h].ade6 / cv[h].ade6:.2f}×" for h in HORIZONS)
                  + f" (computed in {time.perf_counter() - t0:.0f} s).", ""]
    return lines


def _ci(v: tuple[float, float, float, int]) -> str:
    med, lo, hi, n = v
    return "–" if n == 0 else f"{med:+.3f} [{lo:+.3f}, {hi:+.3f}] ({n})"


def cutin_section(cutins: Path, data_root: Path, teacher: Path, n_boot: int, seed: int, res: dict) -> list[str]:
    """The real follower's and the teacher's fall-back and reaction at 1.8 s and 3.0 s on the real cut-ins."""
    rng = np.random.default_rng(seed)
    events = read_events(cutins)
    src = load_sources(data_root)
    tracks = {s.name: Tracks(s.table) for s in src.us101 if any(e.scene == s.name for e in events)}
    tracks["i80-coifman"] = Tracks(src.coifman)
    cfg = read_config(cutins)
    control: dict[str, list[np.ndarray]] = {"us101": [], "i80": []}
    for name, tr in tracks.items():
        control["i80" if name == "i80-coifman" else "us101"].append(
            control_fall_backs(tr, events, cfg, name != "i80-coifman"))
    k = {h: int(np.flatnonzero(np.isclose(TAUS, h * DT))[0]) for h in HORIZONS}
    ctrl = {h: {s: float(np.nanmedian(np.concatenate(v)[:, k[h]])) for s, v in control.items()} for h in HORIZONS}
    steps = max(HORIZONS)
    lines = ["## 2. The teacher's reaction on real cut-ins, 1.8 s and 3.0 s after the prediction start", "",
             "As section 2 of docs/results/reaction.md, over 3 s: the cut-in vehicle plays the ego, its logged path "
             f"over the next {steps} steps is the candidate (keep-lane counterfactual: the same with its lateral "
             "position held); the real follower's fall-back = its x minus its constant-speed path from the "
             "prediction start (negative = behind), *net* = minus the median of followers without a cut-in in the "
             "same source ("
             + "; ".join(f"at {_s(h)}: US-101 {ctrl[h]['us101']:+.3f} m, I-80 {ctrl[h]['i80']:+.3f} m"
                         for h in HORIZONS)
             + "); the teacher's fall-back is its predicted follower x minus the same reference, its reaction the "
             "prediction under the real path minus under the keep-lane path. Events whose intruder or follower is "
             f"not observed over the 8 history steps, or the intruder over the {_s(steps)}, are left out (so fewer "
             "than in reaction.md); the real follower's track must reach the time read. Medians [95 % CI] "
             "(n events), all sources.", ""]
    res["cutins"] = {"control_median": {str(h): ctrl[h] for h in HORIZONS}, "leads": {}}
    gen = load_generator(teacher)
    for lead in CUTIN_LEADS:
        cases = [c for c in (cutin_case(tracks[e.scene], e, lead, steps=steps) for e in events) if c is not None]
        when = "at the centre crossing" if lead == 0 else f"{lead:g} s before the centre crossing"
        lines += [f"### Prediction starting {when} ({len(cases)} events)", "",
                  "| who | " + " | ".join(f"fall-back at {_s(h)} (m)" for h in HORIZONS) + " | "
                  + " | ".join(f"reaction at {_s(h)} (m)" for h in HORIZONS) + " |",
                  "|---|" + "---|" * (2 * len(HORIZONS))]
        real = {h: np.array([c.real_fbs[h - 1] for c in cases]) for h in HORIZONS}
        net = {h: real[h] - np.array([ctrl[h][c.source] for c in cases]) for h in HORIZONS}
        model = {h: cutin_reactions(cases, {"teacher": model_predictor(gen)}, step=h - 1)["teacher"] for h in HORIZONS}
        row_real = {h: median_ci(real[h], rng, n_boot) for h in HORIZONS}
        row_net = {h: median_ci(net[h], rng, n_boot) for h in HORIZONS}
        row_fb = {h: median_ci(model[h]["fall_back"], rng, n_boot) for h in HORIZONS}
        row_re = {h: median_ci(model[h]["reaction"], rng, n_boot) for h in HORIZONS}
        lines.append("| real follower | " + " | ".join(_ci(row_real[h]) for h in HORIZONS) + " | "
                     + " | ".join(f"{_ci(row_net[h])} (net)" for h in HORIZONS) + " |")
        lines.append("| teacher | " + " | ".join(_ci(row_fb[h]) for h in HORIZONS) + " | "
                     + " | ".join(_ci(row_re[h]) for h in HORIZONS) + " |")
        lines.append("")
        res["cutins"]["leads"][str(lead)] = {
            "events": len(cases), "real_fb": {str(h): row_real[h] for h in HORIZONS},
            "real_net": {str(h): row_net[h] for h in HORIZONS},
            "teacher_fall_back": {str(h): row_fb[h] for h in HORIZONS},
            "teacher_reaction": {str(h): row_re[h] for h in HORIZONS},
            "per_event": {"keys": [c.key for c in cases], **{f"real_fb_{h}": real[h].tolist() for h in HORIZONS},
                          **{f"teacher_{q}_{h}": model[h][q].tolist() for h in HORIZONS for q in model[h]}}}
    return lines


def latency_section(latency: Path, res: dict) -> list[str]:
    """The section of a ``nudge-train bench latency --horizons ...`` report (``docs/results/latency.md``)
    whose arms ran at several horizons, included as it stands (its command, machine and load noted)."""
    text = latency.read_text()
    found = re.search(r"<!-- bench latency: (budget off, horizons [0-9 ]+) -->\n(.*?)<!-- /bench latency: \1 -->",
                      text, re.DOTALL)
    if found is None:
        raise SystemExit(f"error: {latency}: no section of `nudge-train bench latency --horizons ...`")
    body = [ln for ln in found.group(2).strip().split("\n") if not ln.startswith("### ")]
    res["latency"] = {"file": paths.repo_relative(latency), "section": found.group(1)}
    return (["## 3. The cost: planning-step latency at 6 and 10 steps", "",
             f"The section `{found.group(1)}` of `{paths.repo_relative(latency)}`; every arm on one thread, "
             "interleaved chunk by chunk on the same runs, so the arms share the machine's load alike.", ""]
            + body + [""])


def run(a: argparse.Namespace) -> int:
    """Runs the measurements, writes the report and the JSON; returns the exit status."""
    torch.set_num_threads(a.threads)
    res: dict = {"teacher": {"path": paths.repo_relative(a.teacher), "sha256": sha256_file(a.teacher)},
                 "data_manifest_sha256": sha256_file(Path(a.data) / "manifest.json"), "commit": git_commit()}
    lines = ["# Horizon: the teacher over 3 s", "",
             "Generated by `nudge-train horizon` (python/train/nudge_train/experiments/horizon.py); metres, one step "
             f"= 0.3 s. Teacher: `{paths.repo_relative(a.teacher)}` (trained on one-step targets, rolled out "
             "recursively; not retrained for the longer horizon). Windows: `nudge-train data build --n-fut 10 --out "
             f"{paths.repo_relative(Path(a.data))}`.", ""]
    try:
        lines += accuracy_section(Path(a.data), a.teacher, a.samples, a.best_of_n, a.seed, res)
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from None
    lines += cutin_section(a.cutins, a.data_root, a.teacher, a.bootstrap, a.seed, res)
    if a.latency is not None:
        lines += latency_section(a.latency, res)
    a.report.parent.mkdir(parents=True, exist_ok=True)
    existing = a.report.read_text() if a.report.exists() else ""
    notes = existing.split(MARKER, 1)[1] if MARKER in existing else "\n"
    a.report.write_text("\n".join(lines) + "\n" + MARKER + notes)
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(res, indent=1, default=float) + "\n")
    print("\n".join(lines))
    print(f"wrote {a.report} and {a.json}")
    return 0
