"""The planner benches as a markdown table, from criterion's saved estimates.

Run after ``cargo bench --bench planner`` (``make bench-planner`` does both): reads
``target/criterion/planner/{step,z_update}_<predictor>/<N>/new/estimates.json`` (criterion's
directory names for the ids ``planner/step/<predictor>/<N>`` and ``planner/z_update/<predictor>/<N>``)
and prints medians (ms) per N with the teacher / student Z-update ratio.

    nudge-train bench planner [--markdown docs/results/planner.md]
"""

from __future__ import annotations

import sys
from pathlib import Path

from nudge_train.experiments.criterion import median_ms

PREDICTORS = ("teacher", "student", "constant_velocity")
NS = (2, 4, 8, 16)


def medians(root: Path) -> dict[tuple[str, str, int], float]:
    """Median (ms) of every planner bench found under ``root`` (target/criterion/planner)."""
    out = {}
    for kind in ("step", "z_update"):
        for pred in PREDICTORS:
            for n in NS:
                ms = median_ms(root, f"{kind}_{pred}", str(n))
                if ms is not None:
                    out[(kind, pred, n)] = ms
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


def run(*, criterion: Path, markdown: Path | None) -> int:
    """``nudge-train bench planner``: prints the table of the planner benches under ``criterion``
    (``target/criterion/planner``) and writes it to ``markdown`` when given. Returns the exit
    status (2 when no planner bench has been run)."""
    rows = medians(criterion)
    if not rows:
        print(f"error: no planner bench results under {criterion} (run `make bench-planner`)", file=sys.stderr)
        return 2
    text = table(rows)
    print(text)
    if markdown:
        markdown.parent.mkdir(parents=True, exist_ok=True)
        markdown.write_text(text + "\n")
    return 0
