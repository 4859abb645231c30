"""Source files of the IDM work and their train/val/test split, by the data pipeline's own rule.

US-101 scenes inherit the split of their overlap group and I-80 time blocks theirs, exactly as
``nudge-train data build`` assigns them (:func:`nudge_train.data.build.collect_units` is called, not
re-implemented), so the IDM fit and the cut-in events never hold out differently from the
prediction models.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from nudge_train.data.build import BuildConfig, collect_units
from nudge_train.data.tracks import TrackTable

I80_PAIRS = "i80/durraniu_i80_0400-0415_emd_reconstructed_carfollowing_pairs.csv.gz"
COIFMAN = "i80/coifman_li_2017_i80_0400-0415_camera6_reextracted.csv.gz"
US101_FLAT = "us101/commonroad_us101_T-1_dynamic_obstacles_flat.csv.gz"
OVERLAP_CSV = "us101/commonroad_us101_scene_overlap_groups.csv"
SPLITS = ("train", "val", "test")


@dataclass
class SceneSource:
    """One US-101 scene: its road-frame track table, overlap group and split."""

    name: str
    group: str
    split: str
    table: TrackTable


@dataclass
class Sources:
    """Everything read once: US-101 scenes (one variant per scene, 3_5 excluded), the Coifman &
    Li I-80 table and its time blocks ``(frame_lo, frame_hi, split)`` (half-open frame ranges)."""

    us101: list[SceneSource]
    coifman: TrackTable
    i80_blocks: list[tuple[int, int, str]]

    def i80_split(self, frame: float) -> str:
        """Split of the I-80 time block holding ``frame`` (the nearest block outside them all)."""
        best, dist = self.i80_blocks[0][2], float("inf")
        for lo, hi, split in self.i80_blocks:
            d = max(lo - frame, 0.0, frame - (hi - 1))
            if d < dist:
                best, dist = split, d
        return best


def load_sources(data_root: Path, progress: bool = False) -> Sources:
    """Read the sources and assign splits with the data pipeline's rule (seed 0 defaults)."""
    units, _ = collect_units(BuildConfig(data_root=Path(data_root), out=Path(data_root) / "unused"), progress)
    us101: list[SceneSource] = []
    blocks: list[tuple[int, int, str]] = []
    coifman: TrackTable | None = None
    for u in units:
        e = u.entry
        assert e.table is not None
        if e.kind == "commonroad":
            us101.append(SceneSource(e.name.split(".")[0], e.group, e.split, e.table))
        elif e.kind == "coifman_block":
            coifman = e.table
            assert u.frames is not None
            blocks.append((u.frames[0], u.frames[1], e.split))
    assert coifman is not None, "the data pipeline read no Coifman & Li table"
    return Sources(us101=us101, coifman=coifman, i80_blocks=blocks)
