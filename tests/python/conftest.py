"""Shared fixtures of the nudge._native binding tests: the shipped models and scenes."""

from __future__ import annotations

import threading
import time
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


def spin_ticks_while_planning(pl: nudge.Planner, sc: nudge.Scenario) -> tuple[int, int]:
    """(ticks, plans): how often a spinning Python thread ran while ``pl`` planned ``sc`` over
    and over for at least 0.5 s (and at least twice). With the GIL held for a whole plan the
    spinner would run only at the switch points between calls, a handful of ticks per plan."""
    ticks = 0
    stop = threading.Event()

    def spin() -> None:
        nonlocal ticks
        while not stop.is_set():
            ticks += 1
            time.sleep(0)

    t = threading.Thread(target=spin)
    t.start()
    try:
        t0 = time.perf_counter()
        n_plans = 0
        before = ticks
        while time.perf_counter() - t0 < 0.5 or n_plans < 2:
            pl.reset()
            pl.plan_scenario(sc)
            n_plans += 1
        during = ticks - before
    finally:
        stop.set()
        t.join()
    return during, n_plans
