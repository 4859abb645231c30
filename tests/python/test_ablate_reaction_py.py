"""The planner setting ``ablate_reaction`` from Python: described and round-tripped like every
setting; in closed loop a constant-velocity planner (whose prediction never depends on the ego)
runs the same with it on, and a learned planner calls its predictor at most once per step."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import nudge

TIMING = {"mpc_s", "z_s", "z_median_s"}


def test_setting_is_described_with_its_default() -> None:
    assert nudge.PlannerSettings.default().safety["ablate_reaction"] is False
    s = nudge.PlannerSettings(safety={"ablate_reaction": True})
    assert s.safety["ablate_reaction"] is True
    assert nudge.PlannerSettings.from_json(s.to_json()) == s
    row = next(r for r in nudge.PlannerSettings.describe() if r["field"] == "safety.ablate_reaction")
    assert row["default"] is False and row["range"] == "true or false"
    assert "keep-lane" in row["doc"]


def test_constant_velocity_runs_are_unaffected(scenes: list[Path]) -> None:
    kw = {"seed": 3, "runs": 2, "threads": 1, "max_steps": 6}
    on = nudge.simulate(scenes[:3], "constant_velocity", settings=nudge.PlannerSettings(safety={"ablate_reaction": True}), **kw)
    off = nudge.simulate(scenes[:3], "constant_velocity", **kw)
    for table in ("runs", "steps"):
        for k, v in off[table].items():
            if k in TIMING or k == "predictor_calls":
                continue
            if isinstance(v, np.ndarray):
                np.testing.assert_array_equal(on[table][k], v, err_msg=f"{table}.{k}")
            else:
                assert on[table][k] == v, f"{table}.{k}"
    assert np.all(on["steps"]["predictor_calls"] <= 1)
    assert np.any(off["steps"]["predictor_calls"] > 1)


def test_ablated_student_calls_its_predictor_once_per_step(scenes: list[Path]) -> None:
    r = nudge.simulate(scenes[:2], "student", settings=nudge.PlannerSettings(safety={"ablate_reaction": True}), runs=1,
                       threads=1, max_steps=4)
    assert np.all(r["steps"]["predictor_calls"] <= 1)
