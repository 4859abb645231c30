"""CommonRoad in and out from Python: the Rust reader's road frame equals the data pipeline's
(``nudge_train.data.commonroad``, the independent truth) on every shared CommonRoad file, to
1 mm / 1 mrad; a scenario built from a CommonRoad file equals the shipped one the pipeline
made; a solution's first state is the ego's own logged state in the file's coordinates."""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import nudge
from nudge._native import commonroad_tracks

REPO = Path(__file__).resolve().parents[2]
NGSIM = Path(os.environ.get("NUDGE_NGSIM") or REPO.parent / "shared" / "data" / "ngsim")
FIXTURE = REPO / "python/train/tests/fixtures/commonroad/USA_US101-1_1_T-1.xml.gz"
SHARED = sorted((NGSIM / "us101").glob("commonroad_us101_*/*.xml.gz"))


def test_shared_commonroad_files_are_present() -> None:
    assert len(SHARED) >= 60, f"CommonRoad files under {NGSIM}/us101: {len(SHARED)} (NUDGE_NGSIM)"


@pytest.mark.parametrize("path", [FIXTURE, *SHARED], ids=lambda p: p.name)
def test_road_frame_equals_the_pipelines(path: Path) -> None:
    from nudge_train.data.commonroad import read_commonroad
    from nudge_train.data.errors import DataError

    try:
        want = read_commonroad(path, frame="straightened")  # the Rust reader's frame
    except DataError as err:  # the pipeline refuses it: so must the Rust reader
        with pytest.raises(nudge.ScenarioError):
            commonroad_tracks(path)
        pytest.skip(f"refused by both: {err}")
    got = commonroad_tracks(path)
    steps = np.rint(want.t / want.dt).astype(np.int64)
    np.testing.assert_array_equal(got["vehicle"], want.vehicle)
    np.testing.assert_array_equal(got["step"], steps)
    np.testing.assert_allclose(got["x"], want.x, rtol=0, atol=1e-3)
    np.testing.assert_allclose(got["y"], want.y, rtol=0, atol=1e-3)
    dh = (got["heading"] - want.heading + math.pi) % (2 * math.pi) - math.pi
    assert np.max(np.abs(dh)) < 1e-3
    np.testing.assert_array_equal(got["speed"], want.speed)
    assert len(got["pieces"]) == len(want.lanes.pieces)
    for (x0, x1, b), (w0, w1, wb) in zip(got["pieces"], want.lanes.pieces, strict=True):
        assert abs(x0 - w0) < 1e-3 and abs(x1 - w1) < 1e-3
        np.testing.assert_allclose(b, wb, rtol=0, atol=1e-3)


CURVED_FIXTURE = REPO / "python/train/tests/fixtures/commonroad/USA_US101-26_1_T-1_cut.xml.gz"


@pytest.mark.parametrize("path", [CURVED_FIXTURE, *SHARED], ids=lambda p: p.name)
def test_curvilinear_frame_equals_the_pipelines(path: Path) -> None:
    """The curvilinear frame nudge plans in on curved roads equals the pipeline's ``frenet`` frame
    (``nudge_train.data.frenet``, the independent truth) on every state, to 1 mm / 1 mrad."""
    from nudge_train.data.commonroad import read_commonroad

    want = read_commonroad(path, frame="frenet")
    got = commonroad_tracks(path, curvilinear=True)
    steps = np.rint(want.t / want.dt).astype(np.int64)
    np.testing.assert_array_equal(got["vehicle"], want.vehicle)
    np.testing.assert_array_equal(got["step"], steps)
    np.testing.assert_allclose(got["x"], want.x, rtol=0, atol=1e-3)
    np.testing.assert_allclose(got["y"], want.y, rtol=0, atol=1e-3)
    dh = (got["heading"] - want.heading + math.pi) % (2 * math.pi) - math.pi
    assert np.max(np.abs(dh)) < 1e-3


def test_scenario_from_commonroad_equals_the_shipped_one() -> None:
    shipped = nudge.Scenario.load(REPO / "assets/scenes/us101-11_1-t02.1-ego132.safetensors")
    src = NGSIM / "us101/commonroad_us101_T-1/USA_US101-11_1_T-1.xml.gz"
    got = nudge.commonroad_scenario(src, ego=132, t0=2.1)
    np.testing.assert_allclose(got.history, shipped.history, rtol=0, atol=1e-3)
    np.testing.assert_array_equal(got.agent_ids, shipped.agent_ids)
    np.testing.assert_allclose(got.lane_bounds, shipped.lane_bounds, rtol=0, atol=1e-3)


def _logged(path: Path, ego: int, step: int) -> tuple[float, float, float]:
    import gzip

    root = ET.fromstring(gzip.decompress(path.read_bytes()))
    ob = next(o for o in root.iter("dynamicObstacle") if o.get("id") == str(ego))
    for st in [ob.find("initialState"), *ob.findall("trajectory/state")]:
        if int(st.findtext("time/exact")) == step:
            return (float(st.findtext("position/point/x")), float(st.findtext("position/point/y")),
                    float(st.findtext("orientation/exact")))
    raise AssertionError(f"no state {step}")


def test_solution_starts_at_the_logged_state_in_file_coordinates(tmp_path: Path) -> None:
    """The first KS state is the ego's logged centre at t0 in the file's own frame, moved from
    nudge's centre of gravity (rear axle + l_r) to CommonRoad's (rear axle + b of vehicle type
    2, 1.4227 m): the inverse of the road frame against the file itself. The 2 cm shift is made
    in the straightened road frame, whose scale differs from the file's by < 1e-3 here: 10 µm."""
    out = tmp_path / "solution.xml"
    info = nudge.commonroad_solution(FIXTURE, out, np.zeros(7), np.zeros(7), ego=484)
    assert info["benchmark_id"] == "KS2:SM1:USA_US101-1_1_T-1:2020a" and info["n_states"] == 22
    first = ET.parse(out).getroot().find("ksTrajectory/ksState")
    step = int(first.findtext("time"))
    x, y, psi = _logged(FIXTURE, 484, step)
    shift = 1.4227170936 - nudge.PlannerSettings().model["l_r"]
    assert abs(float(first.findtext("x")) - (x + shift * math.cos(psi))) < 1e-5
    assert abs(float(first.findtext("y")) - (y + shift * math.sin(psi))) < 1e-5
    assert abs(float(first.findtext("orientation")) - psi) < 1e-6


def test_bad_arguments_are_typed_errors(tmp_path: Path) -> None:
    with pytest.raises(nudge.InputError):
        nudge.commonroad_scenario(FIXTURE, ego=484, planning_problem=1)
    with pytest.raises(nudge.ScenarioError, match="obstacle 7: no dynamic obstacle"):
        nudge.commonroad_scenario(FIXTURE, ego=7)
    with pytest.raises(nudge.ScenarioError, match="no such|No such|not found|os error"):
        nudge.commonroad_scenario(tmp_path / "missing.xml", ego=1)
    with pytest.raises(nudge.InputError):
        nudge.commonroad_solution(FIXTURE, tmp_path / "s.xml", np.zeros(3), np.zeros(4), ego=484)
