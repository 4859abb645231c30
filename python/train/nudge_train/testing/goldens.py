"""Writes the golden files the Rust predictor tests against, the benchmark scenes and (optionally)
the randomly initialised shipped weights. Everything is seeded: rerunning gives identical bytes.

Files (paths relative to the repository root):

* crates/predictor/tests/golden/weights_{teacher,student}_random.safetensors: seeded random generators.
* crates/predictor/tests/golden/cases_{teacher,student}_random.safetensors: for N in {1, 2, 5, 17, 47},
  ``n{N}.history`` [N, 8, 2], ``n{N}.candidates`` [4, 6, 2], ``n{N}.expected`` [4, N−1, 6, 2].
* with ``--trained``: crates/predictor/tests/golden/cases_{teacher,student}_trained.safetensors against
  assets/models/{teacher,student}.safetensors (only for files whose metadata says trained="true"), and
  cases_teacher_trained_h10.safetensors: the trained teacher rolled out recursively over 10 steps (3 s),
  candidates [4, 10, 2], expected [4, N−1, 10, 2], metadata ``horizon`` = "10".
* crates/predictor/benches/data/scenes.safetensors: ``n{N}.history`` [N, 8, 2], ``n{N}.candidates`` [32, 6, 2]
  for N in {2, 4, 8, 16, 32}.
* with ``--ship-random``: assets/models/{teacher,student}.safetensors, random (trained="false").

Expected outputs are computed in float64 from the float32 weights and inputs, then rounded to
float32: they are the exact network output up to one float32 rounding, independent of the BLAS
used, which makes them both stable across machines and the best reference for the Rust f32 code.

``--check`` regenerates into a temporary directory and compares bit-exactly with the committed
files; it exits 1 naming every file that differs.

    nudge-train goldens [--trained] [--ship-random] [--check]
"""

from __future__ import annotations

import copy
import json
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from safetensors import safe_open

from nudge_train.constants import BENCH_NS
from nudge_train.models.config import ModelConfig, student_config, teacher_config
from nudge_train.models.interactive import student_interactive, teacher_interactive
from nudge_train.models.networks import TrajectoryGenerator, build_model
from nudge_train.paths import BENCH_SCENES, GOLDEN_DIR
from nudge_train.testing.synthetic import highway_candidates, highway_history
from nudge_train.training.export import export_generator, load_generator, read_weights, save_safetensors

GENERATOR = "python/train/scripts/make_goldens.py"
"""The ``generator`` label recorded in every file's metadata. It names where this generator lived
when the committed files were made; it is kept so that regenerated files stay byte-identical
(changing it means regenerating every golden file and the Rust tests' references to it)."""
ASSETS_DIR = Path("assets/models")
GOLDEN_NS = (1, 2, 5, 17, 47)
GOLDEN_CANDIDATES = 4
BENCH_CANDIDATES = 32
GOLDEN_SCENE_SEED = 20_261_121
BENCH_SCENE_SEED = 20_261_122
KINDS = ("teacher", "student")
LONG_HORIZON = 10
"""Steps of the long-horizon teacher cases (10 × 0.3 s = 3 s)."""


def config_for(kind: str) -> ModelConfig:
    """The shipped config of ``kind`` (teacher or student)."""
    return teacher_config() if kind == "teacher" else student_config()


def interactive_for(kind: str) -> Callable[[TrajectoryGenerator, torch.Tensor, torch.Tensor], torch.Tensor]:
    """The interactive prediction function of ``kind``."""
    if kind == "teacher":
        return teacher_interactive
    return student_interactive


def expected_output(
    gen: TrajectoryGenerator, history: torch.Tensor, candidates: torch.Tensor, horizon: int | None = None
) -> torch.Tensor:
    """Interactive prediction computed in float64 and rounded once to float32 (a teacher rolled
    out ``horizon`` steps when given, else its ``t_plan``)."""
    gen64 = copy.deepcopy(gen).to(torch.float64)
    h64, c64 = history.to(torch.float64), candidates.to(torch.float64)
    if horizon is not None:
        out = teacher_interactive(gen64, h64, c64, horizon=horizon)
    else:
        out = interactive_for(gen.cfg.kind)(gen64, h64, c64)
    return out.to(torch.float32)


def random_provenance(cfg: ModelConfig) -> dict[str, object]:
    """Provenance of a randomly initialised generator."""
    return {"init": "random", "seed": cfg.seed, "noise_seed": cfg.noise_seed, "generator": GENERATOR}


def write_cases(
    gen: TrajectoryGenerator, path: Path, weights_name: str, seed: int, horizon: int | None = None
) -> None:
    """Golden cases of one generator: N in GOLDEN_NS, GOLDEN_CANDIDATES candidates each, over its
    ``t_plan`` steps, or (a teacher only) rolled out ``horizon`` steps, recorded in the metadata."""
    if horizon is not None and gen.cfg.kind != "teacher":
        raise ValueError(f"horizon: only a teacher rolls out to another horizon, got a {gen.cfg.kind}")
    steps = gen.cfg.t_plan if horizon is None else horizon
    tensors: dict[str, torch.Tensor] = {}
    for n in GOLDEN_NS:
        rng = np.random.default_rng([seed, n])
        history = highway_history(rng, n, gen.cfg.obs_len, gen.cfg.dt)
        candidates = highway_candidates(rng, history[0], GOLDEN_CANDIDATES, steps, gen.cfg.dt)
        h = torch.from_numpy(history)
        c = torch.from_numpy(candidates)
        tensors[f"n{n}.history"] = h
        tensors[f"n{n}.candidates"] = c
        tensors[f"n{n}.expected"] = expected_output(gen, h, c, horizon).contiguous()
    metadata = {
        "weights": weights_name,
        "generator": GENERATOR,
        "kind": gen.cfg.kind,
        "reference_precision": "float64 rounded to float32",
        "scene_seed": str(seed),
    }
    if horizon is not None:
        metadata["horizon"] = str(horizon)
    save_safetensors(tensors, path, metadata)


def write_bench_scenes(path: Path) -> None:
    """Benchmark inputs: one scene per N in BENCH_NS with BENCH_CANDIDATES candidates."""
    cfg = teacher_config()
    tensors: dict[str, torch.Tensor] = {}
    for n in BENCH_NS:
        rng = np.random.default_rng([BENCH_SCENE_SEED, n])
        history = highway_history(rng, n, cfg.obs_len, cfg.dt)
        candidates = highway_candidates(rng, history[0], BENCH_CANDIDATES, cfg.t_plan, cfg.dt)
        tensors[f"n{n}.history"] = torch.from_numpy(history)
        tensors[f"n{n}.candidates"] = torch.from_numpy(candidates)
    metadata = {"generator": GENERATOR, "scene_seed": str(BENCH_SCENE_SEED), "ns": json.dumps(list(BENCH_NS))}
    save_safetensors(tensors, path, metadata)


@dataclass(frozen=True)
class Options:
    """What to generate."""

    trained: bool = False
    ship_random: bool = False


def generate(out_root: Path, src_root: Path, options: Options, log: Callable[[str], None] = print) -> list[Path]:
    """Writes every selected file under ``out_root`` (same relative layout as the repository).

    Trained cases read their weights from ``src_root``/assets/models. Returns the relative paths
    written. Runs single-threaded so results never depend on the thread count.
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    written: list[Path] = []
    try:
        for kind in KINDS:
            cfg = config_for(kind)
            gen, _ = build_model(cfg, "cpu")
            weights_rel = GOLDEN_DIR / f"weights_{kind}_random.safetensors"
            export_generator(gen, cfg, out_root / weights_rel, trained=False, provenance=random_provenance(cfg))
            written.append(weights_rel)
            # Cases use the generator as reloaded from the file: exactly what Rust will load.
            reloaded = load_generator(out_root / weights_rel, "cpu")
            cases_rel = GOLDEN_DIR / f"cases_{kind}_random.safetensors"
            write_cases(reloaded, out_root / cases_rel, weights_rel.name, GOLDEN_SCENE_SEED)
            written.append(cases_rel)
            if options.ship_random:
                asset_rel = ASSETS_DIR / f"{kind}.safetensors"
                shipped = src_root / asset_rel
                if shipped.is_file() and read_weights(shipped).trained:
                    raise ValueError(f"{shipped} holds trained weights; refusing to replace them by random ones")
                export_generator(gen, cfg, out_root / asset_rel, trained=False, provenance=random_provenance(cfg))
                written.append(asset_rel)
            if options.trained:
                asset = src_root / ASSETS_DIR / f"{kind}.safetensors"
                if not asset.is_file():
                    log(f"skip trained cases for {kind}: {asset} not found")
                elif not read_weights(asset).trained:
                    log(f"skip trained cases for {kind}: {asset} has trained=\"false\"")
                else:
                    trained_gen = load_generator(asset, "cpu")
                    if trained_gen.cfg.kind != kind:
                        raise ValueError(f"{asset}: config kind is {trained_gen.cfg.kind!r}, expected {kind!r}")
                    cases_rel = GOLDEN_DIR / f"cases_{kind}_trained.safetensors"
                    write_cases(trained_gen, out_root / cases_rel, (ASSETS_DIR / f"{kind}.safetensors").as_posix(), GOLDEN_SCENE_SEED)
                    written.append(cases_rel)
                    if kind == "teacher":
                        # The same network rolled out over the long horizon (3 s).
                        cases_rel = GOLDEN_DIR / f"cases_teacher_trained_h{LONG_HORIZON}.safetensors"
                        write_cases(trained_gen, out_root / cases_rel, (ASSETS_DIR / "teacher.safetensors").as_posix(),
                                    GOLDEN_SCENE_SEED, horizon=LONG_HORIZON)
                        written.append(cases_rel)
        write_bench_scenes(out_root / BENCH_SCENES)
        written.append(BENCH_SCENES)
    finally:
        torch.set_num_threads(threads)
    return written


def describe_difference(expected: Path, got: Path) -> str:
    """Human-readable reason why two safetensors files differ."""
    if not expected.is_file():
        return "missing from the repository"
    try:
        with safe_open(str(expected), "pt") as a, safe_open(str(got), "pt") as b:
            if a.metadata() != b.metadata():
                return f"metadata differs: committed {a.metadata()} vs regenerated {b.metadata()}"
            if set(a.keys()) != set(b.keys()):
                return f"tensor names differ: {sorted(set(a.keys()) ^ set(b.keys()))}"
            for name in sorted(a.keys()):
                ta, tb = a.get_tensor(name), b.get_tensor(name)
                if ta.shape != tb.shape:
                    return f"{name}: shape {list(ta.shape)} vs {list(tb.shape)}"
                if not torch.equal(ta, tb):
                    diff = (ta.double() - tb.double()).abs().max().item()
                    return f"{name}: values differ (max abs difference {diff:.3g})"
    except Exception as err:  # noqa: BLE001 (any unreadable file is a mismatch to report)
        return f"unreadable: {err}"
    return "bytes differ (header layout)"


def check(repo_root: Path, options: Options, log: Callable[[str], None] = print) -> list[str]:
    """Regenerates into a temporary directory; returns one message per file that differs."""
    problems: list[str] = []
    with tempfile.TemporaryDirectory(prefix="nudge-goldens-") as tmp:
        tmp_root = Path(tmp)
        for rel in generate(tmp_root, repo_root, options, log):
            committed = repo_root / rel
            fresh = tmp_root / rel
            if not committed.is_file() or committed.read_bytes() != fresh.read_bytes():
                problems.append(f"{rel.as_posix()}: {describe_difference(committed, fresh)}")
    return problems


def run(*, repo_root: Path, trained: bool, ship_random: bool, check_only: bool) -> int:
    """``nudge-train goldens``: writes the files below ``repo_root`` (``--trained``,
    ``--ship-random`` add the optional ones), or with ``check_only`` compares a regeneration with
    them. Returns the exit status (1 when a file differs)."""
    options = Options(trained=trained, ship_random=ship_random)
    root = repo_root.resolve()
    if check_only:
        problems = check(root, options)
        if problems:
            print("golden files are out of date (rerun `nudge-train goldens` without --check):", file=sys.stderr)
            for p in problems:
                print(f"  {p}", file=sys.stderr)
            return 1
        print("golden files up to date")
        return 0
    for rel in generate(root, root, options):
        print(f"wrote {rel.as_posix()}")
    return 0
