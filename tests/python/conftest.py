"""Shared fixtures of the nudge._native binding tests: the shipped models and scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import nudge

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def scenes() -> list[Path]:
    paths = nudge.scene_paths()
    assert len(paths) >= 2, "the shipped scenes (assets/scenes) are missing"
    return paths


@pytest.fixture(scope="session")
def teacher_path() -> Path:
    return nudge.model_path("teacher")


@pytest.fixture(scope="session")
def student_path() -> Path:
    return nudge.model_path("student")


@pytest.fixture(scope="session")
def teacher(teacher_path: Path) -> nudge.Predictor:
    return nudge.Predictor.load(teacher_path)


@pytest.fixture(scope="session")
def student(student_path: Path) -> nudge.Predictor:
    return nudge.Predictor.load(student_path)


@pytest.fixture(scope="session")
def scenario(scenes: list[Path]) -> nudge.Scenario:
    """The shipped scene with the most agents (a dense one)."""
    loaded = [nudge.Scenario.load(p) for p in scenes]
    return max(loaded, key=lambda s: (s.n_agents, s.name))


def straight_candidates(sc: nudge.Scenario, batch: int, horizon: int = 6) -> np.ndarray:
    """``[batch, horizon, 2]`` ego candidates: constant speed, lateral offsets spread over ±2 m."""
    x0, y0 = sc.history[0, -1]
    v = float(sc.speed[0])
    k = np.arange(1, horizon + 1) * nudge.DT
    dy = np.linspace(-2.0, 2.0, batch)
    out = np.empty((batch, horizon, 2))
    out[..., 0] = x0 + v * k[None, :]
    out[..., 1] = y0 + dy[:, None] * (k[None, :] / k[-1])
    return out
