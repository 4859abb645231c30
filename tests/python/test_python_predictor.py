"""Your own predictor from Python: nudge.Planner(settings, predictor=obj) and
nudge.simulate(..., predictor=obj) with any object with predict(history, candidates).

The truth for the plans is the built-in constant-velocity predictor: a Python object computing
the same float64 arithmetic (last + k * (last - prev), as crates/predictor's ConstantVelocity)
hands the planner bit-identical predictions, and the planner is deterministic, so the plans
must agree bit for bit (no tolerance)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import nudge
from conftest import spin_ticks_while_planning

MAX_STEP = 30.0  # m per 0.3 s step (nudge_predictor::limits::MAX_STEP)
STATUSES = {"Converged", "MaxIterations", "Refined", "Unsafe", "BudgetExhausted", "Backtracked", "Fallback",
            "SolverFailed"}
PLAN_KEYS = ("delta", "accel", "states", "admm_states")
SCALAR_KEYS = ("cost", "iterations", "predictor_calls", "refused_candidates", "qp_solves", "primal_residual",
               "change_residual", "min_safety", "rollout_min_safety", "checked", "status")


class ConstantVelocity:
    """Every other agent keeps its last observed displacement per step, whatever the ego does."""

    def __init__(self) -> None:
        self.scenes = 0
        self.calls: list[tuple[tuple[int, ...], tuple[int, ...]]] = []

    def set_scene(self, history: np.ndarray) -> None:
        self.scenes += 1

    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        self.calls.append((history.shape, candidates.shape))
        last, prev = history[1:, -1], history[1:, -2]
        k = np.arange(1, candidates.shape[1] + 1, dtype=np.float64)[None, :, None]
        one = last[:, None, :] + k * (last - prev)[:, None, :]
        return np.broadcast_to(one, (candidates.shape[0], *one.shape))


class CuttingIn(ConstantVelocity):
    """Constant velocity plus a lateral drift of 0.2 m per step towards the candidate (an
    interaction-aware toy whose prediction depends on the candidate)."""

    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        out = np.array(super().predict(history, candidates))
        y = np.broadcast_to(history[1:, -1, 1], (candidates.shape[0], history.shape[0] - 1)).copy()
        vy = history[1:, -1, 1] - history[1:, -2, 1]
        for k in range(candidates.shape[1]):
            y = y + vy + np.clip(candidates[:, None, k, 1] - y, -0.2, 0.2)
            out[:, :, k, 1] = y
        return out


def _assert_same_plan(a: dict[str, Any], b: dict[str, Any]) -> None:
    for k in PLAN_KEYS:
        assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k
    for k in SCALAR_KEYS:
        assert a[k] == b[k], (k, a[k], b[k])


def test_python_constant_velocity_plans_as_the_built_in_one(scenes: list[Path]) -> None:
    settings = nudge.PlannerSettings.default()
    for path in scenes[:6]:
        sc = nudge.Scenario.load(path)
        ours = ConstantVelocity()
        built_in = nudge.Planner(settings, nudge.Predictor.constant_velocity())
        python = nudge.Planner(settings, predictor=ours)
        a, b = built_in.plan_scenario(sc), python.plan_scenario(sc)
        _assert_same_plan(a, b)
        # The warm-started second call too.
        _assert_same_plan(built_in.plan_scenario(sc, seed=1), python.plan_scenario(sc, seed=1))
        assert b["predictor_calls"] > 0
        assert sum(c[0] for _, c in ours.calls) >= b["predictor_calls"]


def test_python_predictor_is_handed_the_documented_arrays(scenario: nudge.Scenario) -> None:
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    order: list[str] = []

    class Recorder(ConstantVelocity):
        def set_scene(self, history: np.ndarray) -> None:
            order.append("set_scene")
            assert history.shape == (scenario.n_agents, nudge.T_OBS, 2)

        def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
            order.append("predict")
            seen.append((history, candidates.copy()))
            return super().predict(history, candidates)

    plan = nudge.Planner(None, predictor=Recorder()).plan_scenario(scenario)
    assert order[0] == "set_scene" and order.count("set_scene") == 1 and len(order) > 1
    history, _ = seen[0]
    assert all(h is history for h, _ in seen), "one history array per planning step"
    assert history.dtype == np.float64 and not history.flags.writeable
    np.testing.assert_array_equal(history, scenario.history)
    ego = scenario.history[0, -1]
    for _, cand in seen:
        assert cand.dtype == np.float64 and cand.ndim == 3 and cand.shape[1:] == (6, 2)
        # Ego positions at steps 1..6 after the last observed one (m): within reach of it.
        assert np.all(np.abs(cand[:, 0] - ego).max(axis=-1) < 15.0)
    # The returned plan's states are one of the candidates' trajectories' neighbourhood.
    assert plan["states"].shape == (6, 4)


def test_python_predictor_in_simulate_runs_as_the_built_in_one(scenes: list[Path]) -> None:
    kw: dict[str, Any] = dict(world="teacher", max_steps=4, seed=3)
    a = nudge.simulate(scenes[:2], "constant_velocity", **kw)
    ours = ConstantVelocity()
    b = nudge.simulate(scenes[:2], ours, **kw)
    assert b["runs"]["predictor"] == ["python", "python"]
    assert ours.scenes == int(b["steps"]["run"].size)
    for k in ("x", "y", "psi", "v", "delta", "accel", "cost", "iterations", "predictor_calls"):
        assert np.array_equal(a["steps"][k], b["steps"][k]), k
    for k in ("success", "collision", "n_steps", "target_lane"):
        assert np.array_equal(a["runs"][k], b["runs"][k]), k


def test_python_predictor_is_deterministic(scenario: nudge.Scenario, scenes: list[Path]) -> None:
    plans = [nudge.Planner(None, predictor=CuttingIn()).plan_scenario(scenario) for _ in range(2)]
    _assert_same_plan(*plans)
    # It is interaction-aware: the plan differs from constant velocity's.
    cv = nudge.Planner(None, predictor=ConstantVelocity()).plan_scenario(scenario)
    assert not np.array_equal(plans[0]["states"], cv["states"])
    runs = [nudge.simulate(scenes[:2], CuttingIn(), world="log_replay", max_steps=3, record=True)
            for _ in range(2)]
    for k in ("x", "y", "delta", "accel", "cost"):
        assert np.array_equal(runs[0]["steps"][k], runs[1]["steps"][k]), k
    ex = runs[0]["examples"]
    assert ex["candidate"].shape[0] > 0 and ex["prediction"].shape[1:] == (6, 2)


def test_torch_tensor_predictions_are_accepted(scenario: nudge.Scenario) -> None:
    torch = pytest.importorskip("torch")

    class Torch(ConstantVelocity):
        def predict(self, history: np.ndarray, candidates: np.ndarray) -> Any:
            return torch.tensor(super().predict(history, candidates))  # a copy

    _assert_same_plan(nudge.Planner(None, predictor=ConstantVelocity()).plan_scenario(scenario),
                      nudge.Planner(None, predictor=Torch()).plan_scenario(scenario))


class _Raising(ConstantVelocity):
    def __init__(self, exc: BaseException, where: str = "predict") -> None:
        super().__init__()
        self.exc, self.where = exc, where

    def set_scene(self, history: np.ndarray) -> None:
        if self.where == "set_scene":
            raise self.exc

    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        if self.where == "predict":
            raise self.exc
        return super().predict(history, candidates)


@pytest.mark.parametrize("where", ["predict", "set_scene"])
def test_an_exception_in_the_predictor_is_the_cause(scenario: nudge.Scenario, where: str) -> None:
    boom = ValueError("boom")
    pl = nudge.Planner(None, predictor=_Raising(boom, where))
    with pytest.raises(nudge.PredictorError, match=rf"_Raising\.{where}\(history.*ValueError: boom") as e:
        pl.plan_scenario(scenario)
    assert e.value.__cause__ is boom
    # The planner stays usable.
    ok = nudge.Planner(None, predictor=ConstantVelocity()).plan_scenario(scenario)
    assert ok["states"].shape == (6, 4)


def test_an_exception_in_simulate_is_the_cause(scenes: list[Path]) -> None:
    boom = RuntimeError("boom in a run")
    with pytest.raises(nudge.PredictorError, match=r"step 0: .*RuntimeError: boom in a run") as e:
        nudge.simulate(scenes[:2], _Raising(boom), world="log_replay", max_steps=3)
    assert e.value.__cause__ is boom
    out = nudge.simulate(scenes[:2], _Raising(boom), world="log_replay", max_steps=3, on_error="skip")
    assert all("RuntimeError: boom in a run" in m for m in out["runs"]["error"])


def test_keyboard_interrupt_in_predict_passes_through(scenario: nudge.Scenario) -> None:
    with pytest.raises(KeyboardInterrupt):
        nudge.Planner(None, predictor=_Raising(KeyboardInterrupt())).plan_scenario(scenario)


def _returning(value: Any) -> ConstantVelocity:
    class Returning(ConstantVelocity):
        def predict(self, history: np.ndarray, candidates: np.ndarray) -> Any:
            good = np.array(super().predict(history, candidates))
            return value(good) if callable(value) else value

    return Returning()


def _poke(v: float) -> Any:
    def f(p: np.ndarray) -> np.ndarray:
        p[0, 2, 4, 1] = v  # candidate 0, agent 3, step 5, y
        return p

    return f


@pytest.mark.parametrize(
    "value, message",
    [
        (lambda p: p[:, 1:], r"prediction: expected shape \[1, \d+, 6, 2\], got \[1, \d+, 6, 2\]"),
        (lambda p: p[..., :5, :], r"prediction: expected shape"),
        (lambda p: p[0], r"prediction: expected shape"),
        (lambda p: p.astype(np.int64), r"expected a float64 \(or float32\).*int64"),
        (None, r"numpy.asarray|expected a float64"),
        ("six", r"expected a float64|numpy.asarray"),
        (_poke(np.nan), r"non-finite position \(NaN\) for agent 3 at step 5 \(candidate 0\)"),
        (_poke(np.inf), r"non-finite position \(inf\) for agent 3 at step 5 \(candidate 0\)"),
        (_poke(1e6), r"implausible motion for agent 3 at step 5 \(candidate 0\)"),
    ],
    ids=["agents", "horizon", "rank", "int64", "none", "str", "nan", "inf", "implausible"],
)
def test_an_unusable_prediction_is_refused_naming_the_item(
    scenario: nudge.Scenario, value: Any, message: str
) -> None:
    assert scenario.n_agents > 4
    with pytest.raises(nudge.PredictorError, match=message) as e:
        nudge.Planner(None, predictor=_returning(value)).plan_scenario(scenario)
    assert e.value.__cause__ is None


def test_float32_predictions_are_accepted(scenario: nudge.Scenario) -> None:
    plan = nudge.Planner(None, predictor=_returning(lambda p: p.astype(np.float32))).plan_scenario(scenario)
    assert plan["states"].shape == (6, 4)


class _NoPredict:
    def set_scene(self, history: np.ndarray) -> None: ...


class _NotCallable:
    predict = 3


@pytest.mark.parametrize(
    "obj, message",
    [
        (object(), r"predictor object: no method `predict`"),
        (_NoPredict(), r"_NoPredict: no method `predict`"),
        (_NotCallable(), r"_NotCallable: `predict` is not a method"),
    ],
)
def test_an_object_without_predict_is_refused(obj: object, message: str, scenes: list[Path]) -> None:
    with pytest.raises(nudge.PredictorError, match=message):
        nudge.Planner(None, predictor=obj)
    with pytest.raises(nudge.PredictorError, match=message):
        nudge.simulate(scenes[:1], obj, world="log_replay", max_steps=2)


@pytest.mark.parametrize("horizon", [0, 61, "six", 2.5, -1])
def test_a_bad_horizon_attribute_is_refused(horizon: object) -> None:
    class H(ConstantVelocity):
        pass

    p = H()
    p.horizon = horizon  # type: ignore[attr-defined]
    with pytest.raises(nudge.PredictorError, match=r"`horizon` must be an int in 1..=60"):
        nudge.Planner(None, predictor=p)


def test_the_horizon_attribute_must_fit_the_settings(scenario: nudge.Scenario, scenes: list[Path]) -> None:
    p = ConstantVelocity()
    p.horizon = 5  # type: ignore[attr-defined]
    with pytest.raises(nudge.SettingsError, match=r"`model.horizon` = 6 does not fit: the Python predictor predicts 5 steps"):
        nudge.Planner(None, predictor=p)
    with pytest.raises(nudge.SettingsError, match=r"`model.horizon` = 6 does not fit"):
        nudge.simulate(scenes[:1], p, world="log_replay", max_steps=2)
    s = nudge.PlannerSettings.default().replace(model={"horizon": 5})
    plan = nudge.Planner(s, predictor=p).plan_scenario(scenario)
    assert plan["states"].shape == (5, 4)


def test_simulate_with_a_python_predictor_runs_on_one_thread(scenes: list[Path]) -> None:
    with pytest.raises(nudge.InputError, match=r"`threads`: a Python predictor plans on one thread"):
        nudge.simulate(scenes[:2], ConstantVelocity(), threads=2, world="log_replay", max_steps=2)
    out = nudge.simulate(scenes[:2], ConstantVelocity(), threads=1, world="log_replay", max_steps=2)
    assert out["runs"]["n_steps"].sum() > 0


def test_the_planner_returns_the_object_it_was_given(scenario: nudge.Scenario) -> None:
    p = ConstantVelocity()
    pl = nudge.Planner(None, predictor=p)
    assert pl.predictor is p and repr(pl) == 'Planner(predictor="python")'


def test_gil_is_released_outside_the_python_predictor(scenario: nudge.Scenario) -> None:
    """A Python thread keeps running while another thread plans with a Python predictor: the
    GIL is held only inside its calls."""
    pl = nudge.Planner(None, predictor=ConstantVelocity())
    during, n_plans = spin_ticks_while_planning(pl, scenario)
    # A plan holding the GIL throughout would let the spinner run only at the switch between
    # two plans (a few ticks each). Since `Planner.plan` runs on a worker thread (the caller
    # waits for it and for Ctrl-C) the spinner shares the GIL with two threads: 44-90 ticks per
    # plan measured on a 2-core machine, so the bound is 25.
    assert during > 25 * n_plans, (during, n_plans)


def _first_implausible(history: np.ndarray, pred: np.ndarray) -> tuple[int, int] | None:
    """(agent, step) of the first displacement above MAX_STEP of a [n - 1, horizon, 2]
    prediction, in the order agent, step (step 1 measured from the last observed position)."""
    for i, traj in enumerate(pred):
        path = np.concatenate([history[i + 1, -1:], traj])
        steps = np.hypot(*np.diff(path, axis=0).T)
        bad = np.flatnonzero(steps > MAX_STEP)
        if bad.size:
            return i + 1, int(bad[0]) + 1
    return None


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(data=st.data())
def test_any_corrupted_prediction_is_refused_by_name_or_planned(scenario: nudge.Scenario,
                                                               data: st.DataObject) -> None:
    """Oracle: a corrupted value is refused iff it is non-finite or moves its agent more than
    MAX_STEP in a step (computed here), naming that agent and step; a wrong shape or dtype is
    always refused; anything else plans."""
    sc = scenario.nearest(3)
    n = sc.n_agents
    kind = data.draw(st.sampled_from(["value", "shape", "dtype"]), label="kind")
    if kind == "value":
        agent, step = data.draw(st.integers(1, n - 1)), data.draw(st.integers(1, 6))
        coord = data.draw(st.integers(0, 1))
        # A non-finite value, or the right one moved by up to 60 m (2 x MAX_STEP) or 1e9 m.
        value = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]), label="value") if data.draw(
            st.booleans()) else None
        offset = data.draw(st.floats(-60, 60) | st.floats(-1e9, 1e9), label="offset")
    elif kind == "shape":
        shape = tuple(data.draw(st.lists(st.integers(0, 7), min_size=1, max_size=5), label="shape"))
    else:
        dtype = data.draw(st.sampled_from([np.int32, np.int64, np.float16, np.complex128, np.bool_, object]))

    def corrupt(p: np.ndarray) -> Any:
        if kind == "value":
            p[:, agent - 1, step - 1, coord] = value if value is not None else p[0, agent - 1, step - 1, coord] + offset
            return p
        if kind == "shape":
            return np.zeros(shape)
        return p.astype(dtype)

    if kind == "shape" and shape == (1, n - 1, 6, 2):
        return  # the right shape: not a corruption
    history = sc.history
    planner = nudge.Planner(None, predictor=_returning(corrupt))
    expected = None
    if kind == "value":
        good = np.array(ConstantVelocity().predict(history, np.zeros((1, 6, 2))))[0]
        good[agent - 1, step - 1, coord] = value if value is not None else good[agent - 1, step - 1, coord] + offset
        if value is not None:
            expected = rf"non-finite position \({value:g}\)".replace("nan", "NaN") + rf" for agent {agent} at step {step}\b"
        elif (bad := _first_implausible(history, good)) is not None:
            expected = rf"implausible motion for agent {bad[0]} at step {bad[1]} "
    else:
        expected = r"returned an unusable prediction"
    if expected is None:
        plan = planner.plan_scenario(sc)
        assert plan["status"] in STATUSES and np.isfinite(plan["states"]).all()
        return
    with pytest.raises(nudge.PredictorError, match=expected):
        planner.plan_scenario(sc)


_REENTRANT = r'''
import sys
import numpy as np
import nudge

class CallsBack:
    """A predictor that calls back into the planner it serves (issue 49 class 3)."""

    def __init__(self, what):
        self.what, self.planner, self.inner = what, None, None

    def predict(self, history, candidates):
        if self.inner is None:
            try:
                if self.what == "plan_scenario":
                    self.planner.plan_scenario(self.scenario)
                elif self.what == "reset":
                    self.planner.reset()
                else:
                    self.planner.settings
            except nudge.NudgeError as e:
                self.inner = e
                raise
        last, prev = history[1:, -1], history[1:, -2]
        k = np.arange(1, candidates.shape[1] + 1, dtype=np.float64)[None, :, None]
        one = last[:, None, :] + k * (last - prev)[:, None, :]
        return np.broadcast_to(one, (candidates.shape[0], *one.shape))

sc = nudge.Scenario.load(nudge.scene_paths()[0])
p = CallsBack(sys.argv[1])
pl = nudge.Planner(None, predictor=p)
p.planner, p.scenario = pl, sc
try:
    pl.plan_scenario(sc)
    print("NO ERROR")
except nudge.PredictorError as e:
    print("OUTER", type(e).__name__, "CAUSE", type(e.__cause__).__name__, str(e.__cause__))
# The planner stays usable afterwards (the lock is released).
p.inner = "done"
print("AFTER", pl.plan_scenario(sc)["states"].shape)
'''


@pytest.mark.parametrize("what", ["plan_scenario", "reset", "settings"])
def test_a_predictor_calling_back_into_its_planner_gets_a_typed_error(tmp_path: Path, what: str) -> None:
    """Before: the planner's lock was taken again by the same thread and the interpreter froze
    (SIGINT never handled). Now the re-entrant call raises ReentrancyError, which the outer
    plan reports as the PredictorError's cause; run in a child process so a regression cannot
    hang the suite."""
    import subprocess
    import sys

    script = tmp_path / "reentrant.py"
    script.write_text(_REENTRANT)
    try:
        out = subprocess.run([sys.executable, str(script), what], capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"a predictor calling Planner.{what} from predict deadlocked")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("OUTER PredictorError CAUSE ReentrancyError"), out.stdout
    assert "re-entrant" in lines[0] and f"Planner.{what}" in lines[0], lines[0]
    assert lines[1] == "AFTER (6, 4)", out.stdout
