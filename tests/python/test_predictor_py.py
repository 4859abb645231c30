"""nudge.Predictor: loading, shapes, dtypes, NaN, non-contiguous arrays, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import nudge

from conftest import straight_candidates


def test_names_and_horizon(teacher: nudge.Predictor, student: nudge.Predictor) -> None:
    assert teacher.name == "teacher" and student.name == "student"
    assert teacher.horizon == student.horizon == 6
    cv = nudge.Predictor.constant_velocity()
    assert cv.name == "constant_velocity" and cv.horizon == 6
    assert "teacher" in repr(teacher)


@pytest.mark.parametrize("which", ["teacher", "student", "cv"])
def test_predict_shape_dtype_and_finiteness(which: str, teacher: nudge.Predictor, student: nudge.Predictor,
                                            scenario: nudge.Scenario) -> None:
    p = {"teacher": teacher, "student": student, "cv": nudge.Predictor.constant_velocity()}[which]
    cands = straight_candidates(scenario, 5)
    out = p.predict(scenario.history, cands)
    assert out.shape == (5, scenario.n_agents - 1, 6, 2)
    assert out.dtype == np.float64
    assert np.isfinite(out).all()
    # Deterministic.
    np.testing.assert_array_equal(out, p.predict(scenario.history, cands))


def test_constant_velocity_is_exact(scenario: nudge.Scenario) -> None:
    h = scenario.history
    out = nudge.Predictor.constant_velocity().predict(h, straight_candidates(scenario, 2))
    vel = h[1:, -1] - h[1:, -2]
    want = h[1:, -1][:, None, :] + np.arange(1, 7)[None, :, None] * vel[:, None, :]
    np.testing.assert_allclose(out[0], want, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(out[0], out[1])  # does not react to the ego


def test_float32_and_non_contiguous_inputs_match(teacher: nudge.Predictor, scenario: nudge.Scenario) -> None:
    h = scenario.history
    c = straight_candidates(scenario, 4)
    ref = teacher.predict(h, c)
    # Fortran order and strided views carry the same values.
    np.testing.assert_array_equal(teacher.predict(np.asfortranarray(h), np.asfortranarray(c)), ref)
    big = np.zeros((h.shape[0], 8, 4))
    big[..., ::2] = h
    assert not big[..., ::2].flags.c_contiguous
    np.testing.assert_array_equal(teacher.predict(big[..., ::2], c[::-1][::-1]), ref)
    # float32 in: same as the float64 of the rounded values.
    h32, c32 = h.astype(np.float32), c.astype(np.float32)
    np.testing.assert_array_equal(teacher.predict(h32, c32), teacher.predict(h32.astype(np.float64), c32.astype(np.float64)))


@settings(max_examples=40, deadline=None)
@given(agents=st.integers(1, 60), batch=st.integers(0, 5), t=st.sampled_from([7, 8, 9]),
       h=st.sampled_from([5, 6, 7]), last=st.sampled_from([1, 2, 3]))
def test_shape_errors_raise_input_error(agents: int, batch: int, t: int, h: int, last: int) -> None:
    p = nudge.Predictor.constant_velocity()
    hist = np.cumsum(np.ones((agents, t, last)), axis=1)
    cands = np.ones((batch, h, 2))
    valid = 1 <= agents <= nudge.MAX_AGENTS and t == 8 and last == 2 and h == 6 and batch >= 1
    if valid:
        assert p.predict(hist, cands).shape == (batch, agents - 1, 6, 2)
    else:
        with pytest.raises(nudge.InputError):
            p.predict(hist, cands)


@settings(max_examples=30, deadline=None)
@given(dtype=st.sampled_from(["int64", "int32", "float16", "complex128", "bool", "object", "U3"]))
def test_wrong_dtypes_raise_input_error(dtype: str) -> None:
    p = nudge.Predictor.constant_velocity()
    hist = np.zeros((3, 8, 2)).astype(dtype)
    with pytest.raises(nudge.InputError, match="history: expected a float64"):
        p.predict(hist, np.zeros((1, 6, 2)))
    with pytest.raises(nudge.InputError, match="candidates: expected a float64"):
        p.predict(np.zeros((3, 8, 2)), np.zeros((1, 6, 2)).astype(dtype))


def test_non_array_inputs_raise_input_error() -> None:
    p = nudge.Predictor.constant_velocity()
    with pytest.raises(nudge.InputError, match="history"):
        p.predict([[0.0, 0.0]] * 8, np.zeros((1, 6, 2)))  # type: ignore[arg-type]
    with pytest.raises(nudge.InputError, match="candidates"):
        p.predict(np.zeros((2, 8, 2)), None)  # type: ignore[arg-type]


@settings(max_examples=30, deadline=None)
@given(bad=st.sampled_from([np.nan, np.inf, -np.inf]), where=st.sampled_from(["history", "candidates"]),
       idx=st.integers(0, 11))
def test_non_finite_values_raise_input_error(teacher: nudge.Predictor, scenario: nudge.Scenario,
                                             bad: float, where: str, idx: int) -> None:
    h = scenario.history.copy()
    c = straight_candidates(scenario, 2)
    if where == "history":
        h.reshape(-1)[idx] = bad
    else:
        c.reshape(-1)[idx] = bad
    with pytest.raises(nudge.InputError, match="non-finite|NaN|inf"):
        teacher.predict(h, c)


def test_missing_and_malformed_weights_raise_weights_error(tmp_path: Path) -> None:
    with pytest.raises(nudge.WeightsError, match="nope.safetensors"):
        nudge.Predictor.load(tmp_path / "nope.safetensors")
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json at all}")
    with pytest.raises(nudge.WeightsError):
        nudge.Predictor.load(bad)
    truncated = tmp_path / "trunc.safetensors"
    truncated.write_bytes(nudge.model_path("student").read_bytes()[:1000])
    with pytest.raises(nudge.WeightsError):
        nudge.Predictor.load(truncated)


def test_exception_hierarchy() -> None:
    for cls in (nudge.WeightsError, nudge.InputError, nudge.SettingsError, nudge.ScenarioError, nudge.SolverError):
        assert issubclass(cls, nudge.NudgeError)
        assert issubclass(cls, Exception)
    assert nudge.NudgeError.__module__.startswith("nudge")
