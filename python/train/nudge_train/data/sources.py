"""Discovery of the source files under the NGSIM data directory and their split assignment."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from nudge_train.constants import DEFAULT_ROAD_FRAME

from .commonroad import read_commonroad
from .errors import DataError
from .splits import EXCLUDED_SCENES, SCENE_RE, TOO_FEW_GROUPS, SplitConfig, assign_or_test, read_overlap_groups
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
    rule: str = ""  # why excluded (or why a split was decided rather than drawn): a fixed name
    table: TrackTable | None = field(default=None, repr=False)


# Rules of the source-level decisions (manifest "rule", the dataset report counts them).
CRITICALITY_MODIFIED = "criticality_modified"
DUPLICATE_VARIANT = "duplicate_variant"
NO_OVERLAP_GROUP = "no_overlap_group"
NOT_US101_BENCHMARK = "not_us101_benchmark"


def decision_lines(sources: list[tuple[str, str, str]]) -> list[str]:
    """What the CLI prints about source-level decisions, from (split, rule, reason) triples:
    excluded sources counted per rule, then each distinct split decision."""
    excluded: dict[str, int] = {}
    notes: list[str] = []
    for split, rule, reason in sources:
        if split == "excluded":
            excluded[rule or reason] = excluded.get(rule or reason, 0) + 1
        elif rule and reason not in notes:
            notes.append(reason)
    return [f"excluded {n} source(s) ({rule})" for rule, n in sorted(excluded.items())] + [f"note: {r}" for r in notes]


def us101_sources(data_root: Path, cfg: SplitConfig, window_span_frames: int = 39,
                  progress: bool = False, frame: str = DEFAULT_ROAD_FRAME) -> list[SourceEntry]:
    """Read every US-101 CommonRoad file; keep one variant per scene (variants repeat the same
    traffic, some with vehicles removed); exclude USA_US101-3_5_T-1; assign splits by overlap group
    weighted by the number of 0.1 s window starts.

    Decisions, each recorded on its entry (``rule``, ``reason``), never a traceback: a file whose
    name is no US-101 benchmark id, or whose scene has no row in the overlap table, is excluded
    (its vehicles may be shared with other scenes, so no split is safe for it); with fewer than 3
    overlap groups every scene goes to ``test`` (see :func:`~nudge_train.data.splits.assign_or_test`).

    ``frame``: the road frame of the tables (:data:`~nudge_train.data.commonroad.FRAMES`).

    Raises:
        DataError: no CommonRoad file, an unreadable or malformed overlap table, or a file that
        cannot be read or (frame ``frenet``) represented (naming it).
    """
    files: list[Path] = []
    for d in US101_DIRS:
        files += sorted((data_root / d).glob("*.xml*"))
    if not files:
        raise DataError(data_root, f"no CommonRoad files under {', '.join(US101_DIRS)}")
    overlap = data_root / OVERLAP_CSV
    groups = read_overlap_groups(overlap)
    entries: list[SourceEntry] = []
    by_scene: dict[int, list[tuple[int, Path]]] = {}
    for f in files:
        m = SCENE_RE.search(f.name)
        if m is None:
            entries.append(SourceEntry(f.name, "commonroad", "", "excluded",
                                       "not a US-101 benchmark id (USA_US101-<scene>_<variant>): no overlap group",
                                       NOT_US101_BENCHMARK))
            continue
        by_scene.setdefault(int(m.group(1)), []).append((int(m.group(2)), f))
    weights: dict[str, float] = {}
    for scene in tqdm(sorted(by_scene), desc="read US-101", disable=not progress):
        variants = sorted(by_scene[scene])
        chosen = None
        for variant, f in variants:
            bid = f.name.split(".")[0]
            if bid in EXCLUDED_SCENES:
                entries.append(SourceEntry(f.name, "commonroad", "", "excluded",
                                           "criticality-modified variant (PROVENANCE.md)", CRITICALITY_MODIFIED))
                continue
            if scene not in groups:
                entries.append(SourceEntry(f.name, "commonroad", "", "excluded",
                                           f"scene {scene} has no row in {overlap.name}: its vehicles may be shared "
                                           "with other scenes, so no split is safe", NO_OVERLAP_GROUP))
                continue
            if chosen is not None:
                entries.append(SourceEntry(f.name, "commonroad", "", "excluded",
                                           f"variant of scene {scene}: same traffic as {chosen.name}",
                                           DUPLICATE_VARIANT))
                continue
            table = read_commonroad(f, frame=frame)
            key = f"us101-group-{groups[scene]:02d}"
            n_frames = int(table.frame().max() - table.frame().min() + 1)
            weights[key] = weights.get(key, 0.0) + max(n_frames - window_span_frames, 0)
            chosen = SourceEntry(f.name, "commonroad", key, "", table=table)
            entries.append(chosen)
    split_of, note = assign_or_test(weights, cfg, salt=101, what="US-101 overlap group")
    for e in entries:
        if e.split == "":
            e.split = split_of[e.group]
            if note:
                e.reason, e.rule = note, TOO_FEW_GROUPS
    return entries
