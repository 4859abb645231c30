"""The paper's teacher experiments (Table I): train five configurations, pick one, report, export.

``nudge-train teacher [--data DIR] [--epochs N] [--only NAME ...]``

1. trains every ``python/train/configs/teacher_*.toml`` (resumable: a finished run is skipped, an
   interrupted one resumes from its ``last.pt``);
2. selects the configuration with the lowest validation single-sample FDE at 1.8 s (recursive,
   interactive use: what the planner relies on);
3. evaluates every configuration and a constant-velocity baseline ONCE on the test split, whole
   and interactive subset, single sample and best-of-20, and writes ``docs/results/teacher.md``
   with the paper's Table I beside ours, plus the training curves ``docs/figures/teacher_curves.png``;
4. exports the chosen generator to ``assets/models/teacher.safetensors`` with its provenance.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nudge_train import paths
from nudge_train.constants import PRED_LEN
from nudge_train.data.loader import WindowSet, load_split
from nudge_train.experiments.plots import plot_curves
from nudge_train.jsonio import load_json
from nudge_train.provenance import git_commit, sha256_file
from nudge_train.training.config import load_config
from nudge_train.training.evaluate import Metrics, evaluate_constant_velocity, evaluate_generator
from nudge_train.training.export import export_generator
from nudge_train.training.log import read_metrics
from nudge_train.training.loop import load_best, train

PAPER_TABLE_I = {  # (k_var, I_adv): (ADE@1, FDE@1, ADE@6, FDE@6), metres per the paper
    (1, 1): (0.02, 0.21, 0.40, 1.41),
    (1, 0): (0.01, 0.12, 0.26, 0.96),
    (30, 1): (0.01, 0.13, 0.27, 0.99),
    (64, 1): (0.01, 0.13, 0.26, 0.96),
    (64, 0): (0.01, 0.13, 0.26, 0.98),
}


def _label(rec: dict[str, Any]) -> str:
    return f"k_var={rec['k_var']:g}, I_adv={rec['i_adv']}, k={rec['tcfg'].k_samples}"


def _train_seconds(out: Path) -> tuple[int, float]:
    """Epochs run and summed epoch wall time (s) from a run's ``metrics.jsonl``."""
    rows = read_metrics(out)
    return len(rows), float(sum(r["seconds"] for r in rows))


def _fmt(m: Metrics) -> str:
    return f"{m.ade1:.3f} | {m.ade6:.3f} | {m.fde6:.3f}"


def run(
    *,
    data: str,
    runs_dir: str,
    epochs: int | None,
    only: list[str] | None,
    report: str,
    export: str | None,
    threads: int,
) -> int:
    """``nudge-train teacher``: the whole experiment (see the module doc). ``data``: processed
    build; ``runs_dir``: one training run per config below it; ``epochs``: overrides every
    config's epoch count; ``only``: config names to keep; ``export``: where the chosen teacher is
    written (``None``: not exported)."""
    torch.set_num_threads(threads)

    train_set = load_split(Path(data), "train")
    val_set = load_split(Path(data), "val")
    test_set = load_split(Path(data), "test")
    print(f"windows: train {len(train_set)}, val {len(val_set)}, test {len(test_set)}")

    configs = sorted(paths.configs().glob("teacher_*.toml"))
    if only:
        configs = [c for c in configs if c.stem in only]
    results: dict[str, dict[str, Any]] = {}
    runs: dict[str, Path] = {}
    for path in configs:
        mcfg, tcfg = load_config(path)
        over: dict[str, Any] = {"out_dir": str(Path(runs_dir) / path.stem), "data": data}
        if epochs is not None:
            over["epochs"] = epochs
        tcfg = dataclasses.replace(tcfg, **over).validate()
        out = Path(tcfg.out_dir)
        runs[path.stem] = out
        t0 = time.perf_counter()
        if (out / "summary.json").exists():
            summary = load_json(out / "summary.json")
            print(f"{path.stem}: already trained (best epoch {summary['best_epoch']})")
        else:
            print(f"== training {path.stem}")
            summary = train(mcfg, tcfg, resume=(out / "last.pt").exists(), train_set=train_set, val_set=val_set)
        gen = load_best(out, mcfg)
        val_rec = evaluate_generator(gen, val_set, mode="recursive")
        results[path.stem] = {
            "k_var": tcfg.k_var,
            "i_adv": tcfg.i_adv,
            "mcfg": mcfg,
            "tcfg": tcfg,
            "summary": summary,
            "val_recursive_fde6": val_rec.fde6,
            "invocation_seconds": time.perf_counter() - t0,
            "epochs_run_seconds": _train_seconds(out),
        }
    chosen = min(results, key=lambda k: results[k]["val_recursive_fde6"])
    print(f"chosen by validation single-sample recursive FDE@1.8s: {chosen}")

    inter = np.flatnonzero(test_set.interactive.astype(bool))
    lines = _report_header(train_set, val_set, test_set, inter, chosen)
    subsets = [("all test windows", None), ("interactive test windows", inter)]
    for title, subset in subsets:
        lines += [f"\n### {title}\n", "| model | mode | samples | ADE@0.3s | ADE@1.8s | FDE@1.8s | scenes | agents |",
                  "|---|---|---|---|---|---|---|---|"]
        cv_all = evaluate_constant_velocity(test_set, skip_ego=False, subset=subset)
        cv_oth = evaluate_constant_velocity(test_set, skip_ego=True, subset=subset)
        lines.append(f"| constant velocity | all agents | - | {_fmt(cv_all)} | {cv_all.scenes} | {cv_all.agents} |")
        lines.append(f"| constant velocity | non-ego agents | - | {_fmt(cv_oth)} | {cv_oth.scenes} | {cv_oth.agents} |")
        for name, rec in results.items():
            gen = load_best(runs[name], rec["mcfg"])
            mark = " (chosen)" if name == chosen else ""
            modes = [("recursive", "recursive ×6, ego = log, non-ego")]
            if rec["tcfg"].train_steps == PRED_LEN:  # only a 6-step-trained decoder is meant to be called that way
                modes.insert(0, ("decoder", "one call, 6 steps, all agents"))
            for mode, label in modes:
                for samples in (1, 20):
                    m = evaluate_generator(gen, test_set, mode=mode, samples=samples, subset=subset)
                    rec.setdefault("test", {})[(title, mode, samples)] = m
                    lines.append(
                        f"| {_label(rec)}{mark} | {label} | "
                        f"{'fixed z' if samples == 1 else 'best of 20'} | {_fmt(m)} | {m.scenes} | {m.agents} |"
                    )
    lines += _paper_table(results)
    lines += _training_table(results)
    lines += _reading(results)
    report_path = Path(report)
    report_path.parent.mkdir(parents=True, exist_ok=True)
    plot_curves(
        runs,
        paths.figures() / "teacher_curves.png",
        "Teacher training on NGSIM (train split), validation on the val split",
        "train variety loss (m², best of k)",
        "validation metric, fixed z (m)\n(recursive FDE@1.8s, or ADE)",
    )
    lines.append("\n![training curves](../figures/teacher_curves.png)\n")
    report_path.write_text("\n".join(lines) + "\n")
    print(f"wrote {report_path}")

    if export is not None:
        rec = results[chosen]
        gen = load_best(runs[chosen], rec["mcfg"])
        prov = {
            "data": paths.repo_relative(Path(data)),
            "manifest_sha256": sha256_file(Path(data) / "manifest.json"),
            "split": "train (selected on val)",
            "config": chosen,
            "train": dataclasses.asdict(rec["tcfg"]),
            "best_epoch": rec["summary"]["best_epoch"],
            "best_val_ade": rec["summary"]["best_val_ade"],
            "val_recursive_fde6": rec["val_recursive_fde6"],
            "commit": git_commit(),
            "hardware": f"{torch.get_num_threads()} CPU threads" if not torch.cuda.is_available() else torch.cuda.get_device_name(),
        }
        export_generator(gen, rec["mcfg"], Path(export), trained=True, provenance=prov)
        print(f"exported {chosen} to {export}")
    return 0


def _report_header(train_set: WindowSet, val_set: WindowSet, test_set: WindowSet, inter: np.ndarray, chosen: str) -> list[str]:
    return [
        "# Teacher results (Table I of the paper, on our NGSIM data)",
        "",
        "Generated by `nudge-train teacher` (see README). Metres; one step = 0.3 s.",
        f"Windows: train {len(train_set)}, val {len(val_set)}, test {len(test_set)} "
        f"({len(inter)} interactive test windows). Chosen teacher: **{chosen}** "
        "(lowest validation single-sample recursive FDE at 1.8 s).",
        "",
        "Modes: *recursive ×6* is how the planner uses the teacher: six one-step calls, the ego "
        "set to its logged future after each, the other agents scored (a teacher trained on one-step "
        "targets is only called this way); *one call, 6 steps* (only for configurations trained on "
        "6-step targets) decodes 6 steps from one generator call, Social-GAN's usual evaluation, "
        "every agent scored. At 0.3 s ADE = FDE. *fixed z*: the weights' fixed noise vector, the "
        "planner's single sample; *best of 20*: per scene the z draw (held over the 6 calls) with "
        "the lowest summed ADE. *k*: z draws per scene in the training variety loss.",
    ]


def _paper_table(results: dict[str, dict[str, Any]]) -> list[str]:
    out = [
        "\n### Beside the paper's Table I (ours: recursive mode, all test windows; FDE@1 = ADE@1)\n",
        "| config | k_var | I_adv | paper ADE@1 | paper FDE@1 | paper ADE@6 | paper FDE@6 "
        "| ours fixed z ADE@1 | ADE@6 | FDE@6 | ours best of 20 ADE@1 | ADE@6 | FDE@6 |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, rec in results.items():
        key = (int(rec["k_var"]), int(rec["i_adv"]))
        paper = PAPER_TABLE_I.get(key, (float("nan"),) * 4) if rec["tcfg"].k_samples == 20 else ("-",) * 4
        one = rec["test"][("all test windows", "recursive", 1)]
        best = rec["test"][("all test windows", "recursive", 20)]
        out.append(
            f"| {name} | {key[0]} | {key[1]} | {paper[0]} | {paper[1]} | {paper[2]} | {paper[3]} | "
            f"{one.ade1:.3f} | {one.ade6:.3f} | {one.fde6:.3f} | {best.ade1:.3f} | {best.ade6:.3f} | {best.fde6:.3f} |"
        )
    out.append(
        "\nThe paper trains on ~66k I-80 examples it filtered itself (units presumably metres, its "
        "split random by example, so the same vehicles appear in training and test); we train on the "
        "NGSIM material available here (US-101 CommonRoad scenes and the Coifman & Li I-80 "
        "re-extraction, split by overlap group / time block so no vehicle appears in two splits), "
        "so absolute numbers are not comparable; the ordering of the configurations and the margin "
        "over constant velocity are what carry over. The paper's FDE@1 differs from its ADE@1, "
        "which cannot be for a single step; we report ADE@1 = FDE@1."
    )
    return out


def _reading(results: dict[str, dict[str, Any]]) -> list[str]:
    order = sorted(results, key=lambda k: results[k]["val_recursive_fde6"])
    ranking = " < ".join(f"{k} {results[k]['val_recursive_fde6']:.3f}" for k in order)
    return [
        "",
        f"Validation ranking (single-sample recursive FDE@1.8s in m, the selection metric): {ranking}. "
        "A k = 20 configuration is trained on the best of 20 z draws per scene, so its fixed-z sample is "
        "not what its loss optimises (compare its fixed z and best of 20 rows); the planner uses one fixed "
        "z, which is why the shipped teacher is trained with k = 1 (plain L2 regression, the paper's "
        "I_adv = 0 choice). Epoch budgets differ: see *epochs run*.",
    ]


def _training_table(results: dict[str, dict[str, Any]]) -> list[str]:
    out = [
        "\n### Training runs\n",
        "| config | k samples | train steps | epochs run | best epoch | best val metric (train.val_metric) "
        "| val recursive FDE@1.8s, fixed z | training wall time (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, rec in results.items():
        s = rec["summary"]
        epochs, seconds = rec["epochs_run_seconds"]
        out.append(
            f"| {name} | {rec['tcfg'].k_samples} | {rec['tcfg'].train_steps} | {epochs} | {s['best_epoch'] + 1} "
            f"| {s['best_val_ade']:.3f} | {rec['val_recursive_fde6']:.3f} | {seconds:.0f} |"
        )
    return out

