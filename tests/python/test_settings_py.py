"""nudge.PlannerSettings: dict / JSON round trips and SettingsError for bad keys and values."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import nudge


def test_default_round_trips_through_dict_and_json() -> None:
    s = nudge.PlannerSettings.default()
    d = s.to_dict()
    assert d["horizon"] == 6 and isinstance(d["horizon"], int)
    assert isinstance(d["dt"], float) and d["dt"] == pytest.approx(0.3)
    assert nudge.PlannerSettings.from_dict(d) == s
    assert nudge.PlannerSettings.from_json(s.to_json()) == s
    assert json.loads(s.to_json()) == d
    assert nudge.PlannerSettings() == s
    assert s.horizon == 6 and s.rho == d["rho"]


def test_overrides_and_replace() -> None:
    s = nudge.PlannerSettings(rho=2.5, max_iter=7)
    assert s.rho == 2.5 and s.max_iter == 7
    r = s.replace(max_iter=9)
    assert r.max_iter == 9 and r.rho == 2.5 and s.max_iter == 7
    assert r != s
    # numpy scalars are accepted as numbers
    assert nudge.PlannerSettings.from_dict({"rho": np.float64(3.0), "max_iter": np.int64(4)}).max_iter == 4
    # ints are accepted for float fields
    assert nudge.PlannerSettings(rho=3).rho == 3.0


def test_unknown_key_is_named() -> None:
    with pytest.raises(nudge.SettingsError, match="unknown planner setting `rhoo`"):
        nudge.PlannerSettings.from_dict({"rhoo": 1.0})
    with pytest.raises(nudge.SettingsError, match="`bogus`"):
        nudge.PlannerSettings(bogus=1)


@settings(max_examples=40, deadline=None)
@given(value=st.one_of(st.text(max_size=3), st.none(), st.lists(st.floats(), max_size=2),
                       st.sampled_from([float("nan"), float("inf"), -float("inf")])))
def test_wrong_value_types_name_the_key(value: object) -> None:
    with pytest.raises(nudge.SettingsError, match="`rho`"):
        nudge.PlannerSettings.from_dict({"rho": value})


def test_integer_fields_reject_floats_and_bools() -> None:
    with pytest.raises(nudge.SettingsError, match="`max_iter`.*integer"):
        nudge.PlannerSettings.from_dict({"max_iter": 3.5})
    with pytest.raises(nudge.SettingsError, match="`max_iter`"):
        nudge.PlannerSettings.from_dict({"max_iter": True})
    with pytest.raises(nudge.SettingsError, match="`horizon`"):
        nudge.PlannerSettings.from_dict({"horizon": -1})


def test_invalid_values_are_rejected_by_validation() -> None:
    with pytest.raises(nudge.SettingsError, match="rho"):
        nudge.PlannerSettings(rho=-1.0)
    with pytest.raises(nudge.SettingsError, match="horizon"):
        nudge.PlannerSettings(horizon=0)


def test_not_a_dict_and_bad_json() -> None:
    with pytest.raises(nudge.SettingsError, match="expected a dict"):
        nudge.PlannerSettings.from_dict([("rho", 1.0)])  # type: ignore[arg-type]
    with pytest.raises(nudge.SettingsError, match="key"):
        nudge.PlannerSettings.from_dict({1: 1.0})  # type: ignore[dict-item]
    with pytest.raises(nudge.SettingsError):
        nudge.PlannerSettings.from_json("{not json")
    with pytest.raises(nudge.SettingsError):
        nudge.PlannerSettings.from_json('{"nope": 1}')


def test_attribute_error_for_unknown_field() -> None:
    with pytest.raises(AttributeError, match="no field `nope`"):
        _ = nudge.PlannerSettings.default().nope


@settings(max_examples=30, deadline=None)
@given(rho=st.floats(0.01, 100.0), max_iter=st.integers(1, 500), hs=st.booleans())
def test_round_trip_property(rho: float, max_iter: int, hs: bool) -> None:
    s = nudge.PlannerSettings(rho=rho, max_iter=max_iter, hessian_scaled=hs)
    d = s.to_dict()
    assert d["rho"] == rho and d["max_iter"] == max_iter and d["hessian_scaled"] is hs
    assert nudge.PlannerSettings.from_dict(d) == s
