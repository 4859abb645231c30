"""The planner benches as a markdown table, from criterion's saved estimates.

Run after ``cargo bench --bench planner`` (``make bench-planner`` does both): reads
``target/criterion/planner/{step,z_update}_<predictor>/<N>/new/estimates.json`` (criterion's
directory names for the ids ``planner/step/<predictor>/<N>`` and ``planner/z_update/<predictor>/<N>``)
and prints medians (ms) per N with the teacher / student Z-update ratio.

    .venv/bin/python python/train/scripts/planner_bench_table.py [--markdown docs/results/planner.md]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
PREDICTORS = ("teacher", "student", "constant_velocity")
NS = (2, 4, 8, 16)


def medians(root: Path) -> dict[tuple[str, str, int], float]:
    """Median (ms) of every planner bench found under ``root`` (target/criterion/planner)."""
    out = {}
    for kind in ("step", "z_update"):
        for pred in PREDICTORS:
            for n in NS:
                path = root / f"{kind}_{pred}" / str(n) / "new" / "estimates.json"
                if path.exists():
                    out[(kind, pred, n)] = json.loads(path.read_text())["median"]["point_estimate"] / 1e6
    return out


def table(rows: dict[tuple[str, str, int], float]) -> str:
    """Markdown: one row per N."""
    nan = float("nan")
    lines = [
        "| N | step teacher (ms) | step student (ms) | step CV (ms) | Z-update teacher (ms) | Z-update student (ms) "
        "| Z-update CV (ms) | Z-update teacher / student | step teacher / student |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for n in NS:
        r = {(k, p): rows.get((k, p, n), nan) for k in ("step", "z_update") for p in PREDICTORS}
        lines.append(
            f"| {n} | {r['step', 'teacher']:.2f} | {r['step', 'student']:.2f} | {r['step', 'constant_velocity']:.2f} "
            f"| {r['z_update', 'teacher']:.3f} | {r['z_update', 'student']:.4f} | {r['z_update', 'constant_velocity']:.4f} "
            f"| {r['z_update', 'teacher'] / r['z_update', 'student']:.1f} | {r['step', 'teacher'] / r['step', 'student']:.1f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--criterion", type=Path, default=REPO / "target" / "criterion" / "planner")
    ap.add_argument("--markdown", type=Path, default=None, help="also write the table here")
    args = ap.parse_args(argv)
    rows = medians(args.criterion)
    if not rows:
        print(f"error: no planner bench results under {args.criterion} (run `make bench-planner`)", file=sys.stderr)
        return 2
    text = table(rows)
    print(text)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
