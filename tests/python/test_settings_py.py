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
    assert d["model"]["horizon"] == 6 and isinstance(d["model"]["horizon"], int)
    assert isinstance(d["model"]["dt"], float) and d["model"]["dt"] == pytest.approx(0.3)
    assert nudge.PlannerSettings.from_dict(d) == s
    assert nudge.PlannerSettings.from_json(s.to_json()) == s
    assert json.loads(s.to_json()) == d
    assert nudge.PlannerSettings() == s
    assert s.model["horizon"] == 6 and s.admm["rho"] == d["admm"]["rho"]


def test_overrides_and_replace() -> None:
    s = nudge.PlannerSettings(admm={"rho": 2.5, "max_iter": 7})
    assert s.admm["rho"] == 2.5 and s.admm["max_iter"] == 7
    r = s.replace(admm={"max_iter": 9})
    assert r.admm["max_iter"] == 9 and r.admm["rho"] == 2.5 and s.admm["max_iter"] == 7
    assert r != s
    # numpy scalars are accepted as numbers
    assert nudge.PlannerSettings.from_dict(
        {"admm": {"rho": np.float64(3.0), "max_iter": np.int64(4)}}).admm["max_iter"] == 4
    # ints are accepted for float fields
    assert nudge.PlannerSettings(admm={"rho": 3}).admm["rho"] == 3.0
    # a group given in part keeps the rest of its fields
    assert nudge.PlannerSettings(admm={"rho": 3}).admm["max_iter"] == 30
    # a dotted key (as `describe()` names the fields) sets one field
    assert nudge.PlannerSettings(**{"cost.w_y": 2.0}).cost["w_y"] == 2.0
    assert getattr(s.replace(**{"admm.rho": 4.0}), "admm.rho") == 4.0


def test_unknown_key_is_named() -> None:
    with pytest.raises(nudge.SettingsError, match="unknown planner setting `admm.rhoo`"):
        nudge.PlannerSettings.from_dict({"admm": {"rhoo": 1.0}})
    with pytest.raises(nudge.SettingsError, match="`bogus`"):
        nudge.PlannerSettings(bogus=1)
    with pytest.raises(nudge.SettingsError, match="expected a dict"):
        nudge.PlannerSettings(admm=3)


def test_old_flat_keys_name_their_new_place_or_why_they_went() -> None:
    with pytest.raises(nudge.SettingsError, match="`rho` moved: it is now `admm.rho`"):
        nudge.PlannerSettings(rho=2.0)
    with pytest.raises(nudge.SettingsError, match="`fallback_shy` was removed"):
        nudge.PlannerSettings.from_dict({"fallback_shy": True})
    with pytest.raises(nudge.SettingsError, match="`horizon` moved"):
        nudge.PlannerSettings.from_json('{"horizon": 6}')


@settings(max_examples=40, deadline=None)
@given(value=st.one_of(st.text(max_size=3), st.none(), st.lists(st.floats(), max_size=2),
                       st.sampled_from([float("nan"), float("inf"), -float("inf")])))
def test_wrong_value_types_name_the_key(value: object) -> None:
    with pytest.raises(nudge.SettingsError, match="`admm.rho`"):
        nudge.PlannerSettings.from_dict({"admm": {"rho": value}})


def test_integer_fields_reject_floats_and_bools() -> None:
    with pytest.raises(nudge.SettingsError, match="`admm.max_iter`.*integer"):
        nudge.PlannerSettings.from_dict({"admm": {"max_iter": 3.5}})
    with pytest.raises(nudge.SettingsError, match="`admm.max_iter`"):
        nudge.PlannerSettings.from_dict({"admm": {"max_iter": True}})
    with pytest.raises(nudge.SettingsError, match="`model.horizon`"):
        nudge.PlannerSettings.from_dict({"model": {"horizon": -1}})


def test_invalid_values_are_rejected_by_validation() -> None:
    with pytest.raises(nudge.SettingsError, match="rho"):
        nudge.PlannerSettings(admm={"rho": -1.0})
    with pytest.raises(nudge.SettingsError, match="horizon"):
        nudge.PlannerSettings(model={"horizon": 0})


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
@given(rho=st.floats(0.01, 100.0), max_iter=st.integers(1, 500), ablate=st.booleans())
def test_round_trip_property(rho: float, max_iter: int, ablate: bool) -> None:
    s = nudge.PlannerSettings(safety={"ablate_reaction": ablate}, admm={"rho": rho, "max_iter": max_iter})
    d = s.to_dict()
    assert d["admm"]["rho"] == rho and d["admm"]["max_iter"] == max_iter
    assert d["safety"]["ablate_reaction"] is ablate
    assert nudge.PlannerSettings.from_dict(d) == s
