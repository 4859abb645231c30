"""Draws closed-loop runs written by `nudge simulate --out DIR` as one PNG.

For each of the first ``--max-runs`` runs: the road (lane boundaries from the scenario file), the
other vehicles' observed history and logged future (grey), and the ego's executed path (coloured,
one dot per 0.3 s planning step; red crosses where a step reported a collision).

    python python/train/scripts/plot_runs.py out/demo --scenes assets/scenes --png out/demo/runs.png
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from safetensors.numpy import load_file  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("records_dir", type=Path, help="directory with records.json")
    ap.add_argument("--scenes", type=Path, default=Path("assets/scenes"))
    ap.add_argument("--png", type=Path, default=None, help="output (default RECORDS_DIR/runs.png)")
    ap.add_argument("--max-runs", type=int, default=6)
    args = ap.parse_args(argv)
    records_path = args.records_dir / "records.json"
    if not records_path.exists():
        print(f"error: {records_path} not found (run `nudge simulate --out {args.records_dir}` first)", file=sys.stderr)
        return 2
    runs = json.loads(records_path.read_text())[: args.max_runs]
    if not runs:
        print(f"error: {records_path} holds no runs", file=sys.stderr)
        return 2
    cols = 2 if len(runs) > 1 else 1
    rows = math.ceil(len(runs) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(7.5 * cols, 2.6 * rows), squeeze=False)
    for ax, run in zip(axes.flat, runs, strict=False):
        scene = load_file(str(args.scenes / f"{run['scenario']}.safetensors"))
        hist, fut, valid = scene["history"], scene["future"], scene["future_valid"].astype(bool)
        steps = run["steps"]
        ego = np.array([s["ego"] for s in steps]) if steps else np.zeros((0, 4))
        x_lo = hist[:, :, 0].min() - 5
        x_hi = max(float(ego[:, 0].max()) if len(ego) else 0.0, float(hist[0, -1, 0])) + 20
        for yb in scene["lane_bounds"]:
            ax.axhline(yb, color="0.6", lw=0.8, ls="--")
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
            f"{'success' if run['success'] else 'no success'} in {len(steps)} steps",
            fontsize=8,
        )
        ax.set_xlabel("x along road (m)")
        ax.set_ylabel("y (m)")
        ax.legend(fontsize=7, loc="upper left")
    for ax in list(axes.flat)[len(runs) :]:
        ax.axis("off")
    fig.tight_layout()
    png = args.png or args.records_dir / "runs.png"
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
