"""Helpers shared by the experiment scripts: run logs, training curves and provenance."""

from __future__ import annotations

import hashlib
import json
import subprocess
from pathlib import Path
from typing import Any

__all__ = ["REPO", "git_commit", "plot_curves", "read_metrics", "repo_relative", "sha256_file"]

REPO = Path(__file__).resolve().parents[3]


def read_metrics(out: Path) -> list[dict[str, Any]]:
    """Every epoch row of a training run's ``metrics.jsonl`` (see :func:`nudge_train.training.train`)."""
    return [json.loads(line) for line in (Path(out) / "metrics.jsonl").read_text().splitlines() if line]


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def git_commit() -> str:
    """The repository's HEAD commit, or ``"unknown"`` outside a git checkout."""
    try:
        return subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def repo_relative(path: Path) -> str:
    """``path`` relative to the repository when inside it (provenance must not name a machine)."""
    full = Path(path).resolve()
    return str(full.relative_to(REPO)) if full.is_relative_to(REPO) else str(path)


def plot_curves(runs: dict[str, Path], path: Path, title: str, loss_label: str, val_label: str) -> None:
    """Train loss and validation metric per epoch of each run (log scales) as a PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name, out in runs.items():
        rows = read_metrics(out)
        ep = [r["epoch"] + 1 for r in rows]
        axes[0].plot(ep, [r["loss_var"] for r in rows], label=name)
        axes[1].plot(ep, [r["val_ade"] for r in rows], label=name)
    axes[0].set(xlabel="epoch", ylabel=loss_label, yscale="log")
    axes[1].set(xlabel="epoch", ylabel=val_label, yscale="log")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
