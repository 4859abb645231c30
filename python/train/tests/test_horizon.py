"""A planning horizon of 10 steps (3 s) with the teacher and constant velocity; the student's fixed
6-step decoder refused with a typed error naming the horizon.

Truth: the PyTorch teacher (``teacher_interactive``, float64) rolled out recursively over 10 steps on
the very histories and candidates the Rust planner asked its predictor about.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import torch

import nudge
from nudge_train import paths
from nudge_train.models.interactive import teacher_interactive
from nudge_train.training.export import load_generator, read_weights

TEACHER = paths.model_weights("teacher")
STUDENT = paths.model_weights("student")
HORIZON = 10
# The Rust teacher runs its network in float32 and feeds each step's prediction into the next, so the
# rounding compounds over the roll-out: within 1e-5 m of the float64 PyTorch roll-out through step 7,
# 1.9e-5 m at step 10 on the golden scenes (crates/predictor/tests/predictor_parity.rs, LONG_TOL).
LONG_TOL = 2.5e-5
CALLS_CHECKED = 6  # predictor calls of one plan compared with PyTorch (each roll-out takes a while)


class Recording:
    """A Python predictor that hands the planner the native teacher's predictions and keeps every
    (history, candidates, prediction) it was asked about."""

    def __init__(self, native: nudge.Predictor) -> None:
        self.native = native
        self.horizon = native.horizon
        self.calls: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        out = self.native.predict(history, candidates)
        self.calls.append((np.array(history), np.array(candidates), np.array(out)))
        return out


def _settings(horizon: int) -> nudge.PlannerSettings:
    return nudge.PlannerSettings(model={"horizon": horizon})


def _scenes() -> list[Path]:
    return nudge.scene_paths()[:2]


def test_teacher_planner_at_horizon_10_predicts_as_the_pytorch_roll_out() -> None:
    if not read_weights(TEACHER).trained:
        pytest.skip("untrained teacher")
    teacher = nudge.Predictor.load(TEACHER, horizon=HORIZON)
    assert teacher.horizon == HORIZON
    gen64 = copy.deepcopy(load_generator(TEACHER, "cpu")).to(torch.float64)
    for path in _scenes():
        sc = nudge.Scenario.load(path)
        built_in = nudge.Planner(_settings(HORIZON), teacher).plan_scenario(sc)
        rec = Recording(teacher)
        plan = nudge.Planner(_settings(HORIZON), predictor=rec).plan_scenario(sc)
        # The same predictions make the same plan, bit for bit: 10 states and inputs.
        for k in ("delta", "accel", "states"):
            np.testing.assert_array_equal(plan[k], built_in[k], err_msg=k)
        assert plan["states"].shape == (HORIZON, 4) and plan["delta"].shape == (HORIZON,)
        assert rec.calls, "the planner asked its predictor"
        # The plan itself was among the candidates checked (its positions at steps 1..10).
        xy = plan["states"][:, :2]
        checked = [(h, c[i : i + 1], o[i : i + 1]) for h, c, o in rec.calls for i in range(len(c))
                   if np.array_equal(c[i], xy)]
        assert checked, f"{path.name}: the final plan was never predicted"
        # The plan's prediction and calls spread over the solve: the PyTorch 10-step roll-out.
        spread = [rec.calls[i] for i in np.linspace(0, len(rec.calls) - 1, CALLS_CHECKED).astype(int)]
        for h, c, o in [*checked[:1], *spread]:
            assert c.shape[1:] == (HORIZON, 2) and o.shape[2:] == (HORIZON, 2)
            want = teacher_interactive(gen64, torch.from_numpy(h), torch.from_numpy(c), horizon=HORIZON).numpy()
            err = float(np.abs(o - want).max())
            assert err <= LONG_TOL, f"{path.name}: |rust − pytorch| = {err:.2e} m over {HORIZON} steps"


def test_constant_velocity_planner_at_horizon_10() -> None:
    sc = nudge.Scenario.load(_scenes()[0])
    plan = nudge.Planner(_settings(HORIZON), nudge.Predictor.constant_velocity(HORIZON)).plan_scenario(sc)
    assert plan["states"].shape == (HORIZON, 4)


def test_student_refuses_horizon_10_naming_it() -> None:
    with pytest.raises(nudge.InputError, match=r"student predicts exactly 6 steps; horizon 10 steps"):
        nudge.Predictor.load(STUDENT, horizon=HORIZON)
    student = nudge.Predictor.load(STUDENT)
    with pytest.raises(nudge.SettingsError, match=r"`model.horizon` = 10 does not fit: the student predicts 6 steps"):
        nudge.Planner(_settings(HORIZON), student)
    with pytest.raises(nudge.SettingsError, match=r"`model.horizon` = 10 does not fit: the student predicts 6 steps"):
        nudge.simulate(_scenes()[:1], "student", settings=_settings(HORIZON), max_steps=1, threads=1)


def test_closed_loop_at_horizon_10_in_every_world() -> None:
    """``nudge.simulate`` (what ``nudge-train closed-loop`` and ``interaction`` call) at 10 steps:
    the teacher and constant-velocity planners, the teacher and idm worlds."""
    for predictor in ("teacher", "constant_velocity"):
        for world in ("teacher", "idm"):
            r = nudge.simulate(_scenes()[:1], predictor, world=world, settings=_settings(HORIZON), max_steps=2,
                               threads=1)
            assert not any(r["runs"]["error"]), r["runs"]["error"]
            assert len(r["steps"]["step"]) >= 1


@pytest.mark.parametrize("horizon", [0, 61, -1])
def test_a_horizon_out_of_range_is_refused_naming_it(horizon: int) -> None:
    with pytest.raises(nudge.InputError, match="horizon"):
        nudge.Predictor.load(TEACHER, horizon=horizon)
