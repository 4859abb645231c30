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

    nudge-train bench inference [--markdown docs/results/inference.md]
"""

from __future__ import annotations

import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors import safe_open

from nudge_train import paths
from nudge_train.constants import BENCH_NS
from nudge_train.experiments.criterion import median_ms
from nudge_train.models.interactive import student_interactive, teacher_interactive
from nudge_train.models.networks import TrajectoryGenerator
from nudge_train.training.export import load_generator

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


def run(
    *,
    repo_root: Path | None,
    criterion_dir: Path | None,
    models: list[str],
    ns: list[int],
    batch32: bool,
    warmup: int,
    repeats: int,
    min_seconds: float,
    markdown: Path | None,
) -> int:
    """``nudge-train bench inference``: times ``models`` at the agent counts ``ns`` (among
    :data:`~nudge_train.constants.BENCH_NS`), prints the table beside criterion's medians from
    ``criterion_dir`` and writes it to ``markdown`` when given. Weights, bench scenes and
    criterion results are read below ``repo_root`` when given, else from :mod:`nudge_train.paths`.

    Raises:
        ValueError: a timing parameter out of range or an agent count without a bench scene.
    """
    if warmup < 0 or repeats < 1 or min_seconds < 0:
        raise ValueError("--warmup must be >= 0, --repeats >= 1, --min-seconds >= 0")
    bad = [n for n in ns if n not in BENCH_NS]
    if bad:
        raise ValueError(f"--ns: {bad} not in the bench scenes {BENCH_NS}")

    if repo_root is not None:
        root = repo_root.resolve()
        models_dir, criterion_dir = root / "assets" / "models", criterion_dir or root / "target" / "criterion"
    else:
        root = paths.repo()
        models_dir, criterion_dir = paths.assets() / "models", criterion_dir or paths.criterion()
    scenes_path = root / paths.BENCH_SCENES
    if not scenes_path.is_file():
        print(f"error: {scenes_path} not found (run nudge-train goldens)", file=sys.stderr)
        return 1
    torch.set_num_threads(1)
    group = "predictor_batch32" if batch32 else "predictor"
    count = 32 if batch32 else 1
    functions: dict[str, Predict] = {"teacher": teacher_interactive, "student": student_interactive}

    rows: list[Row] = []
    with safe_open(str(scenes_path), "pt") as scenes:
        for model in models:
            weights = models_dir / f"{model}.safetensors"
            try:
                gen = load_generator(weights, "cpu")
            except (FileNotFoundError, ValueError) as err:
                print(f"error: {err}", file=sys.stderr)
                return 1
            fn = functions[model]
            for n in ns:
                history = scenes.get_tensor(f"n{n}.history")
                cands = scenes.get_tensor(f"n{n}.candidates")[:count].contiguous()
                ms = time_median_ms(lambda: fn(gen, history, cands), warmup, repeats, min_seconds)
                rows.append(Row(model, n, ms, median_ms(criterion_dir, group, model, str(n))))
                print(f"  {model} N={n}: {ms:.3f} ms", file=sys.stderr)

    header = (
        f"PyTorch {torch.__version__} (1 thread, inference_mode, median of ≥{repeats} calls after "
        f"{warmup} warm-up) vs Rust criterion group `{group}` medians; {count} candidate(s) per call; "
        f"same weights (assets/models) and scenes ({paths.BENCH_SCENES}); CPU: {cpu_name()}."
    )
    print(header)
    print(table_text(rows))
    if markdown is not None:
        markdown.parent.mkdir(parents=True, exist_ok=True)
        markdown.write_text(table_markdown(rows, header))
        print(f"wrote {markdown}")
    return 0
