"""Lanes that begin and end through the Python front end: Planner.plan takes the lane layout
(a plan past a lane's end is inadmissible and names the state), bad layouts raise InputError
naming the lane and field, and simulate's run columns carry the outcome."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

import nudge

BOUNDS = np.array([-1.85, 1.85, 5.55])
# Lane 0 (the ego's) really ends at x = 120 m; lane 1 runs on.
EXTENTS = np.array([[-500.0, 120.0], [-500.0, 2000.0]])
REAL = np.array([[False, True], [False, False]])


def _plan(x0: float, y_target: float, **lanes: object) -> dict:
    """One call with the ego alone at (x0, 0), 20 m/s, aiming at ``y_target``."""
    history = np.array([[[x0 - 20.0 * 0.3 * (7 - t), 0.0] for t in range(8)]])
    planner = nudge.Planner(None, nudge.Predictor.constant_velocity())
    return planner.plan(history, [[4.5, 1.9]], [x0, 0.0, 0.0, 20.0], y_target, 20.0,
                        (-1.85, 5.55), **lanes)


def test_a_plan_past_the_end_is_inadmissible_and_named() -> None:
    # Staying in lane 0 5 m before its end at 20 m/s: every state past 120 m is in the ended lane.
    free = _plan(115.0, 0.0)
    assert free["lane_violation"] is None and free["status"] != "Unsafe"
    stuck = _plan(115.0, 0.0, lane_bounds=BOUNDS, lane_extents=EXTENTS, lane_extent_real=REAL)
    v = stuck["lane_violation"]
    if v is not None:
        assert stuck["status"] == "Unsafe"
        assert (v["lane"], v["kind"]) == (0, "Ended") and v["x"] > 120.0 and v["step"] >= 1
    else:
        # The repairs found a plan that leaves the lane sideways before the end: every planned
        # state in lane 0 lies before 120 m.
        for x, y, _, _ in stuck["states"]:
            assert y >= 1.85 or x <= 120.0
    # Far from the end the layout changes nothing, bit for bit.
    far = _plan(-400.0, 3.7)
    far_lanes = _plan(-400.0, 3.7, lane_bounds=BOUNDS, lane_extents=EXTENTS, lane_extent_real=REAL)
    np.testing.assert_array_equal(far["states"], far_lanes["states"])
    assert far["cost"] == far_lanes["cost"]


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"lane_bounds": BOUNDS}, "both or neither"),
        ({"lane_extent_real": REAL}, "without lane_bounds"),
        ({"lane_bounds": BOUNDS, "lane_extents": np.array([[-500.0, 120.0], [np.nan, 2000.0]])}, "lane 1 begin"),
        ({"lane_bounds": BOUNDS, "lane_extents": np.array([[-500.0, 120.0], [300.0, 200.0]])}, "lane 1 end"),
        ({"lane_bounds": BOUNDS[::-1].copy(), "lane_extents": EXTENTS}, "lane 0 bounds"),
        ({"lane_bounds": BOUNDS, "lane_extents": EXTENTS, "lane_extent_real": np.array([[0, 2], [0, 0]])}, "flag 2"),
        ({"lane_bounds": BOUNDS[:2], "lane_extents": EXTENTS}, "lane_bounds"),
    ],
)
def test_bad_layouts_raise_input_error_naming_lane_and_field(kw: dict, match: str) -> None:
    with pytest.raises(nudge.InputError, match=match):
        _plan(0.0, 3.7, **kw)


def test_simulate_reports_the_outcome(scenes: list[Path]) -> None:
    r = nudge.simulate(scenes[:2], "constant_velocity", world="log_replay", threads=1, max_steps=6)
    runs = r["runs"]
    assert len(runs["outcome"]) == 2
    for ok, collision, outcome in zip(runs["success"], runs["collision"], runs["outcome"], strict=True):
        want = "Success" if ok else ("Collision" if collision else "Unfinished")
        assert outcome == want


_value = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-600.0, max_value=2100.0),
    st.sampled_from([-1.85, 1.85, 5.55, 120.0, 1e300, -0.0]),
)


@seed(14)
@settings(max_examples=60, deadline=None, database=None)
@given(
    n_lanes=st.integers(min_value=0, max_value=4),
    n_bounds_delta=st.sampled_from([1, 1, 1, 0, 2]),
    data=st.data(),
)
def test_arbitrary_layouts_give_a_plan_or_an_input_error(n_lanes: int, n_bounds_delta: int,
                                                          data: st.DataObject) -> None:
    """Any layout (non-finite, unordered, the wrong number of boundaries, odd flags): a plan
    whose ``lane_violation`` is None or names a lane of the layout, or InputError; never
    another exception."""
    bounds = np.array(data.draw(st.lists(_value, min_size=n_lanes + n_bounds_delta,
                                         max_size=n_lanes + n_bounds_delta)), dtype=np.float64)
    extents = np.array(data.draw(st.lists(_value, min_size=2 * n_lanes, max_size=2 * n_lanes)),
                       dtype=np.float64).reshape(n_lanes, 2)
    real = np.array(data.draw(st.lists(st.sampled_from([0, 1, 1, 2]), min_size=2 * n_lanes,
                                       max_size=2 * n_lanes)), dtype=np.int64).reshape(n_lanes, 2)
    try:
        out = _plan(100.0, 3.7, lane_bounds=bounds, lane_extents=extents, lane_extent_real=real)
    except nudge.InputError:
        return
    v = out["lane_violation"]
    assert v is None or (0 <= v["lane"] < n_lanes and v["kind"] in ("Ended", "NotBegun"))


def _beside_an_ending_lane(tmp_path: Path, ahead: float) -> Path:
    """The first shipped scene (ego in lane 1 of 5) as "nudge.scenario/2" with lane 0 really
    ending ``ahead`` m ahead of the ego, every other lane running through."""
    from safetensors import safe_open
    from safetensors.numpy import save_file

    src = nudge.scene_paths()[0]
    with safe_open(str(src), "np") as f:
        meta = f.metadata()
        t = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 (safe_open is not a mapping)
    assert int(t["ego_lane"][0]) == 1
    n_lanes = len(t["lane_centres"])
    x0 = float(t["history"][0, -1, 0])
    extent = np.tile([-1e4, 1e4], (n_lanes, 1))
    extent[0, 1] = x0 + ahead
    real = np.zeros((n_lanes, 2), dtype=np.uint8)
    real[0, 1] = 1
    t["lane_extent"], t["lane_extent_real"] = extent, real
    out = tmp_path / f"ending_{ahead:.0f}.safetensors"
    save_file(t, str(out), metadata={**meta, "schema": "nudge.scenario/2"})
    return out


def test_the_target_lane_is_one_rule_for_scenario_and_simulate(tmp_path: Path) -> None:
    """``Scenario.target_lane`` and the run's ``target_lane`` column come from the one Rust
    rule: a lane that really ends within the run's reach (max_steps · dt · v + deadline
    distance) is never drawn; a short run with a short deadline distance may draw it."""
    path = _beside_an_ending_lane(tmp_path, 60.0)
    sc = nudge.Scenario.load(path)
    seeds = range(16)
    assert {sc.target_lane(s) for s in seeds} == {2}
    short = nudge.SimConfig(max_steps=1, world="log_replay")
    near = nudge.PlannerSettings(lane_ends={"deadline_distance": 10.0})
    drawn = [sc.target_lane(s, near, short) for s in seeds]
    assert set(drawn) == {0, 2}
    # The draw of a scene without real ends, seed for seed.
    plain = nudge.Scenario.load(nudge.scene_paths()[0])
    assert drawn == [plain.target_lane(s) for s in seeds]
    for settings_, config in ((None, nudge.SimConfig(world="log_replay", max_steps=1)), (near, short)):
        r = nudge.simulate([path] * len(seeds), "constant_velocity", scene_seeds=list(seeds), threads=1,
                           settings=settings_, config=config)
        assert r["runs"]["target_lane"].tolist() == [sc.target_lane(s, settings_, config) for s in seeds]
    planner = nudge.Planner(near, nudge.Predictor.constant_velocity())
    assert [planner.plan_scenario(sc, seed=s, config=short)["target_lane"] for s in seeds[:4]] == drawn[:4]
    assert planner.plan_scenario(sc, seed=1)["target_lane"] == 2
