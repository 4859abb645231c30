"""`nudge-train data scenes`: write planner scenarios of one split (or the shipped selection)."""

from __future__ import annotations

from collections import Counter
import json
from dataclasses import dataclass, field, replace
from pathlib import Path

from tqdm import tqdm

from nudge_train.artefacts import atomic_write_text
from nudge_train.constants import DEFAULT_ROAD_FRAME

from .grid import build_grid
from .scenarios import Scenario, ScenarioConfig, is_merge_scenario, is_ramp_scenario, scene_scenarios, select_shipped
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
    frame: str = DEFAULT_ROAD_FRAME


SUMMARY = "summary.json"
"""What ``data scenes`` wrote into its output folder: counts per scene, merges, candidates
dropped per reason (read by ``data report``)."""


@dataclass
class ScenesResult:
    """What :func:`write_scenes` did: the files written, candidates dropped per reason, the
    source-level decisions as printable lines, merge scenarios per scene, stale files removed."""

    written: list[Path]
    drops: Counter
    notes: list[str]
    merges: list[Path] = field(default_factory=list)
    per_scene: dict[str, dict[str, int]] = field(default_factory=dict)
    removed: int = 0


def write_scenes(data_root: Path, out_dir: Path, cfg: ScenesConfig, split_cfg: SplitConfig,
                 progress: bool = True) -> ScenesResult:
    """Write the scenarios of ``cfg.split`` (or the shipped selection) into ``out_dir``, remove
    scenario files (``us101-*.safetensors``) of an earlier run that this one did not write, and
    record the counts in ``out_dir/summary.json`` (not for the shipped selection). Merge scenarios:
    :func:`~nudge_train.data.scenarios.is_merge_scenario`."""
    sources = us101_sources(data_root, split_cfg, frame=cfg.frame)
    notes = decision_lines([(e.split, e.rule, e.reason) for e in sources])
    entries = [e for e in sources if e.split == cfg.split and e.table is not None]
    drops: Counter = Counter()
    base = ScenarioConfig()
    dense: list[tuple[Scenario, object, int]] = []
    sparse: list[tuple[Scenario, object, int]] = []
    per_scene: dict[str, dict[str, int]] = {}
    for e in tqdm(entries, desc=f"scenes ({cfg.split})", disable=not progress):
        assert e.table is not None
        grid = build_grid(e.table)
        prov = (PROVENANCE_FRENET if cfg.frame == "frenet" else PROVENANCE).format(source=e.name)
        scene_drops: Counter = Counter()
        found = scene_scenarios(e.table, grid, replace(base, neighbour_range_m=cfg.dense_range_m), cfg.split,
                                scene_drops, prov)
        drops.update(scene_drops)
        dense += [(sc, grid, f_last) for sc, f_last in found]
        per_scene[e.name] = {"scenarios": len(found), "merge_scenarios": sum(is_merge_scenario(sc.tensors)
                                                                             for sc, _ in found),
                             "ramp_scenarios": sum(is_ramp_scenario(sc.tensors) for sc, _ in found),
                             **{f"dropped_{k}": v for k, v in sorted(scene_drops.items())}}
        if cfg.ship:
            for sc, f_last in scene_scenarios(e.table, grid, replace(base, neighbour_range_m=cfg.sparse_range_m),
                                              cfg.split, Counter(), prov):
                sparse.append((sc, grid, f_last))
    if cfg.ship:
        chosen = select_shipped({"dense": dense, "sparse": sparse})  # type: ignore[dict-item]
    else:
        chosen = [sc for sc, _, _ in dense]
    written = [sc.save(out_dir) for sc in chosen]
    merges = [p for p, sc in zip(written, chosen) if is_merge_scenario(sc.tensors)]
    keep = {p.name for p in written}
    removed = 0
    for old in sorted(out_dir.glob("us101-*.safetensors")):
        if old.name not in keep:
            old.unlink()
            removed += 1
    summary = {"split": cfg.split, "road_frame": cfg.frame, "ship": cfg.ship, "scenarios": len(written),
               "merge_scenarios": len(merges), "ramp_scenarios": sum(is_ramp_scenario(sc.tensors) for sc in chosen),
               "candidates_dropped": dict(sorted(drops.items())),
               "per_scene": per_scene}
    if cfg.ship:  # the shipped selection's folder documents itself (PROVENANCE.md)
        return ScenesResult(written=written, drops=drops, notes=notes, merges=merges, per_scene=per_scene,
                            removed=removed)
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / SUMMARY, json.dumps(summary, indent=1, sort_keys=True) + "\n")
    return ScenesResult(written=written, drops=drops, notes=notes, merges=merges, per_scene=per_scene,
                        removed=removed)
