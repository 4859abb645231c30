"""Your own planner in nudge's worlds (nudge.simulate(..., planner=obj)): it sees the closed
loop's state, its inputs are applied as given (no clamping), a bad plan or an exception stops
the run with a typed error naming scene, seed and step, and the records are those of nudge's
own runs (same columns, metrics)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import nudge

T = 6


class Constant:
    """Steers `delta` and accelerates `accel` at every step; keeps every observation."""

    def __init__(self, delta: float = 0.0, accel: float = 0.0) -> None:
        self.delta, self.accel = delta, accel
        self.observations: list[dict] = []
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def plan(self, obs: dict) -> dict:
        self.observations.append({k: (np.array(v) if isinstance(v, np.ndarray) else v) for k, v in obs.items()})
        return {"delta": [self.delta] * obs["horizon"], "accel": np.full(obs["horizon"], self.accel)}


def test_the_inputs_are_applied_and_the_observation_is_the_closed_loop_state(scenes: list[Path]) -> None:
    p = Constant(delta=0.0, accel=0.5)
    r = nudge.simulate(scenes[:2], "constant_velocity", planner=p, world="log_replay", max_steps=4, seed=3)
    runs, steps = r["runs"], r["steps"]
    assert p.resets == 2 and runs["error"] == [None, None]
    assert runs["predictor"] == ["constant_velocity"] * 2
    np.testing.assert_array_equal(steps["accel"], 0.5)
    np.testing.assert_array_equal(steps["delta"], 0.0)
    assert set(steps["status"]) <= {"Converged", "Unsafe"}
    np.testing.assert_array_equal(steps["iterations"], 0)
    assert np.isnan(steps["cost"]).all()
    # Every step was planned outside nudge, and says so (nudge's own planner never does).
    assert len(steps["decided_by"]) == int(runs["n_steps"].sum()) > 0
    assert set(steps["decided_by"]) == {"external"}
    own = nudge.simulate(scenes[:1], "constant_velocity", world="log_replay", max_steps=2, seed=3)
    assert "external" not in set(own["steps"]["decided_by"])
    obs = p.observations
    assert [o["step"] for o in obs] == list(range(int(runs["n_steps"][0]))) + list(range(int(runs["n_steps"][1])))
    for i, path in enumerate(scenes[:2]):
        sc = nudge.Scenario.load(path)
        first = next(o for o in obs if o["scenario"] == sc.name)
        assert first["seed"] == 3 + i and first["horizon"] == T and first["dt"] == nudge.DT
        np.testing.assert_array_equal(first["history"], sc.history)
        np.testing.assert_array_equal(first["ego"][:2], sc.history[0, -1])
        assert first["ego"][3] == sc.speed[0] and first["last_inputs"].tolist() == [0.0, 0.0]
        np.testing.assert_array_equal(first["lane_centres"], sc.lane_centres)
        np.testing.assert_array_equal(first["lane_bounds"], sc.lane_bounds)
        np.testing.assert_array_equal(first["sizes"], sc.size)
        assert first["bounds"] == {"delta_max": 0.15, "a_min": -5.0, "a_max": 3.0}
    # Step k's observed ego is the state step k - 1 left it in, and the inputs it applied.
    run0 = steps["run"] == 0
    ego = steps["ego"][run0]
    for k in range(1, int(runs["n_steps"][0])):
        np.testing.assert_allclose(obs[k]["ego"], ego[k - 1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(obs[k]["history"][0, -1], ego[k - 1, :2], rtol=0, atol=1e-12)
        assert obs[k]["last_inputs"].tolist() == [0.0, 0.5]
    # Straight ahead: speed grows by a * dt every step, heading unchanged.
    v0 = obs[0]["ego"][3]
    np.testing.assert_allclose(ego[:, 3], v0 + 0.5 * nudge.DT * np.arange(1, len(ego) + 1), rtol=1e-12)
    np.testing.assert_allclose(ego[:, 2], obs[0]["ego"][2], rtol=0, atol=1e-12)


def test_the_same_planner_gives_the_same_records(scenes: list[Path]) -> None:
    a = nudge.simulate(scenes[:2], "student", planner=Constant(accel=-0.3), max_steps=3)
    b = nudge.simulate(scenes[:2], "student", planner=Constant(accel=-0.3), max_steps=3)
    for table in ("runs", "steps"):
        for k, v in a[table].items():
            if k not in ("mpc_s", "z_s", "z_median_s"):
                np.testing.assert_array_equal(np.asarray(v), np.asarray(b[table][k]), err_msg=k)


class Raising:
    def plan(self, obs: dict) -> dict:
        if obs["step"] == 2:
            raise ValueError("no plan today")
        return {"delta": [0.0] * T, "accel": [0.0] * T}


def test_an_exception_stops_the_run_naming_scene_seed_and_step(scenes: list[Path]) -> None:
    name = nudge.Scenario.load(scenes[0]).name
    with pytest.raises(nudge.NudgeError, match=rf"Raising.*{name}, seed 5, step 2.*ValueError: no plan today") as e:
        nudge.simulate(scenes[:1], "constant_velocity", planner=Raising(), seed=5, max_steps=5, world="log_replay")
    assert isinstance(e.value.__cause__, ValueError)
    r = nudge.simulate(scenes[:1], "constant_velocity", planner=Raising(), max_steps=5, on_error="skip")
    assert "no plan today" in r["runs"]["error"][0]


class Returns:
    def __init__(self, plan: object) -> None:
        self.value = plan

    def plan(self, obs: dict) -> object:
        return self.value


@pytest.mark.parametrize(("plan", "why"), [
    ({"delta": [0.0] * 5, "accel": [0.0] * T}, r'"delta": expected 6 values \(the horizon\), got 5'),
    ({"delta": [0.0] * T}, r'no "accel"'),
    ({"delta": [0.0] * T, "accel": [0.0] * 5 + [float("nan")]}, r'"accel"\[5\] is not finite'),
    ({"delta": [0.2] + [0.0] * 5, "accel": [0.0] * T}, r'"delta"\[0\] = 0.2 is outside \[-0.15, 0.15\]'),
    ({"delta": [0.0] * T, "accel": [-6.0] * T}, r'"accel"\[0\] = -6 is outside \[-5, 3\]'),
    ([0.0] * T, "expected a mapping"),
    ({"delta": "abc", "accel": [0.0] * T}, r'"delta": expected 6 floats'),
])
def test_an_unusable_plan_is_refused_by_name(scenes: list[Path], plan: object, why: str) -> None:
    with pytest.raises(nudge.InputError, match=rf"Returns.*seed 0, step 0.*unusable plan: {why}"):
        nudge.simulate(scenes[:1], "constant_velocity", planner=Returns(plan), max_steps=2)


def test_a_planner_needs_plan_and_one_thread(scenes: list[Path]) -> None:
    with pytest.raises(nudge.InputError, match="no method `plan`"):
        nudge.simulate(scenes[:1], planner=object())
    with pytest.raises(nudge.InputError, match=r"a Python planner plans on one thread \(its runs share the object\), got 2$"):
        nudge.simulate(scenes[:1], planner=Constant(), threads=2)


class _Predicts:
    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        return np.zeros((len(candidates), len(history) - 1, candidates.shape[1], 2))


def test_the_thread_count_is_named_without_debug_text(scenes: list[Path]) -> None:
    # It read "got Some(2)" (Rust debug text of an Option) before.
    with pytest.raises(nudge.InputError, match=r"a Python predictor plans on one thread .*, got 2$"):
        nudge.simulate(scenes[:1], _Predicts(), threads=2)
