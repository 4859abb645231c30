"""`nudge-train` command line: `nudge-train data build|report|scenes ...`.

Other subcommand groups (training) may be added next to `data`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "ngsim"
DEFAULT_OUT = REPO / "data" / "processed"


def _data_parser(sub: argparse._SubParsersAction) -> None:
    data = sub.add_parser("data", help="NGSIM data pipeline")
    dsub = data.add_subparsers(dest="data_cmd", required=True)

    b = dsub.add_parser("build", help="build training windows (safetensors shards + manifest)")
    b.add_argument("--data-root", type=Path, default=DEFAULT_DATA)
    b.add_argument("--out", type=Path, default=DEFAULT_OUT)
    b.add_argument("--raw", type=Path, action="append", default=[],
                   help="extra official raw NGSIM file(s) (18- or 25-column, feet) to include")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--phases", type=str, default="0,1,2", help="0.1 s phase offsets, e.g. 0 or 0,1,2")
    b.add_argument("--no-i80", action="store_true", help="leave out the Coifman & Li I-80 set")
    b.add_argument("--no-progress", action="store_true")

    r = dsub.add_parser("report", help="write docs/data.md and docs/figures/data_*.png from a build")
    r.add_argument("--processed", type=Path, default=DEFAULT_OUT)
    r.add_argument("--doc", type=Path, default=REPO / "docs" / "data.md")
    r.add_argument("--figures", type=Path, default=REPO / "docs" / "figures")

    s = dsub.add_parser("scenes", help="write planner scenarios (nudge.scenario/1) of a split")
    s.add_argument("--data-root", type=Path, default=DEFAULT_DATA)
    s.add_argument("--split", choices=("train", "val", "test"), default="test")
    s.add_argument("--out", type=Path, default=None,
                   help="output folder (default data/processed/scenes/<split>, or assets/scenes with --ship)")
    s.add_argument("--ship", action="store_true", help="write the small shipped selection (8-12 scenarios)")
    s.add_argument("--range", type=float, default=60.0, help="neighbour range (m)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--no-progress", action="store_true")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="nudge-train")
    sub = parser.add_subparsers(dest="cmd", required=True)
    _data_parser(sub)
    args = parser.parse_args(argv)
    from .data.errors import DataError

    try:
        if args.cmd == "data":
            return _run_data(args)
    except DataError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 1


def _run_data(args: argparse.Namespace) -> int:
    from .data.splits import SplitConfig

    if args.data_cmd == "scenes":
        from .data.scene_cmd import ScenesConfig, write_scenes

        out = args.out or (REPO / "assets" / "scenes" if args.ship else DEFAULT_OUT / "scenes" / args.split)
        paths, drops = write_scenes(args.data_root, out,
                                    ScenesConfig(split=args.split, ship=args.ship, dense_range_m=args.range),
                                    SplitConfig(seed=args.seed), progress=not args.no_progress)
        print(f"wrote {len(paths)} scenarios to {out}")
        for k, v in sorted(drops.items()):
            print(f"  dropped candidates ({k}): {v}")
        return 0
    if args.data_cmd == "build":
        from .data.build import BuildConfig, build

        phases = tuple(int(p) for p in args.phases.split(",") if p.strip())
        manifest = build(BuildConfig(data_root=args.data_root, out=args.out, raw=tuple(args.raw),
                                     seed=args.seed, phases=phases, include_i80=not args.no_i80),
                         progress=not args.no_progress)
        print(f"wrote {args.out / 'manifest.json'}: {manifest['counts']['windows']} windows")
        return 0
    if args.data_cmd == "report":
        from .data.report import write_report

        write_report(args.processed, args.doc, args.figures)
        print(f"wrote {args.doc}")
        return 0
    return 1


if __name__ == "__main__":
    sys.exit(main())
