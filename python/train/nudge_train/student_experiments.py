"""Distil the student from the teacher: train, evaluate, report, export.

``python -m nudge_train.student_experiments [--config FILE] [--distill DIR] [--data DIR]``

1. trains ``python/train/configs/student.toml`` on the distillation set (``data/distill``, made by
   ``python -m nudge_train.distill`` with the shipped teacher; resumable like every training run);
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

import argparse
import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nudge_train.evaluate import Metrics, evaluate_constant_velocity, evaluate_generator
from nudge_train.export import export_generator, load_generator
from nudge_train.teacher_experiments import _git_commit
from nudge_train.training import load_best, load_config, train
from nudge_train.windows_data import load_split

REPO = Path(__file__).resolve().parents[3]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else "missing"


def _row(name: str, m: Metrics) -> str:
    return f"| {name} | {m.ade1:.3f} | {m.ade6:.3f} | {m.fde6:.3f} | {m.scenes} | {m.agents} |"


def _plot(out: Path, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines() if line]
    ep = [r["epoch"] + 1 for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    axes[0].plot(ep, [r["loss_var"] for r in rows])
    axes[0].set(xlabel="epoch", ylabel="train L2 loss vs teacher (m²)", yscale="log")
    axes[1].plot(ep, [r["val_ade"] for r in rows])
    axes[1].set(xlabel="epoch", ylabel="val ADE vs teacher, 6 steps (m)")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle("Student distillation (train: planner-generated set, val: its val split)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Runs the distillation experiment; see the module doc."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", type=Path, default=REPO / "python" / "train" / "configs" / "student.toml")
    ap.add_argument("--distill", default=str(REPO / "data" / "distill"))
    ap.add_argument("--data", default=str(REPO / "data" / "processed"), help="real NGSIM windows (test split)")
    ap.add_argument("--out-dir", default=str(REPO / "runs" / "student"))
    ap.add_argument("--epochs", type=int, default=None)
    ap.add_argument("--teacher", default=str(REPO / "assets" / "models" / "teacher.safetensors"))
    ap.add_argument("--report", default=str(REPO / "docs" / "results" / "student.md"))
    ap.add_argument("--export", default=str(REPO / "assets" / "models" / "student.safetensors"))
    ap.add_argument("--no-export", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)

    mcfg, tcfg = load_config(args.config)
    over: dict[str, Any] = {"out_dir": args.out_dir, "data": args.distill}
    if args.epochs is not None:
        over["epochs"] = args.epochs
    tcfg = dataclasses.replace(tcfg, **over).validate()
    distill = Path(args.distill)
    manifest = json.loads((distill / "manifest.json").read_text())
    teacher_sha = _sha(Path(args.teacher))
    if manifest["teacher"]["sha256"] != teacher_sha:
        raise SystemExit(
            f"error: {distill} was generated with teacher sha256 {manifest['teacher']['sha256'][:12]}..., "
            f"but {args.teacher} is {teacher_sha[:12]}...: regenerate it (python -m nudge_train.distill)"
        )
    train_set, val_set = load_split(distill, "train"), load_split(distill, "val")
    print(f"distillation examples: train {len(train_set)}, val {len(val_set)}")
    out = Path(tcfg.out_dir)
    t0 = time.perf_counter()
    if (out / "summary.json").exists():
        summary = json.loads((out / "summary.json").read_text())
        print(f"student already trained (best epoch {summary['best_epoch'] + 1})")
    else:
        summary = train(mcfg, tcfg, resume=(out / "last.pt").exists(), train_set=train_set, val_set=val_set)
    wall = time.perf_counter() - t0
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines() if line]
    train_seconds = sum(r["seconds"] for r in rows)
    student = load_best(out, mcfg)
    teacher = load_generator(Path(args.teacher))

    dtest = load_split(distill, "test")
    real = load_split(Path(args.data), "test")
    lines = [
        "# Student results (distilled from the shipped teacher)",
        "",
        "Generated by `python -m nudge_train.student_experiments` (see README). Metres; one step = 0.3 s; "
        "the ego is imposed (its candidate or its logged future) and only the other agents are scored.",
        "",
        f"Distillation set `{distill.name}` (teacher sha256 `{teacher_sha[:16]}…`): train {len(train_set)}, "
        f"val {len(val_set)}, test {len(dtest)} examples (one example = one scene history + one ego "
        "candidate the planner evaluated + the teacher's prediction). Real test windows: "
        f"{len(real)} ({int(real.interactive.sum())} interactive).",
        "",
        "## Fidelity: student vs teacher on the planner's candidates (distillation test split)",
        "",
        "| subset | ADE@0.3s | ADE@1.8s | FDE@1.8s | examples | agents |",
        "|---|---|---|---|---|---|",
    ]
    inter_d = np.flatnonzero(dtest.interactive.astype(bool))
    fid_all = evaluate_generator(student, dtest, mode="decoder")
    lines.append(_row("all", fid_all))
    if len(inter_d):
        lines.append(_row("scenes with a logged lane change", evaluate_generator(student, dtest, subset=inter_d)))
    lines += [
        "",
        "## Accuracy on real NGSIM test windows (ego on its logged future)",
    ]
    inter = np.flatnonzero(real.interactive.astype(bool))
    for title, subset in (("all test windows", None), ("interactive test windows", inter)):
        lines += ["", f"### {title}", "", "| model | ADE@0.3s | ADE@1.8s | FDE@1.8s | scenes | agents |",
                  "|---|---|---|---|---|---|"]
        lines.append(_row("constant velocity", evaluate_constant_velocity(real, skip_ego=True, subset=subset)))
        lines.append(_row("teacher (recursive ×6, fixed z)", evaluate_generator(teacher, real, mode="recursive", subset=subset)))
        lines.append(_row("student (one pass)", evaluate_generator(student, real, mode="decoder", subset=subset)))
    lines += [
        "",
        "## Training",
        "",
        f"Config `{args.config.name}`: k_var {tcfg.k_var:g}, I_adv {tcfg.i_adv}, k {tcfg.k_samples}, lr {tcfg.lr:g} "
        f"({tcfg.lr_schedule}), batch {tcfg.batch_size}, {len(rows)} epochs run, best epoch {summary['best_epoch'] + 1} "
        f"(val ADE vs teacher {summary['best_val_ade']:.4f} m), training wall time {train_seconds:.0f} s on "
        f"{torch.get_num_threads()} CPU threads (this invocation {wall:.0f} s).",
        "",
        "![student training](../figures/student_curves.png)",
    ]
    _plot(out, REPO / "docs" / "figures" / "student_curves.png")
    report = Path(args.report)
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {report}")
    if not args.no_export:
        prov = {
            "data": str(distill.resolve().relative_to(REPO)) if distill.resolve().is_relative_to(REPO) else str(distill),
            "distill_manifest_sha256": _sha(distill / "manifest.json"),
            "teacher_sha256": teacher_sha,
            "split": "distillation train (selected on distillation val)",
            "config": args.config.name,
            "train": dataclasses.asdict(tcfg),
            "best_epoch": summary["best_epoch"],
            "best_val_ade": summary["best_val_ade"],
            "commit": _git_commit(),
            "hardware": f"{torch.get_num_threads()} CPU threads"
            if not torch.cuda.is_available()
            else torch.cuda.get_device_name(),
        }
        export_generator(student, mcfg, Path(args.export), trained=True, provenance=prov)
        print(f"exported the student to {args.export}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
