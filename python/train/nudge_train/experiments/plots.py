"""Figures: closed-loop runs over their scenes, and training curves.

Imports only numpy, matplotlib (and the ``nudge`` extension to read scenario files), so that
``make demo`` draws its runs in a light environment without torch.

* :func:`plot_runs` draws runs written by ``nudge simulate --out DIR`` as one PNG: the wheel's
  :func:`nudge.figures.plot_runs` (also ``nudge-figures runs``, the ``figures`` extra).

      nudge-train figures runs out/demo --scenes assets/scenes --png out/demo/runs.png

* :func:`plot_curves` draws the training loss and validation metric per epoch of training runs
  (``docs/figures/teacher_curves.png``, ``student_curves.png``; ``nudge-train figures curves``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


from nudge_train.training.log import read_metrics

__all__ = ["plot_curves", "plot_runs"]


def _pyplot() -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_runs(*, records_dir: Path, scenes: Path, png: Path | None, max_runs: int) -> int:
    """``nudge-train figures runs``: :func:`nudge.figures.plot_runs` (the figure ships in the
    wheel, ``nudge-figures runs``)."""
    from nudge.figures import plot_runs as draw

    return draw(records_dir=records_dir, scenes=scenes, png=png, max_runs=max_runs)


def plot_curves(runs: dict[str, Path], path: Path, title: str, loss_label: str, val_label: str) -> None:
    """Train loss and validation metric per epoch of each training run (``name -> out_dir``,
    log scales) as a PNG at ``path``."""
    plt = _pyplot()
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
