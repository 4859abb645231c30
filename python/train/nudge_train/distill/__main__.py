"""`python -m nudge_train.distill`: generate the distillation set (see docs/distill.md)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from .config import SIZES, SPLITS, DistillConfig


def parse_size(text: str) -> dict[str, int | None]:
    """A preset name (tiny, small, first, paper, all) or ``train=N,val=N,test=N`` (N or ``all``)."""
    if text in SIZES:
        return dict(SIZES[text])
    out: dict[str, int | None] = dict(SIZES["paper"])
    for part in text.split(","):
        k, sep, v = part.partition("=")
        if not sep or k.strip() not in SPLITS:
            raise argparse.ArgumentTypeError(f"bad size {part!r}: expected a preset {sorted(SIZES)} or split=N")
        out[k.strip()] = None if v.strip() == "all" else int(v)
    return out


def main(argv: list[str] | None = None) -> int:
    d = DistillConfig()
    p = argparse.ArgumentParser(prog="python -m nudge_train.distill", description=__doc__)
    p.add_argument("--out", type=Path, default=d.out)
    p.add_argument("--splits", default=",".join(d.splits), help="comma-separated subset of train,val,test")
    p.add_argument("--size", type=parse_size, default="paper",
                   help="scenes per split: preset (tiny, small, first, paper = ~568k/113k/116k examples, all) "
                        "or train=N,val=N,test=N")
    p.add_argument("--teacher", type=Path, default=d.teacher)
    p.add_argument("--scenes-root", type=Path, default=d.scenes_root)
    p.add_argument("--data-root", type=Path, default=d.data_root)
    p.add_argument("--runs", type=int, default=d.runs, help="closed-loop runs per scene")
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--world", choices=("teacher", "log_replay"), default=d.world)
    p.add_argument("--max-steps", type=int, default=d.max_steps)
    p.add_argument("--scenes-per-shard", type=int, default=d.scenes_per_shard)
    p.add_argument("--threads", type=int, default=None, help="rayon threads (default: all cores)")
    p.add_argument("--ray-address", default=None, help="run shards as Ray tasks on this cluster ('auto', 'ray://...')")
    p.add_argument("--ray-local", action="store_true", help="start a local Ray instance for the shards")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    size = a.size if isinstance(a.size, dict) else parse_size(a.size)
    try:
        cfg = replace(d, out=a.out, splits=tuple(s for s in a.splits.split(",") if s), teacher=a.teacher,
                      scenes_root=a.scenes_root, data_root=a.data_root, max_scenes=size, runs=a.runs, seed=a.seed,
                      world=a.world, max_steps=a.max_steps, scenes_per_shard=a.scenes_per_shard, threads=a.threads,
                      progress=not a.no_progress)
    except ValueError as exc:
        p.error(str(exc))
    from .pipeline import generate
    from .stats import describe

    try:
        manifest = generate(cfg, ray_address=a.ray_address, use_ray=a.ray_local)
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(describe(cfg.out, manifest), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
