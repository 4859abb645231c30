"""Discovery of the source files under the NGSIM data directory and their split assignment."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from .commonroad import read_commonroad
from .errors import DataError
from .splits import EXCLUDED_SCENES, SplitConfig, assign, read_overlap_groups, scene_number
from .tracks import TrackTable

US101_DIRS = ("us101/commonroad_us101_T-1", "us101/commonroad_us101_2018b_extra")
OVERLAP_CSV = "us101/commonroad_us101_scene_overlap_groups.csv"
COIFMAN = "i80/coifman_li_2017_i80_0400-0415_camera6_reextracted.csv.gz"


@dataclass
class SourceEntry:
    """One source file (or I-80 time block) and what happened to it."""

    name: str
    kind: str  # "commonroad" | "coifman_block" | "raw"
    group: str  # split group key (overlap group / time block)
    split: str  # train | val | test | excluded
    reason: str = ""
    table: TrackTable | None = field(default=None, repr=False)


def us101_sources(data_root: Path, cfg: SplitConfig, window_span_frames: int = 39,
                  progress: bool = False) -> list[SourceEntry]:
    """Read every US-101 CommonRoad file; keep one variant per scene (variants repeat the same
    traffic, some with vehicles removed); exclude USA_US101-3_5_T-1; assign splits by overlap group
    weighted by the number of 0.1 s window starts."""
    files: list[Path] = []
    for d in US101_DIRS:
        files += sorted((data_root / d).glob("*.xml*"))
    if not files:
        raise DataError(data_root, f"no CommonRoad files under {', '.join(US101_DIRS)}")
    groups = read_overlap_groups(data_root / OVERLAP_CSV)
    entries: list[SourceEntry] = []
    by_scene: dict[int, list[tuple[int, Path]]] = {}
    for f in files:
        scene, variant = scene_number(f.name)
        by_scene.setdefault(scene, []).append((variant, f))
    weights: dict[str, float] = {}
    for scene in tqdm(sorted(by_scene), desc="read US-101", disable=not progress):
        variants = sorted(by_scene[scene])
        chosen = None
        for variant, f in variants:
            bid = f.name.split(".")[0]
            if bid in EXCLUDED_SCENES:
                entries.append(SourceEntry(f.name, "commonroad", "", "excluded",
                                           "criticality-modified variant (PROVENANCE.md)"))
                continue
            if chosen is not None:
                entries.append(SourceEntry(f.name, "commonroad", "", "excluded",
                                           f"variant of scene {scene}: same traffic as {chosen.name}"))
                continue
            if scene not in groups:
                raise DataError(data_root / OVERLAP_CSV, f"scene {scene} ({f.name}) has no overlap_group")
            table = read_commonroad(f)
            key = f"us101-group-{groups[scene]:02d}"
            n_frames = int(table.frame().max() - table.frame().min() + 1)
            weights[key] = weights.get(key, 0.0) + max(n_frames - window_span_frames, 0)
            chosen = SourceEntry(f.name, "commonroad", key, "", table=table)
            entries.append(chosen)
    split_of = assign(weights, cfg, salt=101)
    for e in entries:
        if e.split == "":
            e.split = split_of[e.group]
    return entries
