"""Planner scenarios in the "nudge.scenario/1" schema (one .safetensors file per scenario), or
"nudge.scenario/2" (the same plus lane extents) for tables in the curvilinear road frame.

Road frame x along travel (m), y positive left (m), step 0.3 s; agent 0 = ego; see
docs/data_schema.md for the exact tensors and metadata.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nudge_train.constants import DT, OBS_LEN, PRED_LEN, SCENARIO_SCHEMA, SCENARIO_SCHEMA_EXTENTS

from .grid import Grid
from .st_io import write_safetensors
from .tracks import LaneMap, TrackTable


@dataclass(frozen=True)
class ScenarioConfig:
    """Scenario extraction parameters (s, m)."""

    step_s: float = DT
    n_hist: int = OBS_LEN
    max_future: int = 30
    min_future: int = PRED_LEN
    neighbour_range_m: float = 60.0
    max_agents: int = 47
    straight_tol_m: float = 0.6
    straight_half_range_m: float = 100.0
    road_tolerance_m: float = 2.0
    """How far (m) an agent's observed centre may lie outside the road edges at the ego's x: the
    planner's scenario loader refuses a file beyond it (``ROAD_TOLERANCE`` in
    ``crates/planner/src/scenario.rs``), so such a candidate is dropped as ``agent_off_road``
    (a vehicle still on an on-ramp that joins ahead of the ego, or already on an exit ramp)."""


@dataclass
class Scenario:
    """One scenario: tensors (name -> array) and metadata (str -> str), plus a file stem."""

    tensors: dict[str, np.ndarray]
    metadata: dict[str, str]
    stem: str

    @property
    def n_agents(self) -> int:
        return int(self.tensors["history"].shape[0])

    def save(self, directory: Path) -> Path:
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / f"{self.stem}.safetensors"
        write_safetensors(path, self.tensors, self.metadata)
        return path


def is_merge_scenario(tensors: dict[str, np.ndarray]) -> bool:
    """Whether a scenario's tensors describe a *merge scenario*: the ego, at its last observed
    step, is in a lane that really ends (``lane_extent_real[ego_lane, 1]`` = 1) ahead of it
    (``lane_extent[ego_lane, 1]`` > its x): an on-ramp's acceleration lane or an auxiliary lane
    that ends inside the scene. False without lane extents (``nudge.scenario/1``)."""
    if "lane_extent" not in tensors:
        return False
    lane = int(tensors["ego_lane"][0])
    x = float(tensors["history"][0, -1, 0])
    return bool(tensors["lane_extent_real"][lane, 1]) and float(tensors["lane_extent"][lane, 1]) > x


def is_ramp_scenario(tensors: dict[str, np.ndarray]) -> bool:
    """Whether the ego, at its last observed step, is in a lane that really begins inside the
    scene (``lane_extent_real[ego_lane, 0]`` = 1): an on-ramp lane joined from the ramp, which
    here runs on as an auxiliary lane rather than ending. False without lane extents."""
    if "lane_extent" not in tensors:
        return False
    return bool(tensors["lane_extent_real"][int(tensors["ego_lane"][0]), 0])


def lane_extents_at(lanes: LaneMap, x: float, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Extent of each lane of ``bounds`` [L+1] (the lanes at ``x``, m) in a curvilinear lane map:
    ``extent`` F64 [L, 2] (x where the lane begins and ends, m) and ``real`` U8 [L, 2] (1 where the
    lane really begins / ends there, 0 where only the lane map stops). None for a map without
    extents (the straightened frame) or when a lane at ``x`` matches no lane of the map."""
    if not lanes.lanes:
        return None
    centres = 0.5 * (bounds[:-1] + bounds[1:])
    extent = np.zeros((centres.shape[0], 2))
    real = np.zeros((centres.shape[0], 2), dtype=np.uint8)
    for k, c in enumerate(centres):
        hit = [ln for ln in lanes.lanes if bool(ln.contains(np.asarray([x]), np.asarray([c]))[0])]
        if len(hit) != 1:
            return None
        ln = hit[0]
        extent[k] = (ln.s_begin, ln.s_end)
        real[k] = (int(ln.begins), int(ln.ends))
    return extent, real


def scenario_at(table: TrackTable, grid: Grid, ego_row: int, f_last: int, cfg: ScenarioConfig,
                split: str, drops: Counter, provenance: str) -> Scenario | None:
    """Scenario with ego = grid row ``ego_row`` and last observed frame ``f_last`` (grid index).

    Returns None (and counts the reason in ``drops``) when the ego lacks history or future, or
    the straight-lane approximation fails near the ego, or an agent's observed centre lies more
    than ``cfg.road_tolerance_m`` outside the road at the ego's x, or (curvilinear frame) a lane
    at the ego matches no lane extent. In the curvilinear frame the scenario carries the lane extents
    ("nudge.scenario/2").
    """
    stride = int(round(cfg.step_s / grid.dt))
    hist = f_last - stride * np.arange(cfg.n_hist - 1, -1, -1)
    if hist[0] < 0 or not grid.present[ego_row, hist].all():
        drops["ego_history_incomplete"] += 1
        return None
    fut_all = f_last + stride * np.arange(1, cfg.max_future + 1)
    fut_in = fut_all[fut_all < grid.n_frames]
    ego_fut = grid.present[ego_row, fut_in]
    n_fut = int(np.argmin(ego_fut)) if not ego_fut.all() else int(ego_fut.shape[0])
    if n_fut < cfg.min_future:
        drops["ego_future_short"] += 1
        return None
    fut = fut_all[:n_fut]
    ego_xy = grid.pos[ego_row, f_last]
    dev = table.lanes.local_deviation(float(ego_xy[0]), cfg.straight_half_range_m)
    if dev > cfg.straight_tol_m:
        drops["lanes_not_straight"] += 1
        return None
    full_hist = grid.present[:, hist].all(axis=1)
    d = np.linalg.norm(grid.pos[:, f_last] - ego_xy, axis=1)
    cand = np.flatnonzero(full_hist & (d <= cfg.neighbour_range_m))
    cand = cand[cand != ego_row]
    cand = cand[np.lexsort((grid.ids[cand], d[cand]))][: cfg.max_agents - 1]
    rows = np.concatenate([[ego_row], cand]).astype(np.int64)
    history = grid.pos[rows][:, hist]
    fpres = grid.present[rows][:, fut]
    future = np.where(fpres[..., None], grid.pos[rows][:, fut], 0.0)
    bounds = table.lanes.bounds_at(float(ego_xy[0])).astype(np.float64)
    outside = np.maximum(bounds[0] - history[..., 1], history[..., 1] - bounds[-1])
    if np.any(outside > cfg.road_tolerance_m):
        drops["agent_off_road"] += 1
        return None
    centres = 0.5 * (bounds[:-1] + bounds[1:])
    ego_lane = int(np.clip(np.searchsorted(bounds, ego_xy[1], side="right") - 1, 0, centres.shape[0] - 1))
    extents = lane_extents_at(table.lanes, float(ego_xy[0]), bounds)
    if table.lanes.lanes and extents is None:
        drops["lanes_unmatched"] += 1
        return None
    t0 = (grid.f0 + f_last) * grid.dt
    tensors = {
        "history": history.astype(np.float64),
        "heading": grid.heading[rows, f_last].astype(np.float64),
        "speed": grid.speed[rows, f_last].astype(np.float64),
        "size": grid.size[rows].astype(np.float64),
        "future": future.astype(np.float64),
        "future_valid": fpres.astype(np.uint8),
        "lane_centres": centres,
        "lane_bounds": bounds,
        "ego_lane": np.asarray([ego_lane], dtype=np.int64),
        "agent_ids": grid.ids[rows].astype(np.int64),
    }
    schema = SCENARIO_SCHEMA
    if extents is not None:
        tensors["lane_extent"] = extents[0]
        tensors["lane_extent_real"] = extents[1]
        schema = SCENARIO_SCHEMA_EXTENTS
    meta = {
        "schema": schema, "source": table.source, "scene": table.scene, "split": split,
        "t0_s": f"{t0:.1f}", "dt": str(DT),
        "provenance": (f"{provenance}; ego vehicle {int(grid.ids[ego_row])}, neighbours within "
                       f"{cfg.neighbour_range_m:g} m with full 8-step history; lanes straight within "
                       f"{dev:.2f} m over +-{cfg.straight_half_range_m:g} m"),
    }
    short = table.scene.replace("USA_US101-", "").replace("_T-1", "")
    stem = f"us101-{short}-t{t0:04.1f}-ego{int(grid.ids[ego_row])}"
    return Scenario(tensors=tensors, metadata=meta, stem=stem)


def scene_scenarios(table: TrackTable, grid: Grid, cfg: ScenarioConfig, split: str, drops: Counter,
                    provenance: str) -> list[tuple[Scenario, int]]:
    """Every (ego, last observed frame on the 0.3 s grid, phase 0) scenario of a scene, with the
    grid frame index of its last observed step."""
    stride = int(round(cfg.step_s / grid.dt))
    out: list[tuple[Scenario, int]] = []
    for f_last in range(stride * (cfg.n_hist - 1), grid.n_frames - stride * cfg.min_future, stride):
        for row in range(grid.ids.shape[0]):
            if not grid.present[row, f_last]:
                continue
            sc = scenario_at(table, grid, row, f_last, cfg, split, drops, provenance)
            if sc is not None:
                out.append((sc, f_last))
    return out


def omitted_min_distance(grid: Grid, sc: Scenario, f_last: int, step: int = 3) -> float:
    """Closest approach (m) to the ego, over history and logged future, of vehicles NOT in the
    scenario (inf when none). Used to keep only small-N scenarios where nothing was left out
    that matters."""
    ids = set(int(i) for i in sc.tensors["agent_ids"])
    ego_row = int(np.flatnonzero(grid.ids == sc.tensors["agent_ids"][0])[0])
    n_f = sc.tensors["future"].shape[1]
    frames = f_last + step * np.arange(-7, n_f + 1)
    frames = frames[(frames >= 0) & (frames < grid.n_frames)]
    others = np.asarray([r for r in range(grid.ids.shape[0]) if int(grid.ids[r]) not in ids], dtype=np.int64)
    if others.size == 0:
        return float("inf")
    d = np.linalg.norm(grid.pos[others][:, frames] - grid.pos[ego_row, frames][None], axis=2)
    d = d[np.isfinite(d)]
    return float(d.min()) if d.size else float("inf")


def _score(sc: Scenario) -> tuple[int, int, int]:
    """Preference for shipping: long logged future, ego with lanes on both sides, a neighbour in
    an adjacent lane."""
    t = sc.tensors
    lane = int(t["ego_lane"][0])
    n_lanes = int(t["lane_centres"].shape[0])
    both_sides = int(0 < lane < n_lanes - 1)
    b = t["lane_bounds"]
    y = t["history"][:, -1, 1]
    adj = ((y >= b[max(lane - 1, 0)]) & (y < b[min(lane + 2, n_lanes)])) & (np.abs(y - t["history"][0, -1, 1]) > 1.5)
    return (int(t["future"].shape[1]), both_sides, int(adj[1:].sum() > 0))


def select_shipped(candidates: dict[str, list[tuple[Scenario, Grid, int]]], n_dense: int = 5,
                   n_sparse: int = 5, dense_range: tuple[int, int] = (8, 16),
                   sparse_range: tuple[int, int] = (2, 4), sparse_clear_m: float = 20.0) -> list[Scenario]:
    """Pick a deterministic, varied set: scenes round-robin, dense scenarios (8-16 neighbours) from
    the 60 m candidates and sparse ones (2-4 neighbours) whose omitted vehicles never come closer
    than ``sparse_clear_m`` to the ego. ``candidates``: key "dense"/"sparse" ->
    [(scenario, grid, f_last)] in scene order."""
    chosen: list[Scenario] = []
    for kind, n_want, (lo, hi) in (("dense", n_dense, dense_range), ("sparse", n_sparse, sparse_range)):
        by_scene: dict[str, list[tuple[tuple[int, int, int], Scenario]]] = {}
        for sc, grid, f_last in candidates.get(kind, []):
            nb = sc.n_agents - 1
            if not lo <= nb <= hi:
                continue
            if kind == "sparse" and omitted_min_distance(grid, sc, f_last) < sparse_clear_m:
                continue
            by_scene.setdefault(sc.metadata["scene"], []).append((_score(sc), sc))
        for lst in by_scene.values():
            lst.sort(key=lambda p: (-p[0][0], -p[0][1], -p[0][2], p[1].stem))
        scenes = sorted(by_scene)
        taken = 0
        rnd = 0
        used = {c.stem for c in chosen}
        while taken < n_want and any(rnd < len(by_scene[s]) for s in scenes):
            for s in scenes:
                if taken >= n_want:
                    break
                # Skip near-duplicates: same scene and ego already chosen.
                lst = by_scene[s]
                # (ids repeat across scenes of one overlap group: the same vehicle)
                while rnd < len(lst) and (lst[rnd][1].stem in used or any(
                        int(c.tensors["agent_ids"][0]) == int(lst[rnd][1].tensors["agent_ids"][0])
                        for c in chosen)):
                    lst.pop(rnd)
                if rnd < len(lst):
                    chosen.append(lst[rnd][1])
                    used.add(lst[rnd][1].stem)
                    taken += 1
            rnd += 1
    return chosen
