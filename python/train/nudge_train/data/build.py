"""`nudge-train data build`: every source -> windows -> safetensors shards + manifest.json.

Deterministic: sources and windows in a fixed order, seeded splits, no timestamps; a rebuild
gives byte-identical shards and manifest (sha256 of each shard in the manifest, verified by
:func:`nudge_train.data.loader.load_split`). Every file is written temp-then-rename, the
manifest last; stale temp files of a killed build are removed by the next one.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nudge_train.constants import DATASET_SCHEMA, DEFAULT_ROAD_FRAME, SPLITS, WINDOWS_SCHEMA
from nudge_train.artefacts import atomic_write_text, remove_stale_temps
from nudge_train.provenance import sha256_file

from .coifman import CoifmanConfig, read_coifman
from .errors import DataError
from .grid import build_grid
from .raw import RawConfig, read_raw_ngsim
from .st_io import write_safetensors
from .sources import COIFMAN, SourceEntry, us101_sources
from .splits import TOO_FEW_GROUPS, SplitConfig, assign_or_test
from .tracks import TrackTable
from .windows import Window, WindowConfig, WindowStats, extract_windows, is_merge_window


@dataclass(frozen=True)
class BuildConfig:
    """Everything the build depends on (recorded in the manifest)."""

    data_root: Path
    out: Path
    raw: tuple[Path, ...] = ()
    seed: int = 0
    phases: tuple[int, ...] = (0, 1, 2)
    include_i80: bool = True
    windows_per_shard: int = 4096
    window: WindowConfig = field(default_factory=WindowConfig)
    split: SplitConfig = field(default_factory=SplitConfig)
    coifman: CoifmanConfig = field(default_factory=CoifmanConfig)
    raw_cfg: RawConfig = field(default_factory=RawConfig)
    frame: str = DEFAULT_ROAD_FRAME
    """Road frame of the US-101 scenes (``frenet`` or ``straightened``); recorded in the manifest's
    config as ``road_frame`` (a manifest without it was built in the ``straightened`` frame)."""


def time_blocks(table: TrackTable, block_s: float) -> list[tuple[int, int]]:
    """Contiguous [frame_lo, frame_hi) blocks of ``block_s`` seconds covering the table."""
    fr = table.frame()
    lo, hi = int(fr.min()), int(fr.max()) + 1
    n = max(int(round(block_s / table.dt)), 1)
    return [(s, min(s + n, hi)) for s in range(lo, hi, n)]


@dataclass
class Unit:
    """A unit of windowing: one source table (or one time block of it) with its split."""

    entry: SourceEntry
    frames: tuple[int, int] | None


def collect_units(cfg: BuildConfig, progress: bool) -> tuple[list[Unit], list[SourceEntry]]:
    split_cfg = SplitConfig(seed=cfg.seed, test_frac=cfg.split.test_frac, val_frac=cfg.split.val_frac,
                            i80_block_s=cfg.split.i80_block_s, tries=cfg.split.tries)
    entries = us101_sources(cfg.data_root, split_cfg, progress=progress, frame=cfg.frame)
    units = [Unit(e, None) for e in entries if e.table is not None]
    long_tables: list[tuple[str, str, TrackTable, int]] = []
    if cfg.include_i80:
        path = cfg.data_root / COIFMAN
        if not path.exists():
            raise DataError(path, "Coifman & Li I-80 file not found (use --no-i80 to build without it)")
        long_tables.append(("i80", "coifman_block", read_coifman(path, cfg.coifman), 80))
    for k, rp in enumerate(cfg.raw):
        for t in read_raw_ngsim(rp, cfg.raw_cfg):
            long_tables.append((f"raw{k}-{t.scene}", "raw_block", t, 1000 + k))
    for prefix, kind, table, salt in long_tables:
        blocks = time_blocks(table, split_cfg.i80_block_s)
        keys = [f"{prefix}-block-{b:02d}" for b in range(len(blocks))]
        span = int(round(cfg.window.step_s / table.dt)) * (cfg.window.n_steps - 1)
        weights = {k: float(max(hi - lo - span, 0)) + 1e-6 for k, (lo, hi) in zip(keys, blocks)}
        what = "I-80 time block" if kind == "coifman_block" else f"time block of {table.source} ({table.scene})"
        split_of, note = assign_or_test(weights, split_cfg, salt=salt, what=what)
        for key, (lo, hi) in zip(keys, blocks):
            e = SourceEntry(name=f"{table.source}#{key}", kind=kind, group=key, split=split_of[key], table=table,
                            reason=note, rule=TOO_FEW_GROUPS if note else "")
            entries.append(e)
            units.append(Unit(e, (lo, hi)))
    return units, entries


def _pack(windows: list[tuple[Window, int]]) -> dict[str, np.ndarray]:
    """Shard tensors for windows [(window, source index)] (see docs/data_schema.md)."""
    counts = np.asarray([w.positions.shape[0] for w, _ in windows], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return {
        "positions": np.concatenate([w.positions for w, _ in windows]).astype(np.float32),
        "offsets": offsets,
        "interactive": np.asarray([w.interactive for w, _ in windows], dtype=np.uint8),
        "agent_lane_change": np.concatenate([w.lane_change for w, _ in windows]).astype(np.uint8),
        "size": np.concatenate([w.size for w, _ in windows]).astype(np.float32),
        "source": np.asarray([s for _, s in windows], dtype=np.int64),
        "t0": np.asarray([w.t0 for w, _ in windows], dtype=np.float32),
        "phase": np.asarray([w.phase for w, _ in windows], dtype=np.uint8),
        "origin": np.stack([w.origin for w, _ in windows]).astype(np.float32),
        "agent_ids": np.concatenate([w.ids for w, _ in windows]).astype(np.int64),
        "agent_flags": np.concatenate([w.flags for w, _ in windows]).astype(np.int64),
    }


def _jsonable(obj: object) -> object:
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    return obj


def build(cfg: BuildConfig, progress: bool = True) -> dict:
    """Build the processed dataset into ``cfg.out``; returns the manifest (also written)."""
    wcfg = WindowConfig(**{**asdict(cfg.window), "phases": tuple(cfg.phases)})
    if not cfg.phases or any(p not in (0, 1, 2) for p in cfg.phases):
        raise ValueError(f"phases must be a non-empty subset of 0,1,2: {cfg.phases}")
    units, entries = collect_units(cfg, progress)
    index_of = {e.name: i for i, e in enumerate(entries)}
    per_split: dict[str, list[tuple[Window, int]]] = {s: [] for s in SPLITS}
    per_source: dict[str, dict] = {}
    split_stats = {s: WindowStats() for s in SPLITS}
    merge_per_split = {s: 0 for s in SPLITS}
    for u in tqdm(units, desc="windows", disable=not progress):
        e = u.entry
        assert e.table is not None
        grid = build_grid(e.table, *(u.frames or (None, None)))
        st = WindowStats()
        ws = extract_windows(grid, wcfg, stats=st)
        si = index_of[e.name]
        n_merge = sum(is_merge_window(w, e.table.lanes, wcfg.n_obs) for w in ws)
        merge_per_split[e.split] += n_merge
        per_split[e.split].extend((w, si) for w in ws)
        split_stats[e.split].merge(st)
        per_source[e.name] = {
            "windows": st.kept, "agents": st.agents_kept, "candidates": st.candidates,
            "interactive": int(sum(w.interactive for w in ws)),
            "lane_changing_agents": int(sum(int(w.lane_change.sum()) for w in ws)),
            "merge_windows": int(n_merge),
            "windows_dropped": dict(sorted(st.windows_dropped.items())),
            "agents_dropped": dict(sorted(st.agents_dropped.items())),
        }
    cfg.out.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(cfg.out)
    splits_out: dict[str, dict] = {}
    for s in SPLITS:
        ws = per_split[s]
        shards = []
        for k in range(0, max(len(ws), 1), cfg.windows_per_shard):
            chunk = ws[k:k + cfg.windows_per_shard]
            if not chunk:
                break
            name = f"{s}-{k // cfg.windows_per_shard:03d}.safetensors"
            path = cfg.out / name
            tensors = _pack(chunk)
            write_safetensors(path, tensors, {"schema": WINDOWS_SCHEMA, "split": s})
            shards.append({"file": name, "sha256": sha256_file(path), "windows": len(chunk),
                           "agents": int(tensors["offsets"][-1])})
        st = split_stats[s]
        splits_out[s] = {
            "windows": len(ws), "agents": int(sum(w.positions.shape[0] for w, _ in ws)),
            "interactive": int(sum(w.interactive for w, _ in ws)),
            "merge_windows": int(merge_per_split[s]),
            "candidates": st.candidates,
            "windows_dropped": dict(sorted(st.windows_dropped.items())),
            "agents_dropped": dict(sorted(st.agents_dropped.items())),
            "shards": shards,
        }
    sources = []
    for i, e in enumerate(entries):
        rec = {"index": i, "name": e.name, "kind": e.kind, "group": e.group, "split": e.split}
        if e.reason:
            rec["reason"] = e.reason
        if e.rule:
            rec["rule"] = e.rule
        if e.table is not None:
            rec["scene"] = e.table.scene
            rec["reader_notes"] = dict(sorted(e.table.notes.items()))
        rec.update(per_source.get(e.name, {}))
        sources.append(rec)
    total_w = sum(v["windows"] for v in splits_out.values())
    manifest = {
        "schema": DATASET_SCHEMA,
        "windows_schema": WINDOWS_SCHEMA,
        "config": _jsonable({
            "seed": cfg.seed, "phases": list(cfg.phases), "include_i80": cfg.include_i80,
            "raw": [p.name for p in cfg.raw], "windows_per_shard": cfg.windows_per_shard,
            "window": asdict(wcfg), "split": asdict(cfg.split), "coifman": asdict(cfg.coifman),
            "raw_cleaning": asdict(cfg.raw_cfg),
            "road_frame": cfg.frame,
        }),
        "counts": {"windows": total_w, "agents": sum(v["agents"] for v in splits_out.values()),
                   "sources": len(sources)},
        "splits": splits_out,
        "sources": sources,
    }
    atomic_write_text(cfg.out / "manifest.json", json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    # Shards of an earlier build that this manifest no longer lists (written before it, so a
    # build killed midway leaves the old manifest, whose sha256 entries expose any replaced shard).
    listed = {sh["file"] for sp in splits_out.values() for sh in sp["shards"]}
    for old in cfg.out.glob("*.safetensors"):
        if old.name not in listed:
            old.unlink()
    return manifest
