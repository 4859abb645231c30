"""``nudge-train reaction``: the reaction table of docs/results/reaction.md.

Measures (definitions in :mod:`nudge_train.training.reaction_measure` and
:mod:`nudge_train.experiments.reaction_cutins`) for the teacher, the shipped student and any
``--candidate`` student:

1. held-out planner candidates (the distillation set's test split): the target-lane follower's
   reaction at 1.8 s per planner call, the students' error against the teacher's, and the
   students' position fidelity (ADE / FDE against the teacher);
2. real cut-ins: the models' predicted fall-back and reaction of the real follower against its
   real fall-back, with the prediction starting 0.9 s before the centre crossing (the candidate
   crosses the line within the horizon, as a planner lane change does) and at the crossing.

Every number also goes to a JSON file (``--json``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from nudge_train import paths
from nudge_train.distill.contexts import load_contexts
from nudge_train.idm.cutins import TAUS, Tracks, control_fall_backs, read_events
from nudge_train.idm.pipeline import median_ci
from nudge_train.idm.sources import load_sources
from nudge_train.provenance import git_commit, sha256_file
from nudge_train.training.export import load_generator
from nudge_train.training.reaction import fidelity
from nudge_train.training.reaction_measure import model_predictor, per_context, planner_reactions

from .reaction_cutins import HORIZON_S, cutin_case, cutin_reactions

__all__ = ["CUTIN_LEADS", "MIN_LATERAL", "TARGET_SHARE", "meets_target", "planner_table", "run"]

MIN_LATERAL = 1.0
"""Lateral reach (m) at step 6 that makes a planner candidate a lane-change candidate."""
TARGET_SHARE = 0.3
"""A student reacts like the teacher when its median reaction is within this share of the
teacher's (issue target: within 30 %)."""
CUTIN_LEADS = (0.9, 0.0)
"""Prediction start before the centre crossing (s) of the real cut-ins."""


def meets_target(student_median: float, teacher_median: float, share: float = TARGET_SHARE) -> bool:
    """True when ``|student − teacher| <= share · |teacher|`` (medians, m) and the teacher reacts."""
    return teacher_median != 0.0 and abs(student_median - teacher_median) <= share * abs(teacher_median)


def _ci(v: tuple[float, float, float, int]) -> str:
    med, lo, hi, n = v
    if n == 0:
        return "–"
    return f"{med:+.3f} [{lo:+.3f}, {hi:+.3f}] ({n})"


def planner_table(ctxs: list, models: dict, rng: np.random.Generator, n_boot: int) -> tuple[list[str], dict]:
    """The reaction table of ``models`` (name -> generator, ``"teacher"`` among them) on the planner
    calls ``ctxs``: markdown lines (intro + table) and the numbers."""
    reacts = planner_reactions(ctxs, {k: model_predictor(g) for k, g in models.items()}, min_lateral=MIN_LATERAL)
    teacher = per_context(reacts, "teacher")
    pairs = sum(len(r.candidates) for r in reacts)
    lines = [
        f"{len(ctxs)} planner calls, of which {len(reacts)} have the ego outside the target lane, a target-lane "
        f"follower and lane-change candidates (reach >= {MIN_LATERAL:g} m towards the target lane at 1.8 s; at most "
        f"8 per call, {pairs} in all). Reaction = the follower's predicted x at 1.8 s under the candidate minus "
        "under its keep-lane counterfactual (same x, y held at the ego's), mean over the call's candidates; medians "
        "over calls with 95 % bootstrap intervals (n = calls). Fidelity: ADE over 6 steps / FDE at 1.8 s against the "
        "teacher, up to 16 candidates per call, all calls.",
        "",
        "| model | reaction (m) | share of calls with a reaction < -1 cm | abs. error vs teacher (m) | ratio of medians | "
        "within 30 % | ADE vs teacher (m) | FDE vs teacher (m) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    res: dict = {"calls": len(ctxs), "reaction_calls": len(reacts), "pairs": pairs, "models": {}}
    t_med = float(np.median(teacher))
    for name, gen in models.items():
        v = per_context(reacts, name)
        react = median_ci(v, rng, n_boot)
        share = float(np.mean(v < -0.01))
        row: dict = {"reaction": react, "share_below_1cm": share}
        if name == "teacher":
            err_s, ratio, ok, ade, fde = "–", "1", "–", "–", "–"
        else:
            err = median_ci(np.abs(v - teacher), rng, n_boot)
            a6, f6 = fidelity(gen, ctxs)
            row.update(error=err, ratio=react[0] / t_med, meets_target=meets_target(react[0], t_med), ade=a6, fde=f6)
            err_s, ratio = _ci(err), f"{react[0] / t_med:.2f}"
            ok, ade, fde = ("yes" if row["meets_target"] else "no"), f"{a6:.4f}", f"{f6:.4f}"
        res["models"][name] = row
        lines.append(f"| {name} | {_ci(react)} | {share:.0%} | {err_s} | {ratio} | {ok} | {ade} | {fde} |")
    ref = res["models"].get("student")
    if ref is not None:
        lines.append("")
        for name, row in res["models"].items():
            if name in ("teacher", "student"):
                continue
            fid = row["ade"] <= ref["ade"] and row["fde"] <= ref["fde"]
            row["fidelity_not_worse"] = fid
            row["target_met"] = bool(row["meets_target"] and fid)
            lines.append(f"Target for `{name}` (reaction within {TARGET_SHARE:.0%} of the teacher's, ADE and FDE not worse "
                         f"than the shipped student's): **{'met' if row['target_met'] else 'not met'}** (reaction "
                         f"{'within' if row['meets_target'] else 'not within'} 30 %, fidelity "
                         f"{'not worse' if fid else 'worse'}).")
    return lines, res


def _planner_section(a: argparse.Namespace, models: dict, rng: np.random.Generator, res: dict) -> list[str]:
    ctxs = load_contexts(a.distill, a.split, a.scenes_root)
    t0 = time.perf_counter()
    table, res["planner"] = planner_table(ctxs, models, rng, a.bootstrap)
    return ([f"## 1. Held-out planner candidates ({a.split} split of the distillation set)", ""] + table
            + ["", f"(computed in {time.perf_counter() - t0:.0f} s)", ""])


def _cutin_section(a: argparse.Namespace, models: dict, rng: np.random.Generator, res: dict) -> list[str]:
    events = read_events(a.cutins)
    src = load_sources(a.data_root)
    tracks = {s.name: Tracks(s.table) for s in src.us101 if any(e.scene == s.name for e in events)}
    tracks["i80-coifman"] = Tracks(src.coifman)
    k = int(np.flatnonzero(np.isclose(TAUS, HORIZON_S))[0])
    control: dict[str, list[np.ndarray]] = {"us101": [], "i80": []}
    for name, tr in tracks.items():
        c = control_fall_backs(tr, events, _cutin_cfg(a.cutins), name != "i80-coifman")
        control["i80" if name == "i80-coifman" else "us101"].append(c[:, k])
    ctrl = {s: float(np.nanmedian(np.concatenate(v))) for s, v in control.items()}
    lines = [
        "## 2. Real cut-ins (`assets/worlds/cutins.json`)",
        "",
        "The cut-in vehicle plays the ego; candidate = its logged path over the next 1.8 s, keep-lane "
        "counterfactual = the same with its lateral position held; the real follower's fall-back = its x at "
        "1.8 s minus its constant-speed path from the prediction start (negative = behind); *net* = minus the "
        f"median fall-back of followers without a cut-in in the same source (US-101 {ctrl['us101']:+.3f} m, "
        f"I-80 {ctrl['i80']:+.3f} m). A model's fall-back is its predicted follower x at 1.8 s minus the same "
        "reference; its reaction is real path minus keep-lane. For the real follower the reaction column holds the "
        "net fall-back, the truth the models' reaction estimates. Events whose intruder or follower is not observed "
        "over the 8 history steps (or the intruder over the 1.8 s) are left out. Medians [95 % CI] (n events).",
        "",
    ]
    res["cutins"] = {"control_median_fb_1p8": ctrl, "leads": {}}
    for lead in CUTIN_LEADS:
        cases = [c for c in (cutin_case(tracks[e.scene], e, lead) for e in events) if c is not None]
        r = cutin_reactions(cases, {k_: model_predictor(g) for k_, g in models.items()})
        real = np.array([c.real_fb for c in cases])
        net = real - np.array([ctrl[c.source] for c in cases])
        when = "at the centre crossing" if lead == 0 else f"{lead:g} s before the centre crossing"
        lines += [f"### Prediction starting {when}", "",
                  "| source | who | fall-back at 1.8 s (m) | reaction at 1.8 s (m) |", "|---|---|---|---|"]
        out: dict[str, dict] = {}
        for source in ("us101", "i80", "all"):
            sel = np.array([source == "all" or c.source == source for c in cases], dtype=bool)
            row = {"real_fb": median_ci(real[sel], rng, a.bootstrap), "real_net": median_ci(net[sel], rng, a.bootstrap)}
            lines.append(f"| {source} | real follower | {_ci(row['real_fb'])} | {_ci(row['real_net'])} (net) |")
            for m in models:
                row[f"{m}_fall_back"] = median_ci(r[m]["fall_back"][sel], rng, a.bootstrap)
                row[f"{m}_reaction"] = median_ci(r[m]["reaction"][sel], rng, a.bootstrap)
                lines.append(f"| {source} | {m} | {_ci(row[f'{m}_fall_back'])} | {_ci(row[f'{m}_reaction'])} |")
            out[source] = row
        res["cutins"]["leads"][str(lead)] = {"events": len(cases), "by_source": out,
                                              "per_event": {"keys": [c.key for c in cases], "real_fb": real.tolist(),
                                                            **{m: {q: v.tolist() for q, v in r[m].items()} for m in models}}}
        lines.append("")
    return lines


def _cutin_cfg(path: Path):
    from nudge_train.idm.cutins import CutInConfig
    from nudge_train.jsonio import load_json

    return CutInConfig(**load_json(path)["config"])


def run(a: argparse.Namespace) -> int:
    """Runs the measurements, writes the report and the JSON; returns the exit status."""
    torch.set_num_threads(a.threads)
    models = {"teacher": load_generator(a.teacher), "student": load_generator(a.student)}
    weights = {"teacher": a.teacher, "student": a.student}
    for item in a.candidate:
        name, sep, path = item.partition("=")
        if not sep or not name or name in models:
            raise SystemExit(f"error: --candidate {item!r}: expected a new NAME=PATH")
        models[name] = load_generator(Path(path))
        weights[name] = Path(path)
    rng = np.random.default_rng(a.seed)
    res: dict = {"weights": {k: {"path": paths.repo_relative(Path(v)), "sha256": sha256_file(Path(v))}
                             for k, v in weights.items()},
                 "distill_manifest_sha256": sha256_file(Path(a.distill) / "manifest.json"), "commit": git_commit()}
    lines = [
        "# Reaction: how the predicted traffic answers the ego's plan",
        "",
        "Generated by `nudge-train reaction` (python/train/nudge_train/experiments/reaction_report.py); "
        "metres, one step = 0.3 s. Models: "
        + ", ".join(f"`{k}` = `{paths.repo_relative(Path(v))}`" for k, v in weights.items()) + ".",
        "",
    ]
    lines += _planner_section(a, models, rng, res)
    lines += _cutin_section(a, models, rng, res)
    a.report.parent.mkdir(parents=True, exist_ok=True)
    existing = a.report.read_text() if a.report.exists() else ""
    notes = existing.split("<!-- notes -->", 1)[1] if "<!-- notes -->" in existing else "\n"
    a.report.write_text("\n".join(lines) + "\n<!-- notes -->" + notes)
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(res, indent=1, default=float) + "\n")
    print("\n".join(lines))
    print(f"wrote {a.report} and {a.json}")
    return 0
