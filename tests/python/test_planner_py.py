"""nudge.Scenario and nudge.Planner: one MPC call on a scenario or on raw arrays, bad input,
and the GIL released while planning."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import nudge
from conftest import spin_ticks_while_planning


def test_scenario_fields(scenario: nudge.Scenario) -> None:
    n = scenario.n_agents
    assert scenario.history.shape == (n, 8, 2)
    assert scenario.heading.shape == scenario.speed.shape == (n,)
    assert scenario.size.shape == (n, 2) and (scenario.size > 0).all()
    f = scenario.future.shape[1]
    assert scenario.future.shape == (n, f, 2) and scenario.future_valid.shape == (n, f)
    assert scenario.future_valid.dtype == np.bool_
    assert scenario.lane_bounds.shape == (scenario.lane_centres.shape[0] + 1,)
    assert scenario.road == (scenario.lane_bounds[0], scenario.lane_bounds[-1])
    assert scenario.metadata["schema"] == "nudge.scenario/1"
    assert scenario.agent_ids.dtype == np.int64
    lane = scenario.target_lane(0)
    assert abs(lane - scenario.ego_lane) == 1
    near = scenario.nearest(2)
    assert near.n_agents == 3 and near.name.startswith(scenario.name)


def test_scenario_errors(tmp_path: Path) -> None:
    with pytest.raises(nudge.ScenarioError, match="missing.safetensors"):
        nudge.Scenario.load(tmp_path / "missing.safetensors")
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"garbage")
    with pytest.raises(nudge.ScenarioError, match="bad.safetensors"):
        nudge.Scenario.load(bad)


def _rollout(ego: np.ndarray, delta: np.ndarray, accel: np.ndarray, s: nudge.PlannerSettings) -> np.ndarray:
    """The kinematic bicycle (speed clamped at 0), written here independently of the Rust one."""
    x, y, psi, v = (float(c) for c in ego)
    out = []
    for d, a in zip(delta, accel):
        beta = np.arctan(s.model["l_r"] / (s.model["l_f"] + s.model["l_r"]) * np.tan(d))
        x, y, psi, v = (x + s.model["dt"] * v * np.cos(psi + beta), y + s.model["dt"] * v * np.sin(psi + beta),
                        psi + s.model["dt"] * v * np.sin(beta) / s.model["l_r"], max(v + s.model["dt"] * a, 0.0))
        out.append((x, y, psi, v))
    return np.array(out)


def _check_plan(plan: dict, ego: np.ndarray, s: nudge.PlannerSettings, horizon: int = 6) -> None:
    """Shapes, and what each status promises about the returned plan."""
    assert plan["states"].shape == (horizon, 4)
    assert plan["delta"].shape == plan["accel"].shape == (horizon,)
    assert np.isfinite(plan["states"]).all()
    assert plan["timings"]["total_s"] > 0
    status = plan["status"]
    # One Z-update per ADMM iteration, except the one a QP failure interrupts.
    assert plan["timings"]["z_updates_s"].shape == (plan["iterations"] - (status == "SolverFailed"),)
    assert (plan["solver_failure"] is None) == (status != "SolverFailed")
    assert plan["admm_states"].shape == ((0, 4) if status == "SolverFailed" else (horizon, 4))
    # Every plan's states are its inputs' roll-out, and its safety is that roll-out's.
    np.testing.assert_allclose(plan["states"], _rollout(ego, plan["delta"], plan["accel"], s), atol=1e-9)
    assert plan["min_safety"] == plan["rollout_min_safety"]
    assert (plan["min_safety"] is None) == (plan["checked"] == 0)
    if status == "Converged":
        assert plan["primal_residual"] <= s.admm["eps_primal"] or plan["iterations"] < s.admm["max_iter"]
    if status == "MaxIterations":
        assert plan["iterations"] == s.admm["max_iter"]
    if status != "Unsafe":
        # Admissible: safe, heading within its bound (the ego starts inside it here), on the road.
        assert plan["min_safety"] is None or plan["min_safety"] > s.safety["safety_min"]
        assert (np.abs(plan["states"][:, 2]) <= s.bounds["heading_max"] + 1e-9).all(), plan["states"][:, 2]
    assert status in ("Converged", "MaxIterations", "Refined", "Backtracked", "Fallback",
                      "SolverFailed", "BudgetExhausted", "Unsafe"), status


def test_plan_scenario_and_raw_arrays_agree(teacher: nudge.Predictor, scenario: nudge.Scenario) -> None:
    s = nudge.PlannerSettings.default()
    p1 = nudge.Planner(s, teacher).plan_scenario(scenario, seed=3)
    ego = np.array([*scenario.history[0, -1], scenario.heading[0], scenario.speed[0]])
    _check_plan(p1, ego, s)
    assert p1["target_lane"] == scenario.target_lane(3)
    assert p1["predictor_calls"] > 0
    assert p1["refused_candidates"] == 0
    p2 = nudge.Planner(s, teacher).plan(scenario.history, scenario.size, ego, p1["y_target"],
                                       float(scenario.speed[0]), scenario.road)
    for k in ("states", "delta", "accel"):
        np.testing.assert_array_equal(p1[k], p2[k])
    assert p1["cost"] == p2["cost"] and p1["iterations"] == p2["iterations"]


def test_every_status_keeps_its_promise(scenes: list[Path], student: nudge.Predictor) -> None:
    """One cold-start plan per shipped scene, student and constant velocity: every status seen
    keeps what it promises (several statuses occur on these scenes)."""
    s = nudge.PlannerSettings.default()
    seen = set()
    for path in scenes:
        sc = nudge.Scenario.load(path)
        ego = np.array([*sc.history[0, -1], sc.heading[0], sc.speed[0]])
        for predictor in (student, nudge.Predictor.constant_velocity()):
            plan = nudge.Planner(s, predictor).plan_scenario(sc, seed=0)
            _check_plan(plan, ego, s)
            seen.add(plan["status"])
    assert len(seen) >= 3, seen  # several statuses, each checked above


def test_settings_that_would_overflow_a_qp_are_refused(scenario: nudge.Scenario) -> None:
    """w_a = 1e308 used to overflow the acceleration QP (the Rust unit test
    `qp_failure_ends_in_a_checked_fallback_plan` still forces that failure and checks the
    `SolverFailed` plan); validation now refuses such a weight, naming it, and an ordinary plan
    reports no solver failure."""
    with pytest.raises(nudge.SettingsError, match="w_a"):
        nudge.PlannerSettings(cost={"w_a": 1e308})
    plan = nudge.Planner(None, nudge.Predictor.constant_velocity()).plan_scenario(scenario, seed=0)
    assert plan["status"] != "SolverFailed" and plan["solver_failure"] is None


def test_planner_is_deterministic_and_reset_restores_cold_start(student: nudge.Predictor,
                                                                scenario: nudge.Scenario) -> None:
    pl = nudge.Planner(None, student)
    a = pl.plan_scenario(scenario, target_lane=scenario.target_lane(0))
    pl.reset()
    b = pl.plan_scenario(scenario, target_lane=scenario.target_lane(0))
    np.testing.assert_array_equal(a["states"], b["states"])
    assert pl.predictor.name == "student" and pl.settings == nudge.PlannerSettings.default()


def test_horizon_mismatch_and_bad_lane(scenario: nudge.Scenario) -> None:
    # Refused when the planner is built, before any plan (nudge_planner::fit).
    with pytest.raises(nudge.SettingsError, match="`model.horizon` = 5 does not fit: the constant_velocity predicts 6"):
        nudge.Planner(nudge.PlannerSettings(model={"horizon": 5}), nudge.Predictor.constant_velocity(6))
    pl6 = nudge.Planner(None, nudge.Predictor.constant_velocity())
    with pytest.raises(nudge.InputError, match="target_lane 99"):
        pl6.plan_scenario(scenario, target_lane=99)


@settings(max_examples=30, deadline=None)
@given(field=st.sampled_from(["history", "sizes", "ego"]), kind=st.sampled_from(["nan", "shape", "dtype", "strided"]))
def test_plan_bad_arrays(scenario: nudge.Scenario, field: str, kind: str) -> None:
    pl = nudge.Planner(None, nudge.Predictor.constant_velocity())
    args = {
        "history": scenario.history.copy(),
        "sizes": scenario.size.copy(),
        "ego": np.array([*scenario.history[0, -1], scenario.heading[0], scenario.speed[0]]),
    }
    if kind == "strided":
        # Non-contiguous views are fine: the plan equals the contiguous one.
        ref = pl.plan(args["history"], args["sizes"], args["ego"], float(scenario.lane_centres[0]),
                      float(scenario.speed[0]), scenario.road)
        wide = np.repeat(args[field][..., None], 2, axis=-1)[..., 0]
        assert not wide.flags.c_contiguous or wide.ndim == 1
        args[field] = wide
        pl.reset()
        out = pl.plan(args["history"], args["sizes"], args["ego"], float(scenario.lane_centres[0]),
                      float(scenario.speed[0]), scenario.road)
        np.testing.assert_array_equal(out["states"], ref["states"])
        return
    if kind == "nan":
        args[field].reshape(-1)[0] = np.nan
    elif kind == "shape":
        args[field] = args[field][..., :1]
    else:
        args[field] = args[field].astype(np.int32)
    with pytest.raises(nudge.InputError, match=field):
        pl.plan(args["history"], args["sizes"], args["ego"], float(scenario.lane_centres[0]),
                float(scenario.speed[0]), scenario.road)


def test_plan_non_finite_scalars(scenario: nudge.Scenario) -> None:
    pl = nudge.Planner(None, nudge.Predictor.constant_velocity())
    ego = np.array([*scenario.history[0, -1], scenario.heading[0], scenario.speed[0]])
    with pytest.raises(nudge.InputError, match="y_target"):
        pl.plan(scenario.history, scenario.size, ego, float("nan"), 20.0, scenario.road)
    with pytest.raises(nudge.InputError, match="road"):
        pl.plan(scenario.history, scenario.size, ego, 0.0, 20.0, (float("inf"), 1.0))


def test_gil_is_released_while_planning(teacher: nudge.Predictor, scenario: nudge.Scenario) -> None:
    """A Python thread keeps running while another thread is inside plan()."""
    pl = nudge.Planner(None, teacher)
    during, n_plans = spin_ticks_while_planning(pl, scenario)
    assert during > 50 * n_plans, (during, n_plans)
