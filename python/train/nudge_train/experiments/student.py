"""Distil the student from the teacher: train, evaluate, report, export.

``nudge-train student [--config FILE] [--distill DIR] [--data DIR]``

1. trains ``python/train/configs/student.toml`` on the distillation set (``data/distill``, made by
   ``nudge-train distill`` with the shipped teacher; resumable like every training run);
2. evaluates the best-validation student ONCE on held-out data, whole and interactive subset:

   * *fidelity*: against the teacher's own predictions on the distillation test split (the
     planner's candidates, the teacher's answers), ADE / FDE over the other agents;
   * *accuracy*: on the real NGSIM test windows with the ego imposed on its logged future, beside
     the teacher's recursive prediction (fixed z, ego = log) and constant velocity;

3. writes ``docs/results/student.md`` and the training curve ``docs/figures/student_curves.png``;
4. exports the student to ``assets/models/student.safetensors`` (trained = "true") with its
   provenance (distillation manifest hash, teacher hash, config, best epoch, commit).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nudge_train import paths
from nudge_train.data.loader import load_split
from nudge_train.experiments.plots import plot_curves
from nudge_train.jsonio import load_json
from nudge_train.provenance import git_commit, sha256_file
from nudge_train.training.config import load_config
from nudge_train.training.evaluate import Metrics, evaluate_constant_velocity, evaluate_generator
from nudge_train.training.export import export_generator, load_generator, read_weights
from nudge_train.training.log import read_metrics
from nudge_train.training.loop import load_best, train


def _row(name: str, m: Metrics) -> str:
    return f"| {name} | {m.ade1:.3f} | {m.ade6:.3f} | {m.fde6:.3f} | {m.scenes} | {m.agents} |"



def evaluation_lines(student: torch.nn.Module, teacher_gen: torch.nn.Module, teacher_sha: str, distill_dir: Path,
                     data: Path, train_val: tuple[int, int]) -> list[str]:
    """The report's evaluation sections (markdown lines) of ``student`` against ``teacher_gen``
    (its file's sha256 ``teacher_sha``): the distillation set (``train_val`` = its train and val
    example counts) and its fidelity on the set's test split, the reaction table on the same
    split's planner calls, and the accuracy on the real test windows of the processed build
    ``data``, beside the teacher and constant velocity."""
    from nudge_train.distill.contexts import load_contexts
    from nudge_train.experiments.reaction_report import planner_table

    dtest = load_split(distill_dir, "test")
    real = load_split(data, "test")
    lines = [
        f"Distillation set `{distill_dir.name}` (teacher sha256 `{teacher_sha[:16]}…`): train {train_val[0]}, "
        f"val {train_val[1]}, test {len(dtest)} examples (one example = one scene history + one ego "
        "candidate the planner evaluated + the teacher's prediction). Real test windows: "
        f"{len(real)} ({int(real.interactive.sum())} interactive).",
        "",
        "## Fidelity: student vs teacher on the planner's candidates (distillation test split)",
        "",
        "| subset | ADE@0.3s | ADE@1.8s | FDE@1.8s | examples | agents |",
        "|---|---|---|---|---|---|",
    ]
    inter_d = np.flatnonzero(dtest.interactive.astype(bool))
    lines.append(_row("all", evaluate_generator(student, dtest, mode="decoder")))
    if len(inter_d):
        lines.append(_row("scenes with a logged lane change", evaluate_generator(student, dtest, subset=inter_d)))
    table, _ = planner_table(load_contexts(distill_dir, "test", paths.processed() / "scenes"),
                             {"teacher": teacher_gen, "student": student}, np.random.default_rng(0), 2000)
    lines += [
        "",
        "## Reaction to the ego: student vs teacher on the planner's candidates (distillation test split)",
        "",
        "How far the target-lane follower's predicted position at 1.8 s moves between a lane-change candidate "
        "and the same candidate keeping its lane (docs/results/reaction.md, `nudge-train reaction`).",
        "",
        *table,
        "",
        "## Accuracy on real NGSIM test windows (ego on its logged future)",
    ]
    inter = np.flatnonzero(real.interactive.astype(bool))
    for title, subset in (("all test windows", None), ("interactive test windows", inter)):
        lines += ["", f"### {title}", "", "| model | ADE@0.3s | ADE@1.8s | FDE@1.8s | scenes | agents |",
                  "|---|---|---|---|---|---|"]
        lines.append(_row("constant velocity", evaluate_constant_velocity(real, skip_ego=True, subset=subset)))
        lines.append(_row("teacher (recursive ×6, fixed z)",
                          evaluate_generator(teacher_gen, real, mode="recursive", subset=subset)))
        lines.append(_row("student (one pass)", evaluate_generator(student, real, mode="decoder", subset=subset)))
    return lines


def run(
    *,
    config: Path,
    distill: str,
    data: str,
    out_dir: str,
    epochs: int | None,
    teacher: str,
    report: str,
    export: str | None,
    threads: int,
) -> int:
    """``nudge-train student``: the distillation experiment (see the module doc). ``distill``:
    the distillation set; ``data``: the processed build (its real test windows); ``teacher``: the
    weights the set was generated with; ``export``: where the student is written (``None``: not
    exported)."""
    torch.set_num_threads(threads)

    mcfg, tcfg = load_config(config)
    over: dict[str, Any] = {"out_dir": out_dir, "data": distill}
    if epochs is not None:
        over["epochs"] = epochs
    tcfg = dataclasses.replace(tcfg, **over).validate()
    distill_dir = Path(distill)
    manifest = load_json(distill_dir / "manifest.json")
    teacher_sha = sha256_file(Path(teacher))
    if manifest["teacher"]["sha256"] != teacher_sha:
        raise SystemExit(
            f"error: {distill_dir} was generated with teacher sha256 {manifest['teacher']['sha256'][:12]}..., "
            f"but {teacher} is {teacher_sha[:12]}...: regenerate it (nudge-train distill)"
        )
    train_set, val_set = load_split(distill_dir, "train"), load_split(distill_dir, "val")
    print(f"distillation examples: train {len(train_set)}, val {len(val_set)}")
    out = Path(tcfg.out_dir)
    t0 = time.perf_counter()
    if (out / "summary.json").exists():
        summary = load_json(out / "summary.json")
        print(f"student already trained (best epoch {summary['best_epoch'] + 1})")
    else:
        summary = train(mcfg, tcfg, resume=(out / "last.pt").exists(), train_set=train_set, val_set=val_set)
    wall = time.perf_counter() - t0
    rows = read_metrics(out)
    train_seconds = sum(r["seconds"] for r in rows)
    student = load_best(out, mcfg)
    teacher_gen = load_generator(Path(teacher))

    lines = [
        "# Student results (distilled from the shipped teacher)",
        "",
        "Generated by `nudge-train student` (see README). Metres; one step = 0.3 s; "
        "the ego is imposed (its candidate or its logged future) and only the other agents are scored.",
        "",
        *evaluation_lines(student, teacher_gen, teacher_sha, distill_dir, Path(data),
                          (len(train_set), len(val_set))),
    ]
    lines += [
        "",
        "## Training",
        "",
        f"Config `{config.name}`: k_var {tcfg.k_var:g}, I_adv {tcfg.i_adv}, k {tcfg.k_samples}, lr {tcfg.lr:g} "
        f"({tcfg.lr_schedule}), batch {tcfg.batch_size}, {len(rows)} epochs run, best epoch {summary['best_epoch'] + 1} "
        f"(val ADE vs teacher {summary['best_val_ade']:.4f} m), training wall time {train_seconds:.0f} s on "
        f"{torch.get_num_threads()} CPU threads (this invocation {wall:.0f} s).",
        "",
        "![student training](../figures/student_curves.png)",
    ]
    plot_curves(
        {"student": out},
        paths.figures() / "student_curves.png",
        "Student distillation (train: planner-generated set, val: its val split)",
        "train L2 loss vs teacher (m²)",
        "val ADE vs teacher, 6 steps (m)",
    )
    report_path = Path(report)
    report_path.parent.mkdir(parents=True, exist_ok=True)
    report_path.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {report_path}")
    if export is not None:
        prov = {
            "data": paths.repo_relative(distill_dir),
            "distill_manifest_sha256": sha256_file(distill_dir / "manifest.json"),
            "teacher_sha256": teacher_sha,
            "split": "distillation train (selected on distillation val)",
            "config": config.name,
            "train": dataclasses.asdict(tcfg),
            "best_epoch": summary["best_epoch"],
            "best_val_ade": summary["best_val_ade"],
            "commit": git_commit(),
            "hardware": f"{torch.get_num_threads()} CPU threads"
            if not torch.cuda.is_available()
            else torch.cuda.get_device_name(),
        }
        export_generator(student, mcfg, Path(export), trained=True, provenance=prov)
        print(f"exported the student to {export}")
    return 0



def _training_lines(weights: Path) -> list[str]:
    """How ``weights`` was trained, stage by stage (newest first), from its provenance: a
    ``student-react`` stage records the provenance of the student it was fine-tuned from
    (``init_provenance``), back to the position-only student of ``nudge-train student``."""
    out: list[str] = []
    prov: dict | None = read_weights(weights).provenance
    while prov:
        train_cfg = prov.get("train", {})
        sel = prov.get("selected")
        commit = str(prov.get("commit", "?"))[:10]
        if sel is None:
            out.append(
                f"- `nudge-train student --config python/train/configs/{prov.get('config')}` (commit `{commit}`): "
                f"position (L2) loss only, on the distillation set `{prov.get('data')}`, best epoch "
                f"{int(prov.get('best_epoch', -1)) + 1} (validation ADE vs teacher "
                f"{float(prov.get('best_val_ade', float('nan'))):.4f} m).")
            break
        ref = prov.get("reference", {})
        out.append(
            f"- `nudge-train student-react --config python/train/configs/{prov.get('config')}` (commit `{commit}`, "
            f"{prov.get('hardware', '?')}): fine-tuned from `{train_cfg.get('init')}` on `{prov.get('data')}` with "
            f"reaction weight {train_cfg.get('reaction_weight', 0):g}, lr {train_cfg.get('lr', 0):g}, time budget "
            f"{train_cfg.get('time_budget_s', 0):.0f} s; kept step {sel['step']} (evaluated every "
            f"{train_cfg.get('eval_every')}): validation ADE / FDE vs teacher {sel['val_ade']:.4f} / "
            f"{sel['val_fde']:.4f} m, reaction error {sel['val_reaction_error']:.4f} m (the reference "
            f"`{train_cfg.get('reference')}`: {ref.get('val_ade', float('nan')):.4f} / "
            f"{ref.get('val_fde', float('nan')):.4f} m, {ref.get('val_reaction_error', float('nan')):.4f} m).")
        prov = prov.get("init_provenance")
    return out


def report(*, weights: Path, teacher: Path, distill: Path, data: Path, out: Path, threads: int) -> int:
    """``nudge-train student-report``: the student report (``docs/results/student.md``) of the
    student in ``weights`` (default the shipped one), evaluated against ``teacher`` on the test
    split of the distillation set ``distill`` it was trained on and on the real test windows of
    ``data``, with how it was trained (its provenance, stage by stage). Returns the exit status."""
    import sys

    torch.set_num_threads(threads)
    t0 = time.perf_counter()
    try:
        manifest = load_json(distill / "manifest.json")
        teacher_sha = sha256_file(teacher)
        student = load_generator(weights)
        teacher_gen = load_generator(teacher)
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if manifest["teacher"]["sha256"] != teacher_sha:
        print(f"error: {distill} was generated with teacher sha256 {manifest['teacher']['sha256'][:12]}..., "
              f"but {teacher} is {teacher_sha[:12]}...", file=sys.stderr)
        return 2
    counts = tuple(int(manifest["splits"][s]["examples"]) for s in ("train", "val"))
    lines = [
        "# Student results (distilled from the shipped teacher)",
        "",
        f"Generated by `nudge-train student-report` for `{paths.repo_relative(weights)}` (see README). Metres; "
        "one step = 0.3 s; the ego is imposed (its candidate or its logged future) and only the other agents are "
        "scored.",
        "",
        *evaluation_lines(student, teacher_gen, teacher_sha, distill, data, (counts[0], counts[1])),
        "",
        "## Training",
        "",
        "How it was trained, from its provenance, newest stage first (validation numbers on the validation "
        "split of the distillation set each stage was trained on):",
        "",
        *_training_lines(weights),
        "",
        f"(report computed in {time.perf_counter() - t0:.0f} s on {torch.get_num_threads()} CPU threads)",
    ]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {out}")
    return 0
