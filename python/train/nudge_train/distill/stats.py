"""Statistics of a generated distillation set (for docs/distill.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nudge_train.jsonio import load_json


def describe(out: Path, manifest: dict | None = None) -> dict:
    """Examples, contexts, runs per split, agents-per-example histogram, interactive share
    (examples and scenes), disk size and the last run's throughput."""
    if manifest is None:
        manifest = load_json(out / "manifest.json")
    res: dict = {"splits": {}, "disk_bytes": 0}
    for split, s in manifest["splits"].items():
        shards = s["shards"]
        size = sum((out / e["file"]).stat().st_size for e in shards if (out / e["file"]).exists())
        hist = np.asarray(s.get("agents_hist") or [0], dtype=np.int64)
        ex = int(s["examples"])
        nz = np.flatnonzero(hist)
        res["splits"][split] = {
            "examples": ex,
            "contexts": int(s["contexts"]),
            "shards": f"{len(shards)}/{s['shards_planned']}",
            "scenes_done": sum(e["scenes"] for e in shards),
            "runs": sum(e["runs"] for e in shards),
            "failed_runs": sum(e["failed_runs"] for e in shards),
            "interactive_example_share": (s["interactive_examples"] / ex) if ex else 0.0,
            "interactive_scene_share": s["interactive_scenes"] / max(sum(e["scenes"] for e in shards), 1),
            "agents_per_example": {int(k): int(hist[k]) for k in nz},
            "agents_mean": float((hist * np.arange(len(hist))).sum() / max(hist.sum(), 1)),
            "bytes": size,
        }
        res["disk_bytes"] += size
    if "last_run" in manifest:
        res["last_run"] = manifest["last_run"]
    runs = manifest.get("generation_runs", [])
    if runs:
        ex, wall = sum(r["examples"] for r in runs), sum(r["wall_s"] for r in runs)
        res["generation"] = {"examples": ex, "wall_s": wall, "examples_per_s": ex / wall if wall else 0.0}
    return res


def agents_histogram_table(hist: dict[int, int], bins: tuple[int, ...] = (2, 5, 10, 15, 20, 30, 48)) -> str:
    """A markdown row set: agents-per-example histogram in coarse bins."""
    rows = []
    for lo, hi in zip(bins[:-1], bins[1:]):
        n = sum(v for k, v in hist.items() if lo <= k < hi)
        rows.append(f"| {lo}-{hi - 1} | {n} |")
    return "\n".join(rows)


def markdown(res: dict) -> str:
    """The statistics as markdown tables (for docs/distill.md)."""
    lines = ["| split | scenes done | runs (failed) | contexts | examples | interactive scenes | "
             "examples from interactive scenes | mean agents / example | disk (MB) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for split, s in res["splits"].items():
        lines.append(f"| {split} | {s['scenes_done']} | {s['runs']} ({s['failed_runs']}) | {s['contexts']} | "
                     f"{s['examples']} | {100 * s['interactive_scene_share']:.0f} % | "
                     f"{100 * s['interactive_example_share']:.0f} % | {s['agents_mean']:.1f} | {s['bytes'] / 1e6:.1f} |")
    lines += ["", "Agents per example (ego included), all splits:", "", "| agents | examples |", "|---|---|"]
    total: dict[int, int] = {}
    for s in res["splits"].values():
        for k, v in s["agents_per_example"].items():
            total[int(k)] = total.get(int(k), 0) + v
    lines.append(agents_histogram_table(total))
    return "\n".join(lines)

