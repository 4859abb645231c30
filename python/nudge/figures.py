"""Figures of closed-loop runs: :func:`plot_runs` draws runs written by ``nudge simulate --out
DIR`` over their scenes as one PNG. Needs matplotlib (the ``figures`` extra:
``pip install "nudge-planner[figures]"``); no torch. The command line::

    nudge-figures runs out/demo --scenes assets/scenes --png out/demo/runs.png

For each of the first ``max_runs`` runs: the road (lane boundaries from the scenario file), the
other vehicles' observed history and logged future (grey), and the ego's executed path
(coloured, one dot per 0.3 s planning step; red crosses where a step reported a collision); on
scenes with lane extents, where a lane really has not begun or has ended (shaded, a red bar at
the line). ``nudge-train figures runs`` is this command.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["main", "plot_runs"]


def _pyplot() -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (imported on first use)."""
    try:
        import matplotlib
    except ImportError as e:
        raise ImportError('nudge.figures needs matplotlib: pip install "nudge-planner[figures]"') from e
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"duplicate key {k!r}")
        out[k] = v
    return out


def plot_runs(*, records_dir: Path, scenes: Path | None = None, png: Path | None = None, max_runs: int = 6) -> int:
    """The first ``max_runs`` runs of ``records_dir/records.json`` over their scenes (read from
    the folder ``scenes``, default the shipped scenes) as one PNG at ``png`` (default
    ``records_dir/runs.png``). Returns the exit status (2 when there is nothing to draw or the
    records cannot be read, with the reason on stderr)."""
    import nudge

    records_dir = Path(records_dir)
    scenes = Path(scenes) if scenes is not None else nudge.assets_dir() / "scenes"
    records_path = records_dir / "records.json"
    if not records_path.exists():
        print(f"error: {records_path} not found (run `nudge simulate --out {records_dir}` first)", file=sys.stderr)
        return 2
    try:
        runs = json.loads(records_path.read_bytes(), object_pairs_hook=_no_duplicates)[:max_runs]
    except (OSError, ValueError) as e:
        print(f"error: {records_path}: {e}", file=sys.stderr)
        return 2
    if not runs:
        print(f"error: {records_path} holds no runs", file=sys.stderr)
        return 2
    plt = _pyplot()
    cols = 2 if len(runs) > 1 else 1
    rows = math.ceil(len(runs) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(7.5 * cols, 2.6 * rows), squeeze=False)
    for ax, run in zip(axes.flat, runs, strict=False):
        scene = nudge.Scenario.load(scenes / f"{run['scenario']}.safetensors")
        hist, fut, valid = scene.history, scene.future, scene.future_valid.astype(bool)
        steps = run["steps"]
        ego = np.array([s["ego"] for s in steps]) if steps else np.zeros((0, 4))
        x_lo = hist[:, :, 0].min() - 5
        x_hi = max(float(ego[:, 0].max()) if len(ego) else 0.0, float(hist[0, -1, 0])) + 20
        for yb in scene.lane_bounds:
            ax.axhline(yb, color="0.6", lw=0.8, ls="--")
        x_hi = max(x_hi, _draw_lane_extents(ax, scene))
        ax.axhline(run["y_target"], color="tab:green", lw=0.8, alpha=0.5)
        for a in range(1, hist.shape[0]):
            ax.plot(hist[a, :, 0], hist[a, :, 1], color="0.5", lw=1)
            f = fut[a][valid[a]][: len(steps)]
            ax.plot(f[:, 0], f[:, 1], color="0.8", lw=1)
        ax.plot(hist[0, :, 0], hist[0, :, 1], color="tab:blue", lw=1.5)
        if len(ego):
            ax.plot(ego[:, 0], ego[:, 1], "o-", color="tab:orange", ms=3, lw=1.5, label="ego (executed)")
            hit = np.array([s["collision"] for s in steps])
            if hit.any():
                ax.plot(ego[hit, 0], ego[hit, 1], "x", color="red", ms=8, label="collision")
        ax.set_xlim(x_lo, x_hi)
        ax.set_title(
            f"{run['scenario']}  {run['predictor']}  target lane {run['target_lane']}  "
            f"{run.get('outcome') or ('success' if run['success'] else 'no success')} in {len(steps)} steps",
            fontsize=8,
        )
        ax.set_xlabel("x along road (m)")
        ax.set_ylabel("y (m)")
        ax.legend(fontsize=7, loc="upper left")
    for ax in list(axes.flat)[len(runs) :]:
        ax.axis("off")
    fig.tight_layout()
    png = Path(png) if png is not None else records_dir / "runs.png"
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    print(f"wrote {png}")
    return 0


def _draw_lane_extents(ax: Any, scene: Any) -> float:
    """Shades where a lane of ``scene`` ("nudge.scenario/2") has really not begun or has ended,
    a red bar at its begin / end; returns the x (m) the plot should reach to show the ego lane's
    end (-inf when there is none)."""
    ext, real = scene.lane_extents, scene.lane_extent_real
    if ext is None:
        return -math.inf
    b = scene.lane_bounds
    for k in range(len(ext)):
        for side, (x0, x1) in ((0, (ext[k, 0] - 1e4, ext[k, 0])), (1, (ext[k, 1], ext[k, 1] + 1e4))):
            if real[k, side]:
                ax.fill_between([x0, x1], b[k], b[k + 1], color="0.9", lw=0)
                ax.plot([ext[k, side]] * 2, [b[k], b[k + 1]], color="tab:red", lw=2)
    e = scene.ego_lane
    return float(ext[e, 1]) + 10.0 if real[e, 1] else -math.inf


def main(argv: list[str] | None = None) -> int:
    """``nudge-figures runs RECORDS_DIR [--scenes DIR] [--png FILE] [--max-runs N]``."""
    parser = argparse.ArgumentParser(prog="nudge-figures", description="figures of nudge's closed-loop runs")
    sub = parser.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("runs", help="draw closed-loop runs written by `nudge simulate --out DIR` as one PNG")
    r.add_argument("records_dir", type=Path, help="directory with records.json")
    r.add_argument("--scenes", type=Path, default=None, help="folder of the runs' scenario files (default: shipped)")
    r.add_argument("--png", type=Path, default=None, help="output (default RECORDS_DIR/runs.png)")
    r.add_argument("--max-runs", type=int, default=6, help="runs drawn (the first ones)")
    a = parser.parse_args(argv)
    try:
        return plot_runs(records_dir=a.records_dir, scenes=a.scenes, png=a.png, max_runs=a.max_runs)
    except ImportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
