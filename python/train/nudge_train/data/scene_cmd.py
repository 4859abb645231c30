"""`nudge-train data scenes`: write planner scenarios of one split (or the shipped selection)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

from tqdm import tqdm

from .grid import build_grid
from .scenarios import Scenario, ScenarioConfig, scene_scenarios, select_shipped
from .sources import decision_lines, us101_sources
from .splits import SplitConfig

PROVENANCE = ("NGSIM US-101 (FHWA, public domain), Los Angeles 15 June 2005, via the CommonRoad "
              "2020a/2018b benchmark scenario {source} (TU Munich); road frame straightened along "
              "the fitted lane geometry by nudge_train.data")
PROVENANCE_FRENET = ("NGSIM US-101 (FHWA, public domain), Los Angeles 15 June 2005, via the CommonRoad "
                     "2020a/2018b benchmark scenario {source} (TU Munich); curvilinear road frame (arclength "
                     "and offset along a spline fitted to the lane geometry) by nudge_train.data")


@dataclass(frozen=True)
class ScenesConfig:
    """What to write: a split, all candidates or the shipped selection, neighbour ranges (m)."""

    split: str = "test"
    ship: bool = False
    dense_range_m: float = 60.0
    sparse_range_m: float = 25.0
    stride_steps: int = 1
    frame: str = "straightened"


def write_scenes(data_root: Path, out_dir: Path, cfg: ScenesConfig, split_cfg: SplitConfig,
                 progress: bool = True) -> tuple[list[Path], Counter, list[str]]:
    """Write scenarios; returns written paths, candidate drop counts (reason -> count) and the
    source-level decisions (excluded files per rule, split decisions) as printable lines."""
    sources = us101_sources(data_root, split_cfg, frame=cfg.frame)
    notes = decision_lines([(e.split, e.rule, e.reason) for e in sources])
    entries = [e for e in sources if e.split == cfg.split and e.table is not None]
    drops: Counter = Counter()
    base = ScenarioConfig()
    written: list[Path] = []
    dense: list[tuple[Scenario, object, int]] = []
    sparse: list[tuple[Scenario, object, int]] = []
    for e in tqdm(entries, desc=f"scenes ({cfg.split})", disable=not progress):
        assert e.table is not None
        grid = build_grid(e.table)
        prov = (PROVENANCE_FRENET if cfg.frame == "frenet" else PROVENANCE).format(source=e.name)
        for sc, f_last in scene_scenarios(e.table, grid, replace(base, neighbour_range_m=cfg.dense_range_m),
                                          cfg.split, drops, prov):
            dense.append((sc, grid, f_last))
        if cfg.ship:
            for sc, f_last in scene_scenarios(e.table, grid, replace(base, neighbour_range_m=cfg.sparse_range_m),
                                              cfg.split, Counter(), prov):
                sparse.append((sc, grid, f_last))
    if cfg.ship:
        chosen = select_shipped({"dense": dense, "sparse": sparse})  # type: ignore[dict-item]
    else:
        chosen = [sc for sc, _, _ in dense]
    for sc in chosen:
        written.append(sc.save(out_dir))
    return written, drops, notes
