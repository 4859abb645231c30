"""Property tests (hypothesis) over the public Python entry points: ``Predictor.predict``,
``Planner.plan`` / ``plan_scenario``, the ``PlannerSettings`` / ``SimConfig`` constructors and
JSON readers, ``Scenario.load`` and ``simulate``, fed arbitrary finite and non-finite floats,
shapes, dtypes and argument types.

Oracle: a typed ``nudge.NudgeError`` (``TypeError`` where Python's own argument semantics
demand it), or a valid result: predictions finite and within 30 m per step; plans finite, of the
right shapes, and never reported safe (``Converged`` / ``MaxIterations``) with a safety value
that is not a finite number above the threshold; settings that round-trip; scenarios whose
arrays are finite and consistent; simulation columns of consistent lengths. Never a panic
(pyo3's ``PanicException`` is a ``BaseException`` and fails the test), never a call slower than
``SLOW_S``.

Short by default (``make test``); ``NUDGE_FUZZ_EXAMPLES=N`` sets the examples per test for a
long run (``make fuzz-python``), ``NUDGE_FUZZ_SEED`` the seed.
"""

from __future__ import annotations

import json
import os
import struct
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import nudge

EXAMPLES = int(os.environ.get("NUDGE_FUZZ_EXAMPLES", "100"))
SEED = int(os.environ.get("NUDGE_FUZZ_SEED", "20261130"))
SLOW_S = 60.0
MAX_STEP = 30.0  # m per 0.3 s step (nudge_predictor::limits::MAX_STEP)
STATUSES = {"Converged", "MaxIterations", "Refined", "Unsafe", "BudgetExhausted", "Backtracked", "Fallback", "SolverFailed"}

FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=False, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.filter_too_much])

# Every outcome of a try, counted per entry point and printed at the end of the session with -s.
COUNTS: dict[str, dict[str, int]] = {}


def _count(entry: str, outcome: str) -> None:
    c = COUNTS.setdefault(entry, {})
    c[outcome] = c.get(outcome, 0) + 1


@pytest.fixture(scope="module", autouse=True)
def _report() -> Any:
    yield
    for entry, c in sorted(COUNTS.items()):
        print(f"\n{entry}: " + ", ".join(f"{k} {v}" for k, v in sorted(c.items())))


def _judge(entry: str, call: Callable[[], Any], check: Callable[[Any], None],
           python_errors: tuple[type[BaseException], ...] = ()) -> None:
    """Runs ``call``: a NudgeError (counted by class), an allowed Python error, or a result that
    passes ``check``. Anything else, a panic included, fails."""
    t0 = time.monotonic()
    try:
        result = call()
    except nudge.NudgeError as e:
        _count(entry, type(e).__name__)
        return
    except python_errors as e:
        _count(entry, type(e).__name__)
        return
    finally:
        elapsed = time.monotonic() - t0
        assert elapsed < SLOW_S, f"{entry}: a call took {elapsed:.1f} s"
    check(result)
    _count(entry, "valid")


# ------------------------------------------------------------------------------------------
# Shared inputs.
# ------------------------------------------------------------------------------------------

SCENES = nudge.scene_paths()
BASE = nudge.Scenario.load(SCENES[0])  # 16 agents
SMALL = BASE.nearest(3)
CV = nudge.Predictor.constant_velocity()
STUDENT = nudge.Predictor.load(nudge.model_path("student"))
TEACHER = nudge.Predictor.load(nudge.model_path("teacher"))
PREDICTORS = {"constant_velocity": CV, "student": STUDENT, "teacher": TEACHER}

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
wild_float = st.one_of(
    any_float,
    st.sampled_from([0.0, -0.0, 1e-300, 1e6, 1e6 + 1, 1e9, 1e154, 1e300, -1e300, 3.4e38, np.nan, np.inf, -np.inf]),
)
wild_int = st.one_of(st.integers(-3, 70), st.integers(-(2**70), 2**70), st.sampled_from([2**63, 2**64 - 1, 2**64]))
# Arguments of the wrong type.
junk = st.one_of(st.none(), st.text(max_size=5), st.lists(st.integers(), max_size=3), st.booleans(),
                 st.just(object()), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@st.composite
def float_arrays(draw: st.DrawFn, base: np.ndarray) -> Any:
    """``base`` (a valid array) mutated: a few values replaced by arbitrary floats, the shape
    changed, the dtype changed, or turned into nested lists / masked arrays / junk."""
    a = base.copy()
    kind = draw(st.sampled_from(["ok"] * 8 + ["values"] * 4 + ["shift", "shape", "dtype", "list", "masked", "junk"]))
    if kind == "values" and a.size:
        for _ in range(draw(st.integers(1, 3))):
            a.reshape(-1)[draw(st.integers(0, a.size - 1))] = draw(wild_float)
    elif kind == "shift":
        a = a + draw(st.floats(-2e6, 2e6))
    elif kind == "shape":
        shape = draw(st.lists(st.integers(0, 9), min_size=0, max_size=4))
        a = np.resize(a, shape) if a.size else np.zeros(shape)
    elif kind == "dtype":
        dtype = draw(st.sampled_from(["float32", "float16", "int64", "bool", "complex128", "object", "U3"]))
        with np.errstate(all="ignore"):
            return a.astype(dtype)
    elif kind == "list":
        return a.tolist()
    elif kind == "masked":
        return np.ma.masked_array(a)
    elif kind == "junk":
        return draw(junk)
    return a


def _candidates(sc: nudge.Scenario, batch: int, horizon: int = 6) -> np.ndarray:
    x0, y0 = sc.history[0, -1]
    v = float(sc.speed[0]) * nudge.DT
    k = np.arange(1, horizon + 1)
    out = np.empty((batch, horizon, 2))
    out[..., 0] = x0 + v * k[None, :]
    out[..., 1] = y0 + np.linspace(-1.0, 1.0, batch)[:, None] * k[None, :] / horizon
    return out


# ------------------------------------------------------------------------------------------
# Predictor.predict
# ------------------------------------------------------------------------------------------


def _predictions_valid(history: np.ndarray, batch: int) -> Callable[[Any], None]:
    def check(out: Any) -> None:
        h = np.asarray(history, dtype=np.float64)
        n = h.shape[0]
        assert isinstance(out, np.ndarray) and out.dtype == np.float64
        assert out.shape == (batch, n - 1, 6, 2), out.shape
        assert np.isfinite(out).all(), "non-finite prediction accepted"
        prev = np.broadcast_to(h[1:, -1][None], (batch, n - 1, 2))
        for k in range(6):
            step = np.hypot(*(out[:, :, k] - prev).transpose(2, 0, 1))
            assert (step <= MAX_STEP * (1 + 1e-12)).all(), f"implausible step {step.max()} m at step {k + 1}"
            prev = out[:, :, k]
    return check


@FUZZ
@seed(SEED)
@given(which=st.sampled_from(sorted(PREDICTORS)), data=st.data(), batch=st.integers(1, 4),
       agents=st.integers(1, 16))
def test_predict_gives_typed_errors_or_valid_predictions(which: str, data: st.DataObject, batch: int,
                                                         agents: int) -> None:
    sc = BASE.nearest(agents - 1)
    history = data.draw(float_arrays(sc.history), label="history")
    candidates = data.draw(float_arrays(_candidates(sc, batch)), label="candidates")
    p = PREDICTORS[which]

    def check(out: Any) -> None:
        h = np.asarray(history, dtype=np.float64)
        c = np.asarray(candidates, dtype=np.float64)
        _predictions_valid(h, c.shape[0])(out)

    _judge(f"predict[{which}]", lambda: p.predict(history, candidates), check)


# ------------------------------------------------------------------------------------------
# Planner.plan / plan_scenario
# ------------------------------------------------------------------------------------------


def _plan_valid(horizon: int = 6) -> Callable[[Any], None]:
    def check(plan: Any) -> None:
        assert plan["status"] in STATUSES
        for k in ("delta", "accel"):
            assert plan[k].shape == (horizon,) and np.isfinite(plan[k]).all(), (k, plan[k])
        assert plan["states"].shape == (horizon, 4) and np.isfinite(plan["states"]).all()
        assert np.isfinite(plan["cost"]), plan["cost"]
        b = plan["min_safety"]
        if plan["status"] in ("Converged", "MaxIterations") and b is not None:
            # Nothing non-finite is ever safe.
            assert np.isfinite(b) and b > 0.0, f"{plan['status']} with min_safety {b}"
    return check


@FUZZ
@seed(SEED + 1)
@given(which=st.sampled_from(["constant_velocity", "student"]), data=st.data())
def test_plan_gives_typed_errors_or_valid_plans(which: str, data: st.DataObject) -> None:
    sc = SMALL
    ego = np.array([*sc.history[0, -1], sc.heading[0], sc.speed[0]])
    lane = sc.target_lane(0)
    kwargs: dict[str, Any] = {
        "history": data.draw(float_arrays(sc.history), label="history"),
        "sizes": data.draw(float_arrays(sc.size), label="sizes"),
        "ego": data.draw(float_arrays(ego), label="ego"),
        "y_target": float(sc.lane_centres[lane]),
        "v_ref": float(sc.speed[0]),
        "road": sc.road,
        "last_delta": 0.0,
        "last_accel": 0.0,
    }
    for k in ("y_target", "v_ref", "last_delta", "last_accel"):
        if data.draw(st.integers(0, 5), label=f"edit {k}") == 0:
            kwargs[k] = data.draw(st.one_of(wild_float, junk), label=k)
    if data.draw(st.integers(0, 5), label="edit road") == 0:
        kwargs["road"] = data.draw(st.one_of(st.tuples(wild_float, wild_float), junk), label="road")
    planner = nudge.Planner(None, PREDICTORS[which])
    _judge(f"plan[{which}]", lambda: planner.plan(**kwargs), _plan_valid(), python_errors=(TypeError,))


@FUZZ
@seed(SEED + 2)
@given(keep=st.integers(0, 20), target_lane=st.one_of(st.none(), wild_int, junk), s=st.one_of(wild_int, junk),
       scene=st.integers(0, len(SCENES) - 1))
def test_plan_scenario_gives_typed_errors_or_valid_plans(keep: int, target_lane: Any, s: Any, scene: int) -> None:
    sc = nudge.Scenario.load(SCENES[scene]).nearest(keep)
    planner = nudge.Planner(None, CV)
    _judge("plan_scenario", lambda: planner.plan_scenario(sc, target_lane=target_lane, seed=s), _plan_valid(),
           python_errors=(TypeError,))


# ------------------------------------------------------------------------------------------
# PlannerSettings / SimConfig
# ------------------------------------------------------------------------------------------

SETTINGS_FIELDS = sorted(nudge.PlannerSettings.default().to_dict())
CONFIG_FIELDS = sorted(nudge.SimConfig.default().to_dict())
setting_values = st.one_of(wild_float, wild_int, st.booleans(), st.text(max_size=12),
                           st.sampled_from(["teacher", "log_replay", "idm", "student"]), junk)


def _round_trips(cls: type) -> Callable[[Any], None]:
    def check(s: Any) -> None:
        assert isinstance(s, cls)
        d = s.to_dict()
        assert cls.from_dict(d) == s
        assert cls.from_json(s.to_json()) == s
        for v in d.values():
            if isinstance(v, float):
                assert np.isfinite(v), d
    return check


@FUZZ
@seed(SEED + 3)
@given(which=st.sampled_from(["PlannerSettings", "SimConfig"]), data=st.data())
def test_settings_constructors_give_typed_errors_or_valid_settings(which: str, data: st.DataObject) -> None:
    cls = nudge.PlannerSettings if which == "PlannerSettings" else nudge.SimConfig
    fields = SETTINGS_FIELDS if cls is nudge.PlannerSettings else CONFIG_FIELDS
    keys = st.one_of(st.sampled_from(fields), st.text(max_size=8))
    overrides = data.draw(st.dictionaries(keys, setting_values, max_size=4), label="overrides")
    how = data.draw(st.sampled_from(["new", "from_dict", "replace", "from_json"]), label="how")
    if how == "new":
        call: Callable[[], Any] = lambda: cls(**overrides)  # noqa: E731
    elif how == "from_dict":
        call = lambda: cls.from_dict(overrides)  # noqa: E731
    elif how == "replace":
        call = lambda: cls.default().replace(**overrides)  # noqa: E731
    else:
        text = data.draw(st.one_of(
            st.just(json.dumps(overrides, default=str, allow_nan=True)),
            st.text(max_size=40),
            st.builds(lambda k, v: f'{{"{k}": {v}, "{k}": {v}}}', st.sampled_from(fields), st.integers(0, 9)),
            st.builds(lambda v: json.dumps(v), st.lists(st.floats(allow_nan=False), max_size=4)),
        ), label="text")
        call = lambda: cls.from_json(text)  # noqa: E731
    _judge(f"{which}.{how}", call, _round_trips(cls), python_errors=(TypeError,))


# ------------------------------------------------------------------------------------------
# Scenario.load
# ------------------------------------------------------------------------------------------

SCENE_BYTES = [p.read_bytes() for p in SCENES[:3]]


def _header(b: bytes) -> tuple[int, dict[str, Any]]:
    n = struct.unpack("<Q", b[:8])[0]
    return n, json.loads(b[8:8 + n])


@st.composite
def mutated_scene(draw: st.DrawFn) -> bytes:
    b = bytearray(draw(st.sampled_from(SCENE_BYTES)))
    n, header = _header(bytes(b))
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["flip", "truncate", "value", "value", "value", "header"]))
        if kind == "flip" and b:
            i = draw(st.integers(0, len(b) - 1))
            b[i] ^= 1 << draw(st.integers(0, 7))
        elif kind == "truncate":
            del b[draw(st.integers(0, len(b))):]
        elif kind == "value":
            names = [k for k, v in header.items() if k != "__metadata__" and v["dtype"] == "F64"]
            name = draw(st.sampled_from(names))
            lo, hi = header[name]["data_offsets"]
            count = (hi - lo) // 8
            if count == 0:
                continue
            i = 8 + n + lo + 8 * draw(st.integers(0, count - 1))
            if i + 8 <= len(b):
                b[i:i + 8] = struct.pack("<d", draw(wild_float))
        elif kind == "header":
            meta = dict(header.get("__metadata__", {}))
            meta[draw(st.sampled_from(["schema", "dt", "split", "x"]))] = draw(st.text(max_size=6))
            header2 = dict(header, __metadata__=meta)
            text = json.dumps(header2).encode()
            b = bytearray(struct.pack("<Q", len(text)) + text + bytes(b[8 + n:]))
            n, header = len(text), header2
    return bytes(b)


def _scenario_valid(sc: Any) -> None:
    assert isinstance(sc, nudge.Scenario)
    n = sc.n_agents
    assert sc.history.shape == (n, 8, 2) and np.isfinite(sc.history).all()
    assert sc.size.shape == (n, 2) and (sc.size > 0).all()
    assert np.isfinite(sc.heading).all() and np.isfinite(sc.speed).all()
    lo, hi = sc.road
    assert np.isfinite([lo, hi]).all() and lo < hi
    assert 0 <= sc.ego_lane < len(sc.lane_centres)
    assert np.isfinite(sc.future[sc.future_valid]).all()


@FUZZ
@seed(SEED + 4)
@given(data=mutated_scene())
def test_scenario_load_gives_typed_errors_or_valid_scenes(tmp_path_factory: pytest.TempPathFactory,
                                                           data: bytes) -> None:
    path = tmp_path_factory.mktemp("scene") / "fuzzed.safetensors"
    path.write_bytes(data)
    _judge("Scenario.load", lambda: nudge.Scenario.load(path), _scenario_valid)


# ------------------------------------------------------------------------------------------
# simulate
# ------------------------------------------------------------------------------------------


def _columns_valid(r: Any) -> None:
    runs, steps = r["runs"], r["steps"]
    n = len(runs["scenario"])
    assert n >= 1
    assert all(len(v) == n for v in runs.values())
    s = len(steps["run"])
    assert all(len(v) == s for v in steps.values())
    assert int(np.sum(runs["n_steps"])) == s
    assert np.isfinite(steps["ego"]).all()
    ok = steps["status"]
    assert set(ok) <= STATUSES


@FUZZ
@seed(SEED + 5)
@given(data=st.data())
def test_simulate_gives_typed_errors_or_valid_columns(data: st.DataObject) -> None:
    k = data.draw(st.integers(0, 3), label="scenes")
    paths: Any = [str(p) for p in SCENES[:k]]
    if data.draw(st.integers(0, 9), label="paths kind") == 0:
        paths = data.draw(st.one_of(junk, st.just(str(SCENES[0])), st.just(["/nonexistent.safetensors"])))
    kwargs: dict[str, Any] = {"max_steps": data.draw(st.sampled_from([1, 2, 3, 0, -1, 10**9, "3", 2.5]))}
    optional: dict[str, st.SearchStrategy[Any]] = {
        "seed": wild_int,
        "runs": st.one_of(st.integers(-1, 2), st.sampled_from([2**40, 2**70])),
        "threads": st.one_of(st.none(), st.integers(-1, 2), st.sampled_from([10**6, 2**70])),
        "world": st.sampled_from(["teacher", "log_replay", "predictor", "log-replay", ""]),
        "world_predictor": st.sampled_from(["teacher", "student", "constant_velocity", "nope"]),
        "scene_seeds": st.lists(wild_int, max_size=4),
        "on_error": st.sampled_from(["raise", "skip", "ignore"]),
        "settle_y": wild_float,
        "abort_after": wild_int,
        "settings": st.sampled_from([nudge.PlannerSettings(model={"horizon": 5}), nudge.PlannerSettings(model={"dt": 0.5}),
                                     nudge.PlannerSettings(admm={"max_iter": 2})]),
        "record": st.booleans(),
        "trace": st.booleans(),
    }
    for name, strategy in optional.items():
        if data.draw(st.integers(0, 4), label=f"set {name}") == 0:
            kwargs[name] = data.draw(strategy, label=name)
    predictor = data.draw(st.sampled_from(["constant_velocity", "constant_velocity", "student", "constant-velocity",
                                           "/nonexistent.safetensors"]), label="predictor")
    _judge("simulate", lambda: nudge.simulate(paths, predictor, **kwargs), _columns_valid,
           python_errors=(TypeError,))


TRACE = nudge.simulate(SCENES[:1], "constant_velocity", world="log_replay", max_steps=4, trace=True)["traces"][0]
TRACE_KEYS = sorted(TRACE)


def _animation_valid(w: Any) -> None:
    assert w["frames"] >= 1 and w["width"] >= 2 and w["height"] >= 2
    assert Path(w["gif"]).stat().st_size > 0


@FUZZ
@seed(SEED + 6)
@given(data=st.data())
def test_animate_gives_typed_errors_or_an_animation(tmp_path_factory: pytest.TempPathFactory,
                                                    data: st.DataObject) -> None:
    trace: Any = dict(TRACE)
    for key in data.draw(st.lists(st.sampled_from(TRACE_KEYS), max_size=2, unique=True), label="spoil"):
        base = TRACE[key]
        if isinstance(base, np.ndarray) and base.dtype == np.float64:
            trace[key] = data.draw(float_arrays(base), label=key)
        elif data.draw(st.booleans(), label=f"drop {key}"):
            del trace[key]
        else:
            trace[key] = data.draw(junk, label=key)
    if data.draw(st.integers(0, 19), label="trace kind") == 0:
        trace = data.draw(junk, label="trace")
    settings: dict[str, Any] = {}
    if data.draw(st.integers(0, 3), label="settings") == 0:
        field = data.draw(st.sampled_from(["px_per_m", "behind_m", "ahead_m", "margin_m", "frame_s", "bogus"]))
        settings[field] = data.draw(st.one_of(wild_float, junk), label=field)
    gif = tmp_path_factory.mktemp("anim") / "run.gif"
    _judge("animate", lambda: nudge._native.animate(trace, gif, **settings), _animation_valid)


def test_the_short_mode_exercised_every_entry_point() -> None:
    """Every property above produced both typed errors and valid results (so the generators
    reach past the first check). Runs last in this module."""
    if EXAMPLES < 100:
        pytest.skip("too few examples to require both outcomes")
    groups: dict[str, dict[str, int]] = {}
    for entry, c in COUNTS.items():
        g = groups.setdefault(entry.split("[")[0].split(".")[0], {})
        for k, v in c.items():
            g[k] = g.get(k, 0) + v
    assert set(groups) == {"predict", "plan", "plan_scenario", "PlannerSettings", "SimConfig", "Scenario",
                           "simulate", "animate"}, sorted(groups)
    for group, c in groups.items():
        assert c.get("valid", 0) > 0, f"{group}: no valid result: {c}"
        assert sum(v for k, v in c.items() if k != "valid") > 0, f"{group}: no refusal: {c}"


class _CallsBack:
    """Constant velocity that, at its ``at``-th call, calls ``method`` of ``target`` (its own
    planner or another one) once (issue 49: re-entrancy)."""

    def __init__(self, at: int, method: str) -> None:
        self.at, self.method, self.calls, self.target, self.scenario = at, method, 0, None, None
        self.raised: BaseException | None = None

    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        self.calls += 1
        if self.calls == self.at:
            try:
                if self.method == "plan_scenario":
                    self.target.plan_scenario(self.scenario)
                elif self.method == "reset":
                    self.target.reset()
                else:
                    _ = self.target.settings
            except nudge.NudgeError as e:
                self.raised = e
                raise
        last, prev = history[1:, -1], history[1:, -2]
        k = np.arange(1, candidates.shape[1] + 1, dtype=np.float64)[None, :, None]
        one = last[:, None, :] + k * (last - prev)[:, None, :]
        return np.broadcast_to(one, (candidates.shape[0], *one.shape))


@FUZZ
@seed(SEED)
@given(at=st.integers(1, 40), method=st.sampled_from(["plan_scenario", "reset", "settings"]), own=st.booleans(),
       which=st.integers(0, 9))
def test_reentrant_predictor_property(at: int, method: str, own: bool, which: int) -> None:
    """A predictor calling back into its own planner gets ReentrancyError (the outer plan a
    PredictorError with it as the cause) and never deadlocks; calling another planner works;
    the planner plans again afterwards."""
    paths = nudge.scene_paths()
    sc = nudge.Scenario.load(paths[which % len(paths)])
    p = _CallsBack(at, method)
    planner = nudge.Planner(None, predictor=p)
    other = nudge.Planner(None, predictor=nudge.Predictor.constant_velocity())
    p.target, p.scenario = (planner if own else other), sc
    try:
        out = planner.plan_scenario(sc)
    except nudge.PredictorError as e:
        assert own and isinstance(e.__cause__, nudge.ReentrancyError), repr(e.__cause__)
        assert f"Planner.{method}" in str(e.__cause__)
        _count("reentrant predictor", "ReentrancyError")
    else:
        assert not own or p.calls < at, (own, p.calls, at)
        assert np.isfinite(out["states"]).all()
        _count("reentrant predictor", "planned" if p.calls >= at else "planned (callback not reached)")
    p.at = -1
    assert planner.plan_scenario(sc)["states"].shape == (6, 4)
