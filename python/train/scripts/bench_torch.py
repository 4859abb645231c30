#!/usr/bin/env python3
"""Times the PyTorch reference predictors on the same weights and inputs as the Rust benchmark
and prints them next to the Rust (criterion) medians.

Weights: assets/models/{teacher,student}.safetensors. Inputs: crates/predictor/benches/data/scenes.safetensors
(``n{N}.history`` [N, 8, 2], ``n{N}.candidates`` [32, 6, 2]). One timed call is a full prediction
from the history: the teacher's whole 6-call recursion, or the student's encoder + pooling +
6-step decoder, for ONE candidate (``--batch32``: all 32 candidates in one call, compared with the
criterion group ``predictor_batch32``). PyTorch runs single-threaded in inference mode; each
configuration gets a warm-up, then many individually timed repeats, and the median is reported.

Rust medians are read from target/criterion/<group>/<model>/<N>/new/estimates.json
(``median.point_estimate``, ns) when present; run ``cargo bench --bench predictor`` first.

Usage (from the repository root):
    .venv/bin/python python/train/scripts/bench_torch.py [--markdown docs/bench_torch.md]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors import safe_open

try:
    import nudge_train  # noqa: F401
except ModuleNotFoundError:  # running from a checkout without an install of python/train
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nudge_train.export import load_generator
from nudge_train.interactive import student_interactive, teacher_interactive
from nudge_train.models import TrajectoryGenerator

NS = (2, 4, 8, 16, 32)
MODELS = ("teacher", "student")
Predict = Callable[[TrajectoryGenerator, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class Row:
    """One line of the result table (times in milliseconds)."""

    model: str
    n: int
    torch_ms: float
    rust_ms: float | None

    @property
    def ratio(self) -> float | None:
        """PyTorch time / Rust time (> 1: Rust is faster)."""
        return None if self.rust_ms is None or self.rust_ms <= 0 else self.torch_ms / self.rust_ms


def time_median_ms(fn: Callable[[], object], warmup: int, repeats: int, min_seconds: float) -> float:
    """Median wall time of ``fn()`` in ms over at least ``repeats`` calls and ``min_seconds``."""
    for _ in range(warmup):
        fn()
    samples: list[int] = []
    deadline = time.perf_counter() + min_seconds
    while len(samples) < repeats or time.perf_counter() < deadline:
        start = time.perf_counter_ns()
        fn()
        samples.append(time.perf_counter_ns() - start)
        if len(samples) >= 100 * repeats:
            break
    return statistics.median(samples) / 1e6


def rust_median_ms(criterion_dir: Path, group: str, model: str, n: int) -> float | None:
    """Criterion's median for ``group/model/n`` in ms, or None if that bench has not been run."""
    path = criterion_dir / group / model / str(n) / "new" / "estimates.json"
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        return float(data["median"]["point_estimate"]) / 1e6
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        print(f"warning: cannot read {path}: {err}", file=sys.stderr)
        return None


def _fmt(value: float | None, digits: int = 3) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def table_text(rows: list[Row]) -> str:
    """Fixed-width table for the terminal."""
    lines = [f"{'model':<8} {'N':>3} {'PyTorch ms':>11} {'Rust ms':>9} {'ratio':>8}"]
    for r in rows:
        lines.append(f"{r.model:<8} {r.n:>3} {_fmt(r.torch_ms):>11} {_fmt(r.rust_ms, 4):>9} {_fmt(r.ratio, 1):>8}")
    return "\n".join(lines)


def table_markdown(rows: list[Row], header: str) -> str:
    """Markdown table with a one-paragraph description of the setting."""
    lines = [header, "", "| model | N | PyTorch ms | Rust ms | ratio (PyTorch/Rust) |", "|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r.model} | {r.n} | {_fmt(r.torch_ms)} | {_fmt(r.rust_ms, 4)} | {_fmt(r.ratio, 1)} |")
    return "\n".join(lines) + "\n"


def cpu_name() -> str:
    """CPU model from /proc/cpuinfo where available."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or "unknown CPU"


def main(argv: list[str] | None = None) -> int:
    """CLI entry point; returns the exit status."""
    root_default = Path(__file__).resolve().parents[3]
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repo-root", type=Path, default=root_default, help="repository root")
    parser.add_argument("--criterion-dir", type=Path, default=None, help="default: <repo-root>/target/criterion")
    parser.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    parser.add_argument("--ns", nargs="+", type=int, default=list(NS), help=f"agent counts, among {NS}")
    parser.add_argument("--batch32", action="store_true", help="32 candidates per call (group predictor_batch32)")
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=50, help="minimum timed calls per configuration")
    parser.add_argument("--min-seconds", type=float, default=1.0, help="minimum timing per configuration")
    parser.add_argument("--markdown", type=Path, default=None, help="also write the table as markdown here")
    args = parser.parse_args(argv)
    if args.warmup < 0 or args.repeats < 1 or args.min_seconds < 0:
        parser.error("--warmup must be >= 0, --repeats >= 1, --min-seconds >= 0")
    bad = [n for n in args.ns if n not in NS]
    if bad:
        parser.error(f"--ns: {bad} not in the bench scenes {NS}")

    root: Path = args.repo_root.resolve()
    criterion_dir: Path = args.criterion_dir or root / "target" / "criterion"
    scenes_path = root / "crates" / "predictor" / "benches" / "data" / "scenes.safetensors"
    if not scenes_path.is_file():
        print(f"error: {scenes_path} not found (run python/train/scripts/make_goldens.py)", file=sys.stderr)
        return 1
    torch.set_num_threads(1)
    group = "predictor_batch32" if args.batch32 else "predictor"
    count = 32 if args.batch32 else 1
    functions: dict[str, Predict] = {"teacher": teacher_interactive, "student": student_interactive}

    rows: list[Row] = []
    with safe_open(str(scenes_path), "pt") as scenes:
        for model in args.models:
            weights = root / "assets" / "models" / f"{model}.safetensors"
            try:
                gen = load_generator(weights, "cpu")
            except (FileNotFoundError, ValueError) as err:
                print(f"error: {err}", file=sys.stderr)
                return 1
            fn = functions[model]
            for n in args.ns:
                history = scenes.get_tensor(f"n{n}.history")
                cands = scenes.get_tensor(f"n{n}.candidates")[:count].contiguous()
                ms = time_median_ms(lambda: fn(gen, history, cands), args.warmup, args.repeats, args.min_seconds)
                rows.append(Row(model, n, ms, rust_median_ms(criterion_dir, group, model, n)))
                print(f"  {model} N={n}: {ms:.3f} ms", file=sys.stderr)

    header = (
        f"PyTorch {torch.__version__} (1 thread, inference_mode, median of ≥{args.repeats} calls after "
        f"{args.warmup} warm-up) vs Rust criterion group `{group}` medians; {count} candidate(s) per call; "
        f"same weights (assets/models) and scenes (crates/predictor/benches/data/scenes.safetensors); CPU: {cpu_name()}."
    )
    print(header)
    print(table_text(rows))
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(table_markdown(rows, header))
        print(f"wrote {args.markdown}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
