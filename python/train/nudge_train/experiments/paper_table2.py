"""The paper's Table II: five student configurations trained under one budget on a distillation
set, selected on validation, evaluated once on test (``nudge-train paper``, stage ``table2``).

1. **Distillation set** (:func:`nudge_train.distill.pipeline.generate`, resumable and verified
   shard by shard): the current planner with the shipped teacher as planning predictor and world,
   ``size`` scenes per split (the paper's size by default, docs/distill.md).
2. **Five students**, (k_var, I_adv) ∈ :data:`CONFIGS`, the paper's student sizes
   (``python/train/configs/student.toml``: encoder / decoder 16, MLP 16, discriminator encoder
   24, no z, k = 1), every one with the same optimiser, epochs and samples per epoch (one
   budget); each training run resumes from its ``last.pt`` and is skipped once its
   ``summary.json`` exists.
3. **Selection** on the distillation validation split (the run's best validation ADE against the
   teacher). Every configuration's best checkpoint is exported with its provenance to
   ``<runs>/<name>/student.safetensors`` (:func:`export_all`), so that any of them can plan or
   be compared in closed loop; the shipped ``assets/models/student.safetensors`` is never
   touched here (shipping the chosen one is a deliberate step, docs/paper/README.md).
4. **Test, once**: ADE / FDE at 1.8 s against the teacher on the held-out planner candidates
   (distillation test split; all, and scenes with a logged lane change) and against the logged
   future on the real test windows (all, interactive), the ego imposed. Cached per configuration
   with the hash of its weights and of the test sets.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nudge_train.experiments.paper_runs import Log, file_sha, load_cached, sha256, write_cached

CONFIGS = ((1, 1), (1, 0), (64, 1), (64, 0), (128, 0))
"""The paper's student configurations (k_var, I_adv), in its table's order."""
PAPER_TABLE_II = {(1, 1): (0.69, 1.14), (1, 0): (0.17, 0.31), (64, 1): (0.24, 0.42), (64, 0): (0.17, 0.31),
                  (128, 0): (0.16, 0.29)}
"""The paper's Table II: ADE, FDE at T_pred = 6 (1.8 s), its chosen (128, 0)."""
PAPER_CHOICE = (128, 0)


@dataclass(frozen=True)
class Table2Spec:
    """What the stage runs. ``size``: scenes per split of the distillation set; ``distill_steps``:
    closed-loop steps per run of the generator; ``epochs`` / ``samples_per_epoch`` /
    ``batch_size``: the one training budget (``None``: the base config's); ``max_val_windows``:
    validation subset per epoch; ``max_real``: real test windows evaluated (``None``: all);
    ``threads``: torch threads and rayon threads of the generator; ``students``: run folder names
    (:func:`name_of`) to train in this invocation, ``None`` for all five (a subset lets several
    processes share the five trainings; the table is written by an invocation that trains all)."""

    distill: Path
    runs: Path
    cache: Path
    base_config: Path
    size: dict[str, int | None]
    distill_steps: int
    epochs: int | None
    samples_per_epoch: int | None
    batch_size: int | None
    max_val_windows: int | None
    max_real: int | None
    threads: int
    progress: bool
    students: tuple[str, ...] | None = None


def name_of(kv: int, adv: int) -> str:
    """Run folder name of a configuration: ``student_k64_adv0``."""
    return f"student_k{kv}_adv{adv}"


def check_students(names: tuple[str, ...] | None) -> None:
    """Raises ValueError naming the first name that is not a configuration's run folder name."""
    known = [name_of(kv, adv) for kv, adv in CONFIGS]
    for n in names or ():
        if n not in known:
            raise ValueError(f"students: {n!r} is not one of {known}")
    if names is not None and not names:
        raise ValueError("students: at least one name expected")


def generate_set(spec: Table2Spec, log: Log) -> dict:
    """Generates (or completes) the distillation set; returns its manifest."""
    from nudge_train.distill.config import DistillConfig
    from nudge_train.distill.pipeline import generate

    cfg = DistillConfig(out=spec.distill, max_scenes=dict(spec.size), max_steps=spec.distill_steps,
                        threads=spec.threads, progress=spec.progress)
    return generate(cfg, log=log)


INPUTS_FILE = "paper_inputs.json"
"""The inputs a Table II training run was started with (data shards, configuration), in its folder."""


def _shards_key(distill: Path, splits: tuple[str, ...]) -> list[str]:
    """The sha256 of every shard of ``splits`` the distillation manifest lists, in order."""
    from nudge_train.jsonio import load_json

    manifest = load_json(distill / "manifest.json")
    return [e["sha256"] for s in splits for e in manifest["splits"][s]["shards"]]


def _check_run_inputs(run_dir: Path, inputs: dict[str, Any], log: Log) -> None:
    """Keeps a training run folder only when it was started with ``inputs`` (same data shards,
    same configuration); otherwise removes it, so the run starts afresh, and says so."""
    import shutil

    key = sha256(json.dumps(inputs, sort_keys=True, default=str).encode())
    record = run_dir / INPUTS_FILE
    if run_dir.exists() and any(run_dir.iterdir()):
        try:
            ok = json.loads(record.read_text()).get("key") == key
        except (OSError, json.JSONDecodeError, AttributeError):
            ok = False
        if ok:
            return
        log(f"table2: {run_dir} was trained on other data or settings; training it afresh")
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps({"key": key, "inputs": inputs}, indent=1, default=str))


def train_all(spec: Table2Spec, log: Log) -> dict[tuple[int, int], dict[str, Any]]:
    """Trains (or resumes, or skips) the five configurations; returns their summaries (with the
    training wall time summed over epochs, ``train_s``)."""
    import torch

    from nudge_train.data.loader import load_split
    from nudge_train.jsonio import load_json
    from nudge_train.training.config import load_config
    from nudge_train.training.log import read_metrics
    from nudge_train.training.loop import train

    torch.set_num_threads(spec.threads)
    mcfg, base = load_config(spec.base_config)
    over: dict[str, Any] = {"data": str(spec.distill), "threads": spec.threads, "device": "cpu"}
    for key in ("epochs", "samples_per_epoch", "batch_size", "max_val_windows"):
        if getattr(spec, key) is not None:
            over[key] = getattr(spec, key)
    if spec.epochs is not None:
        over["patience"] = spec.epochs
    train_set = val_set = None
    data_key = _shards_key(spec.distill, ("train", "val"))
    out: dict[tuple[int, int], dict[str, Any]] = {}
    for kv, adv in CONFIGS:
        if spec.students is not None and name_of(kv, adv) not in spec.students:
            continue
        tcfg = dataclasses.replace(base, **over, k_var=float(kv), i_adv=adv,
                                   out_dir=str(spec.runs / name_of(kv, adv))).validate()
        run_dir = Path(tcfg.out_dir)
        settings = {k: v for k, v in dataclasses.asdict(tcfg).items() if k not in ("out_dir", "data", "threads", "device")}
        _check_run_inputs(run_dir, {"data": data_key, "train": settings, "model": mcfg.to_dict()}, log)
        if (run_dir / "summary.json").exists():
            summary = load_json(run_dir / "summary.json")
            log(f"table2: {name_of(kv, adv)} already trained (best epoch {summary['best_epoch'] + 1})")
        else:
            if train_set is None:
                train_set, val_set = load_split(spec.distill, "train"), load_split(spec.distill, "val")
            log(f"table2: training {name_of(kv, adv)} ({tcfg.epochs} epochs of "
                f"{min(tcfg.samples_per_epoch or len(train_set), len(train_set))} examples)")
            summary = train(mcfg, tcfg, resume=(run_dir / "last.pt").exists(), train_set=train_set,
                            val_set=val_set, progress=spec.progress)
        rows = read_metrics(run_dir)
        out[(kv, adv)] = {**summary, "train_s": sum(r["seconds"] for r in rows), "epochs_run": len(rows),
                          "tcfg": dataclasses.asdict(tcfg), "mcfg": mcfg}
    return out


EXPORT_FILE = "student.safetensors"
"""The exported best checkpoint of a Table II run, in its folder."""


def export_all(spec: Table2Spec, trained: dict[tuple[int, int], dict[str, Any]], manifest_path: Path,
               log: Log) -> dict[tuple[int, int], Path]:
    """Exports every trained configuration's best checkpoint to ``<run>/student.safetensors``
    (trained = true, provenance: the distillation set, its manifest and teacher sha256, the
    configuration, its training settings, best epoch and validation ADE, the sha256 of the
    ``best.pt`` it came from, the commit); an export whose recorded ``best.pt`` sha256 is still
    the run's is kept. Returns the file of each configuration."""
    from nudge_train import paths
    from nudge_train.jsonio import load_json
    from nudge_train.provenance import git_commit, sha256_file
    from nudge_train.training.export import export_generator, read_weights
    from nudge_train.training.loop import load_best

    out: dict[tuple[int, int], Path] = {}
    for (kv, adv), info in trained.items():
        run_dir = spec.runs / name_of(kv, adv)
        path = run_dir / EXPORT_FILE
        best_sha = file_sha(run_dir / "best.pt")
        try:
            current = path.is_file() and read_weights(path).provenance.get("best_pt_sha256") == best_sha
        except ValueError:
            current = False
        if not current:
            prov = {
                "data": paths.repo_relative(spec.distill),
                "distill_manifest_sha256": sha256_file(manifest_path),
                "teacher_sha256": load_json(manifest_path)["teacher"]["sha256"],
                "split": "distillation train (selected on distillation val)",
                "config": f"Table II (k_var, I_adv) = ({kv}, {adv}), base {spec.base_config.name}",
                "train": {k: (paths.repo_relative(Path(v)) if k in ("data", "out_dir") else v)
                          for k, v in info["tcfg"].items()},
                "best_epoch": info["best_epoch"],
                "best_val_ade": info["best_val_ade"],
                "best_pt_sha256": best_sha,
                "commit": git_commit(),
                "hardware": f"{spec.threads} CPU thread(s)",
            }
            export_generator(load_best(run_dir, info["mcfg"]), info["mcfg"], path, trained=True, provenance=prov)
            log(f"table2: exported {name_of(kv, adv)} to {path}")
        out[(kv, adv)] = path
    return out


def evaluate_all(spec: Table2Spec, trained: dict[tuple[int, int], dict[str, Any]], real_root: Path,
                 manifest: dict, log: Log) -> dict[tuple[int, int], dict[str, Any]]:
    """The once-on-test metrics of every configuration (cached per configuration, keyed by the
    weights, the sha256 of every test shard the distillation ``manifest`` lists and the real
    test set's manifest)."""
    import numpy as np
    import torch

    from nudge_train.data.loader import load_split
    from nudge_train.training.evaluate import evaluate_generator
    from nudge_train.training.loop import load_best

    torch.set_num_threads(spec.threads)
    real_manifest = real_root / "manifest.json"
    test_shards = [e["sha256"] for e in manifest["splits"]["test"]["shards"]]
    dtest = real = None
    out: dict[tuple[int, int], dict[str, Any]] = {}
    for (kv, adv), info in trained.items():
        run_dir = spec.runs / name_of(kv, adv)
        inputs = {"best": file_sha(run_dir / "best.pt"), "distill_test": test_shards, "real": file_sha(real_manifest),
                  "max_real": spec.max_real}
        key = sha256(json.dumps(inputs, sort_keys=True).encode())
        path = spec.cache / "table2" / f"{name_of(kv, adv)}-test.json"
        payload = load_cached(path, key, log)
        if payload is None:
            if dtest is None:
                dtest = load_split(spec.distill, "test")
                real = load_split(real_root, "test", spec.max_real)
            assert real is not None
            gen = load_best(run_dir, info["mcfg"])
            payload = {}
            subsets = {"fidelity_all": (dtest, None),
                       "fidelity_interactive": (dtest, np.flatnonzero(dtest.interactive.astype(bool))),
                       "real_all": (real, None),
                       "real_interactive": (real, np.flatnonzero(real.interactive.astype(bool)))}
            for label, (data, subset) in subsets.items():
                if subset is not None and subset.size == 0:
                    payload[label] = None
                    continue
                m = evaluate_generator(gen, data, mode="decoder", subset=subset)
                payload[label] = dataclasses.asdict(m)
            write_cached(path, key, payload)
        out[(kv, adv)] = payload
    return out


def table_markdown(trained: dict[tuple[int, int], dict[str, Any]], tested: dict[tuple[int, int], dict[str, Any]],
                   manifest: dict) -> str:
    """Markdown: the five configurations, validation ADE, test ADE / FDE on every subset, the
    paper's values beside; the choice on validation."""
    def cell(d: dict | None, key: str) -> str:
        return "–" if d is None or not math.isfinite(d[key]) else f"{d[key]:.3f}"

    chosen = min(trained, key=lambda k: trained[k]["best_val_ade"])
    lines = ["| k_var | I_adv | val ADE vs teacher | vs teacher ADE@1.8s | FDE@1.8s | vs teacher, lane-change scenes "
             "ADE | FDE | real test ADE | FDE | real interactive ADE | FDE | paper ADE | paper FDE | epochs "
             "| training (s) |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for kv, adv in CONFIGS:
        t, e = trained[(kv, adv)], tested[(kv, adv)]
        pa, pf = PAPER_TABLE_II[(kv, adv)]
        mark = " (chosen)" if (kv, adv) == chosen else ""
        paper_mark = " (paper's choice)" if (kv, adv) == PAPER_CHOICE else ""
        lines.append(f"| {kv}{mark} | {adv} | {t['best_val_ade']:.4f} | {cell(e['fidelity_all'], 'ade6')} "
                     f"| {cell(e['fidelity_all'], 'fde6')} | {cell(e['fidelity_interactive'], 'ade6')} "
                     f"| {cell(e['fidelity_interactive'], 'fde6')} | {cell(e['real_all'], 'ade6')} "
                     f"| {cell(e['real_all'], 'fde6')} | {cell(e['real_interactive'], 'ade6')} "
                     f"| {cell(e['real_interactive'], 'fde6')} | {pa}{paper_mark} | {pf} | {t['epochs_run']} "
                     f"| {t['train_s']:.0f} |")
    splits = manifest.get("splits", {})
    counts = ", ".join(f"{s} {splits[s]['examples']}" for s in ("train", "val", "test") if s in splits)
    first = trained[CONFIGS[0]]["tcfg"]
    budget = (f"one budget for all five: {first['epochs']} epochs of {first['samples_per_epoch'] or 'all'} examples, "
              f"batch {first['batch_size']}, lr {first['lr']:g} ({first['lr_schedule']}), validation on "
              f"{first['max_val_windows'] or 'all'} validation examples")
    return "\n".join([
        f"Distillation set: {counts} examples (teacher sha256 `{manifest['teacher']['sha256'][:16]}…`); {budget}. "
        f"Chosen on validation: **k_var = {chosen[0]}, I_adv = {chosen[1]}**.",
        "",
        *lines,
    ])


def run(spec: Table2Spec, real_root: Path, log: Log) -> dict[str, Any]:
    """The whole stage; returns ``{"markdown", "manifest", "trained", "tested", "exported"}``
    (``markdown`` ``None`` and ``tested`` / ``exported`` empty when ``spec.students`` leaves a
    configuration out)."""
    manifest = generate_set(spec, log)
    incomplete = [s for s, d in manifest["splits"].items() if not d.get("complete")]
    if incomplete:
        raise RuntimeError(f"{spec.distill}: splits {incomplete} are incomplete after generation")
    trained = train_all(spec, log)
    if len(trained) < len(CONFIGS):
        log(f"table2: trained {sorted(name_of(*k) for k in trained)}; the table needs all {len(CONFIGS)} "
            "configurations: run the stage again without a subset of students")
        return {"markdown": None, "manifest": manifest, "trained": trained, "tested": {}, "exported": {}}
    exported = export_all(spec, trained, spec.distill / "manifest.json", log)
    tested = evaluate_all(spec, trained, real_root, manifest, log)
    return {"markdown": table_markdown(trained, tested, manifest), "manifest": manifest, "trained": trained,
            "tested": tested, "exported": exported}
