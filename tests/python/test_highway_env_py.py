"""nudge.adapters.highway: nudge as the ego's controller in highway-env, checked against
highway-env's own state (positions, headings, lane indices, its recorded vehicle histories, its
action mapping and its vehicle model) and end to end on short episodes."""

from __future__ import annotations

import math
import os

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import given, seed, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import nudge  # noqa: E402
from nudge.adapters.highway import (  # noqa: E402
    HighwayAdapterError,
    HistoryBuffer,
    LaneLayout,
    NudgeHighwayController,
    action_from_inputs,
    env_config,
    inputs_from_action,
    make_env,
    planner_settings,
    run_episode,
    to_highway,
    to_nudge,
)

BOUNDS = planner_settings().bounds
finite = st.floats(-1e4, 1e4, allow_nan=False)


def _env(**config: object):
    return make_env("highway-v0", config={"vehicles_count": 15, "duration": 40, **config})


@pytest.fixture(scope="module")
def student() -> nudge.Predictor:
    return nudge.Predictor.load(nudge.model_path("student"))


# ---- frames and actions -----------------------------------------------------------------------


@seed(50)
@settings(max_examples=200, deadline=None)
@given(finite, finite, st.floats(-math.pi, math.pi))
def test_the_mirror_is_its_own_inverse_and_flips_y_and_heading(x: float, y: float, h: float) -> None:
    xn, yn, psin = to_nudge(x, y, h)
    assert (xn, yn, psin) == (x, -y, -h)
    assert to_highway(xn, yn, psin) == (x, y, h)


@seed(50)
@settings(max_examples=200, deadline=None)
@given(st.floats(-0.15, 0.15), st.floats(-5.0, 3.0))
def test_actions_round_trip_and_match_highway_envs_own_mapping(delta: float, accel: float) -> None:
    action = action_from_inputs(delta, accel, BOUNDS)
    assert np.all(np.abs(action) <= 1.0 + 1e-12)
    d, a = inputs_from_action(action, BOUNDS)
    assert d == pytest.approx(delta, abs=1e-12) and a == pytest.approx(accel, abs=1e-12)


def test_highway_env_applies_nudges_inputs_with_the_steering_mirrored() -> None:
    env = _env()
    env.reset(seed=0)
    for delta, accel in [(0.15, 3.0), (-0.15, -5.0), (0.07, -1.25), (0.0, 0.0)]:
        got = env.unwrapped.action_type.get_action(action_from_inputs(delta, accel, BOUNDS))
        assert got["steering"] == pytest.approx(-delta, abs=1e-12)
        assert got["acceleration"] == pytest.approx(accel, abs=1e-12)


def test_a_step_is_three_frames_of_a_tenth_of_a_second() -> None:
    cfg = env_config()
    assert cfg["simulation_frequency"] == pytest.approx(10.0)
    assert int(cfg["simulation_frequency"] // cfg["policy_frequency"]) == 3
    env = _env()
    env.reset(seed=0)
    env.step(action_from_inputs(0.0, 0.0, BOUNDS))
    assert env.unwrapped.steps == 3
    assert env.unwrapped.time == pytest.approx(nudge.DT, abs=1e-12)


def _bicycle(z: np.ndarray, delta: float, accel: float, dt: float, l: float) -> np.ndarray:  # noqa: E741
    """One Euler step of the kinematic bicycle of docs (PLANNER.md), l_f = l_r = l, nudge frame."""
    beta = math.atan(0.5 * math.tan(delta))
    x, y, psi, v = z
    return np.array([x + dt * v * math.cos(psi + beta), y + dt * v * math.sin(psi + beta), psi + dt * v * math.sin(beta) / l, v + dt * accel])


def test_the_ego_moves_as_nudges_bicycle_in_nudges_frame() -> None:
    """Positive steering turns the ego left (nudge y up) as nudge's model says, to 1e-9 m."""
    env = _env()
    env.reset(seed=3)
    ego = env.unwrapped.vehicle
    z = np.array([*[float(c) for c in to_nudge(ego.position[0], ego.position[1], ego.heading)], float(ego.speed)])
    for delta, accel in [(0.1, 1.0), (0.1, 0.0), (-0.05, -2.0)]:
        env.step(action_from_inputs(delta, accel, BOUNDS))
        for _ in range(3):
            z = _bicycle(z, delta, accel, 0.1, 2.5)
        got = to_nudge(ego.position[0], ego.position[1], ego.heading)
        assert np.allclose([*got, ego.speed], z, atol=1e-9), (got, z)
    assert z[1] > -float(env.unwrapped.road.network.get_lane(ego.lane_index).start[1])  # moved left


# ---- lanes ------------------------------------------------------------------------------------


def test_lanes_are_mirrored_against_highway_envs_lane_indices() -> None:
    env = _env(lanes_count=4, vehicles_count=30)
    env.reset(seed=1)
    u = env.unwrapped
    lay = LaneLayout.from_road(u.road, float(u.vehicle.position[1]))
    assert lay.n_lanes == 4
    assert np.allclose(lay.centres, [-12.0, -8.0, -4.0, 0.0])
    assert np.allclose(lay.bounds, [-14.0, -10.0, -6.0, -2.0, 2.0])
    assert not lay.extent_real.any()
    for _ in range(5):
        env.step(action_from_inputs(0.0, 0.0, BOUNDS))
    for v in u.road.vehicles:
        _, yn, _ = to_nudge(v.position[0], v.position[1], v.heading)
        assert lay.lane_of(float(yn)) == 3 - v.lane_index[2], (v.position, v.lane_index)
        assert lay.from_highway_lane(float(u.road.network.get_lane(v.lane_index).start[1])) == 3 - v.lane_index[2]


def test_merges_lanes_begin_and_end_where_highway_env_puts_them() -> None:
    import gymnasium as gym

    env = gym.make("merge-v1")  # its own discrete actions: see the next test
    env.reset(seed=0)
    u = env.unwrapped
    lay = LaneLayout.from_road(u.road, float(u.vehicle.position[1]))
    merge = u.road.network.get_lane(("b", "c", 2))
    assert np.allclose(lay.centres, [-merge.start[1], -4.0, 0.0])
    assert np.allclose(lay.extents[0], [merge.start[0], merge.end[0]])
    main_end = u.road.network.get_lane(("c", "d", 0)).end[0]
    assert np.allclose(lay.extents[1:], [[0.0, main_end], [0.0, main_end]])
    assert lay.extent_real.tolist() == [[True, True], [False, False], [False, False]]


def test_merge_envs_reward_refuses_continuous_actions() -> None:
    """Why the merge envs are not driven (docs/highway_env.md): highway-env's MergeEnv reward
    tests ``action in [0, 2]`` (its discrete meta-actions), which fails on any action array,
    already when the env is made (its reset's info holds the reward terms of a sampled action).
    When a highway-env release fixes it, this fails: add the merge envs to the adapter."""
    with pytest.raises(ValueError, match="truth value of an array"):
        make_env("merge-v1")


# ---- history ----------------------------------------------------------------------------------


def test_the_history_is_the_envs_recorded_positions_every_third_frame(student: nudge.Predictor) -> None:
    env = _env(show_trajectories=True)  # highway-env then records every vehicle at every frame
    env.reset(seed=2)
    ctrl = NudgeHighwayController(env, predictor=student)
    ctrl.reset()
    u = env.unwrapped
    first = {id(v): (v.position.copy(), v.heading, v.speed) for v in u.road.vehicles}
    for step in range(10):
        action = ctrl.act()
        if step == 0:
            # Padding: constant velocity along the heading, backwards from the first state.
            for v in u.road.vehicles:
                p, h, s = first[id(v)]
                x, y, psi = to_nudge(p[0], p[1], h)
                want = np.array([[x - k * 0.3 * s * math.cos(psi), y - k * 0.3 * s * math.sin(psi)] for k in range(7, -1, -1)])
                assert np.allclose(ctrl.history.history(id(v)), want, atol=1e-12)
                assert ctrl.history.padded(id(v)) == 7
        env.step(action)
    ctrl.act()  # records the state after the 10th step
    for v in u.road.vehicles:
        hist = ctrl.history.history(id(v))
        assert ctrl.history.padded(id(v)) == 0
        for j in range(8):
            rec = v.history[3 * j]  # highway-env's record 3 frames (0.3 s) per step back
            x, y, _ = to_nudge(rec.position[0], rec.position[1], rec.heading)
            assert np.allclose(hist[-1 - j], [x, y], atol=1e-12), (j, hist[-1 - j], rec.position)


def test_history_records_must_be_one_step_apart() -> None:
    buf = HistoryBuffer()
    buf.record(0.0, {1: np.array([0.0, 0.0, 0.0, 10.0])})
    with pytest.raises(HighwayAdapterError, match="0.3 s apart"):
        buf.record(0.0, {1: np.array([0.0, 0.0, 0.0, 10.0])})
    buf.record(0.3, {2: np.array([5.0, 1.0, 0.0, 10.0])})
    assert 1 not in buf and 2 in buf  # a vehicle no longer seen is dropped


# ---- configuration errors ---------------------------------------------------------------------


def test_an_env_not_configured_for_nudge_is_refused_naming_the_field(student: nudge.Predictor) -> None:
    import gymnasium as gym

    with pytest.raises(HighwayAdapterError, match="'type'"):
        NudgeHighwayController(gym.make("highway-v0"), predictor=student)
    cfg = env_config()
    cfg["action"] = {**cfg["action"], "steering_range": [-0.785, 0.785]}
    with pytest.raises(HighwayAdapterError, match="steering_range"):
        NudgeHighwayController(gym.make("highway-v0", config=cfg), predictor=student)
    cfg = env_config()
    cfg["action"] = {**cfg["action"], "clip": True}
    with pytest.raises(HighwayAdapterError, match="'clip'"):
        NudgeHighwayController(gym.make("highway-v0", config=cfg), predictor=student)
    cfg = env_config()
    cfg["policy_frequency"] = 1
    with pytest.raises(HighwayAdapterError, match="policy_frequency"):
        NudgeHighwayController(gym.make("highway-v0", config=cfg), predictor=student)
    with pytest.raises(HighwayAdapterError, match="l_f"):
        NudgeHighwayController(_env(), settings=nudge.PlannerSettings.default(), predictor=student)
    with pytest.raises(HighwayAdapterError, match="simulation_frequency"):
        make_env("highway-v0", config={"simulation_frequency": 15})


# ---- end to end -------------------------------------------------------------------------------


def test_nudge_drives_the_ego_to_the_lane_and_speed_it_is_given(student: nudge.Predictor) -> None:
    env = _env(initial_lane_id=1, vehicles_count=5)
    ctrl = NudgeHighwayController(env, predictor=student, target_lane=0, v_ref=20.0)
    r = run_episode(env, ctrl, seed=4, max_steps=30)
    ego = env.unwrapped.vehicle
    assert not r.crashed and r.steps == 30
    assert ego.lane_index[2] == 0 and r.lane_changes == 1  # highway-env's own lane index
    assert abs(ego.position[1] - 0.0) < 0.5 and abs(ego.heading) < 0.05
    assert ego.speed < 22.0  # from 25 m/s towards 20
    assert r.out_of_range == 0 and len(ctrl.stats.actions) == 30
    assert sum(ctrl.stats.statuses.values()) == 30


def test_the_lane_rule_leaves_a_slow_lane_for_a_free_faster_one(student: nudge.Predictor) -> None:
    env = _env(vehicles_count=1)
    env.reset(seed=0)
    ctrl = NudgeHighwayController(env, predictor=student)
    ctrl.reset()
    ego = np.array([100.0, -4.0, 0.0, 25.0])  # nudge lane 2 (highway-env lane 1)
    slow = (np.array([130.0, -4.0, 0.0, 15.0]), 5.0)
    assert ctrl.target(ego, [slow], 30.0) == (1, 2)  # both free: the right one
    right_blocked = (np.array([95.0, -8.0, 0.0, 25.0]), 5.0)
    assert ctrl.target(ego, [slow, right_blocked], 30.0) == (1, 2)  # the change holds once chosen
    ctrl.reset()
    assert ctrl.target(ego, [slow, right_blocked], 30.0) == (3, 2)  # right lane taken: left
    ctrl.reset()
    left_blocked = (np.array([110.0, 0.0, 0.0, 25.0]), 5.0)
    assert ctrl.target(ego, [slow, right_blocked, left_blocked], 30.0) == (2, None)
    ctrl.reset()
    assert ctrl.target(ego, [(np.array([130.0, -4.0, 0.0, 29.0]), 5.0)], 30.0) == (2, None)  # no advantage


def test_the_lane_rule_settles_after_a_change_and_takes_an_ego_off_the_road_as_in_the_edge_lane(
    student: nudge.Predictor,
) -> None:
    env = _env(vehicles_count=1)
    env.reset(seed=0)
    ctrl = NudgeHighwayController(env, predictor=student)
    ctrl.reset()
    ego = np.array([100.0, -4.0, 0.0, 25.0])
    assert ctrl.target(ego, [(np.array([130.0, -4.0, 0.0, 15.0]), 5.0)], 30.0) == (1, 2)
    arrived = np.array([130.0, -7.8, 0.0, 25.0])  # within 0.5 m of lane 1's centre
    slow = (np.array([160.0, -7.8, 0.0, 15.0]), 5.0)  # lanes 0 and 2 are free and faster
    for _ in range(ctrl.lane_rule.settle_steps):
        assert ctrl.target(arrived, [slow], 30.0) == (1, None)
    assert ctrl.target(arrived, [slow], 30.0) == (0, 1)  # settled: the rule looks again
    ctrl.reset()
    beyond = np.array([100.0, -14.3, -0.1, 25.0])  # right edge at -14 m
    assert ctrl.layout.lane_of(-14.3) is None
    assert ctrl.target(beyond, [], 30.0) == (0, None)


def test_an_action_outside_the_range_is_recorded_and_sent_unclamped(student: nudge.Predictor) -> None:
    env = _env()
    env.reset(seed=0)
    ctrl = NudgeHighwayController(env, predictor=student)
    ctrl.reset()

    class Over:
        def plan(self, *args: object, **kwargs: object) -> dict:
            return {"delta": np.full(6, 0.2), "accel": np.full(6, 0.0), "status": "Converged"}

        def reset(self) -> None:
            pass

    ctrl.planner = Over()
    action = ctrl.act()
    assert ctrl.stats.out_of_range == [(0, "steering", pytest.approx(-0.2 / 0.15))]
    assert env.unwrapped.action_type.get_action(action)["steering"] == pytest.approx(-0.2)


def _actions(student: nudge.Predictor, seed: int) -> tuple[np.ndarray, np.ndarray]:
    env = _env()
    ctrl = NudgeHighwayController(env, predictor=student)
    run_episode(env, ctrl, seed=seed, max_steps=12)
    return np.array(ctrl.stats.actions), np.array(env.unwrapped.vehicle.position)


def test_episodes_are_deterministic_given_the_seed(student: nudge.Predictor) -> None:
    a1, p1 = _actions(student, 7)
    a2, p2 = _actions(student, 7)
    assert np.array_equal(a1, a2) and np.array_equal(p1, p2)
    a3, _ = _actions(student, 8)
    assert not np.array_equal(a1, a3)


def test_the_dev_venv_installs_the_highway_extra_as_pyproject_states_it() -> None:
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    extra = re.search(r"^highway = \[(.*)\]", (root / "pyproject.toml").read_text(), flags=re.M)
    assert extra is not None, "pyproject.toml has no extra `highway`"
    assert extra[1].strip(), "the extra `highway` is empty"
    make = (root / "Makefile").read_text()
    extras = re.search(r"^DEV_EXTRAS := (.*)$", make, flags=re.M)
    assert extras is not None and "highway" in extras[1].split(), "the dev venv skips `highway`"
    recipe = re.search(r"^\$\(ENV_STAMP\):.*\n((?:\t.*\n)+)", make, flags=re.M)
    assert recipe is not None and "optional-dependencies" in recipe[1], "extras not read from pyproject"
    assert "$(DEV_EXTRAS)" in recipe[1]
