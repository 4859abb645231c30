"""`python -m nudge_train.idm {fit,cutins,report,all}`: IDM fitted to real NGSIM car-following,
the real cut-ins and the IDM world's intrusion rule (docs/results/idm_fit.md)."""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

from .pipeline import Settings


def main(argv: list[str] | None = None) -> int:
    d = Settings()
    p = argparse.ArgumentParser(prog="python -m nudge_train.idm", description=__doc__)
    p.add_argument("stage", choices=("fit", "cutins", "report", "all"))
    p.add_argument("--data-root", type=Path, default=d.data_root)
    p.add_argument("--runs", type=Path, default=d.runs, help="intermediate results (resumable driver fits)")
    p.add_argument("--assets", type=Path, default=d.assets, help="where idm.json and cutins.json go")
    p.add_argument("--doc", type=Path, default=d.doc)
    p.add_argument("--figures", type=Path, default=d.figures)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    s = replace(d, data_root=a.data_root, runs=a.runs, assets=a.assets, doc=a.doc, figures=a.figures, seed=a.seed,
                fit=replace(d.fit, seed=a.seed), rule=replace(d.rule, seed=a.seed), progress=not a.no_progress)
    from nudge_train.data.errors import DataError

    from .pipeline import run_cutins, run_fit
    from .report import main_report
    from .sources import load_sources

    t0 = time.perf_counter()
    try:
        sources = load_sources(s.data_root, s.progress) if a.stage in ("fit", "cutins", "all") else None
        if a.stage in ("fit", "all"):
            run_fit(s, sources)
        if a.stage in ("cutins", "all"):
            run_cutins(s, sources)
        if a.stage in ("report", "all"):
            main_report(s.runs, s.doc, s.figures)
    except (DataError, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{a.stage}: {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
