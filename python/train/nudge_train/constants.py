"""Constants shared by the data pipeline, the networks, training and the distillation set.

The time grid and window lengths are those of the paper and of the Rust crates (``nudge._native``
exposes ``T_OBS`` and ``DT``); the schema strings name the file formats documented in
docs/data_schema.md, docs/models.md and docs/distill.md.
"""

from __future__ import annotations

__all__ = [
    "BENCH_NS",
    "DATASET_SCHEMA",
    "DISTILL_SCHEMA",
    "DT",
    "OBS_LEN",
    "PRED_LEN",
    "SCENARIO_SCHEMA",
    "SCENARIO_SCHEMA_EXTENTS",
    "ROAD_FRAMES",
    "DEFAULT_ROAD_FRAME",
    "SPLITS",
    "WEIGHTS_FORMAT",
    "WINDOWS_SCHEMA",
]

OBS_LEN = 8
"""Observed steps per agent (t_obs): the networks' input window."""
PRED_LEN = 6
"""Future steps of a training window and of the planning horizon (t_plan)."""
DT = 0.3
"""Step length in seconds (NGSIM's 10 Hz resampled every third frame)."""

SPLITS = ("train", "val", "test")
"""The data splits, in this order everywhere (split by overlap group / time block, never by window)."""

DATASET_SCHEMA = "nudge.dataset/1"
"""``manifest.json`` of a processed-data build (``nudge-train data build``)."""
WINDOWS_SCHEMA = "nudge.windows/1"
"""One shard of training windows of a processed-data build."""
SCENARIO_SCHEMA = "nudge.scenario/1"
"""One planner scenario file (``nudge-train data scenes``), read by the Rust scenario loader."""
ROAD_FRAMES = ("frenet", "straightened")
"""Road frames of the US-101 reader, the default first: ``frenet`` (curvilinear: arclength and
offset along a fitted reference path, lanes with extents) and ``straightened`` (one rotation and a
first-order straightening along a fitted polynomial; the frame of builds before the curvilinear
one became the default, and of the ten scenarios in ``assets/scenes``)."""
DEFAULT_ROAD_FRAME = ROAD_FRAMES[0]
"""The road frame of ``nudge-train data build`` and ``data scenes`` unless ``--frame`` says otherwise."""
SCENARIO_SCHEMA_EXTENTS = "nudge.scenario/2"
"""A planner scenario with lane extents (where each lane begins and ends along x), written for
the curvilinear road frame (``nudge-train data scenes --frame frenet``); the Rust loader reads
both versions."""
DISTILL_SCHEMA = "nudge.distill/1"
"""The distillation set: its ``manifest.json`` and every shard (``nudge-train distill``)."""
WEIGHTS_FORMAT = "nudge.weights/1"
"""Generator weights (``.safetensors``), read by the Rust predictor."""

BENCH_NS = (2, 4, 8, 16, 32)
"""Agent counts of the predictor benchmark's scenes (crates/predictor/benches/data/scenes.safetensors)."""
