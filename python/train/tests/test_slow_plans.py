"""``nudge-train slow-plans``: the lane geometry by hand, the categories, and the re-simulation
of a real closed-loop cache (it must reproduce every cached run it describes)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import nudge

from nudge_train.experiments import closed_loop, slow_plans


def test_lane_entry_by_hand() -> None:
    # Lane [0, 3.5] m, a box 2 m wide: outside, partly in from the left, wholly in, partly in
    # from the right, outside; a non-finite centre gives NaN.
    y = np.array([-1.0, 0.5, 1.75, 4.4, 5.0, np.nan])
    got = slow_plans.lane_entry(y, 1.0, 0.0, 3.5)
    np.testing.assert_allclose(got[:5], [0.0, 1.5, 2.0, 0.1, 0.0], atol=1e-12)
    assert math.isnan(got[5])
    # A box wider than the lane reaches in by the lane's width at most.
    assert slow_plans.lane_entry(np.array([1.75]), 3.0, 0.0, 3.5)[0] == pytest.approx(3.5)
    with pytest.raises(ValueError, match="lane"):
        slow_plans.lane_entry(y, 1.0, 3.5, 0.0)
    with pytest.raises(ValueError, match="half width"):
        slow_plans.lane_entry(y, float("nan"), 0.0, 3.5)


def test_categories() -> None:
    assert slow_plans.classify(0.2, 0.9, 5.0) == "in_lane"
    assert slow_plans.classify(0.0, 0.4, 5.0) == "enters"
    assert slow_plans.classify(0.0, 0.4, -3.0) == "enters"
    assert slow_plans.classify(0.0, 0.0, 6.3) == "ahead"
    assert slow_plans.classify(0.0, 0.0, 0.0) == "behind"
    assert slow_plans.classify(0.0, 0.0, -9.0) == "behind"
    with pytest.raises(ValueError, match="non-finite"):
        slow_plans.classify(float("nan"), 0.0, 1.0)


def test_settings_label() -> None:
    assert slow_plans.settings_label(nudge.PlannerSettings().to_json()) == "default"
    other = nudge.PlannerSettings.from_json(json.dumps({"cost": {"w_y": 20.0}})).to_json()
    assert slow_plans.settings_label(other).startswith("settings ")


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A closed-loop cache of the shipped scenes (student planner, IDM world, one seed each)."""
    root = tmp_path_factory.mktemp("slow_plans")
    scenes = Path(nudge.scene_paths()[0]).parent
    cfg = closed_loop.EvalConfig(scenes=scenes, seeds=1, planners=("student",), worlds=("idm",), threads=1,
                                 batch=100, cache=root / "cache", progress=False)
    closed_loop.collect(cfg, log=lambda *_: None)
    return root / "cache"


def _parts(cache: Path) -> list[Path]:
    return sorted(cache.glob("*/part-*.json"))


def test_a_real_cache_is_reproduced_and_described(cache: Path, tmp_path: Path) -> None:
    data = json.loads(_parts(cache)[0].read_text())
    cached = sum(1 for n in data["runs"]["slow_planned_free_steps"] if n > 0)
    assert len(slow_plans.flagged_runs(cache)) == cached
    # Flag the first run by hand: its re-simulation cannot reproduce that, and says which run.
    data["runs"]["slow_planned_free_steps"][0] += 1
    forged = tmp_path / "forged"
    (forged / "chunk").mkdir(parents=True)
    (forged / "chunk" / "part-0000.json").write_text(json.dumps(data))
    scenes = Path(nudge.scene_paths()[0]).parent
    with pytest.raises(ValueError, match=data["runs"]["scenario"][0]):
        slow_plans.run(forged, scenes, tmp_path / "r.md", None, "test", progress=False)
    # The unforged cache writes its report and one JSON row per flagged step.
    assert slow_plans.run(cache, scenes, tmp_path / "r.md", tmp_path / "r.json", "test", progress=False) == 0
    rows = json.loads((tmp_path / "r.json").read_text())
    steps = sum(data["runs"]["slow_planned_free_steps"]) - 1
    assert len(rows) == steps
    assert all(r["category"] in slow_plans.CATEGORIES and r["settings"] == "default" for r in rows)
    # What decided each step's plan is read from the cache, step by step, for the flagged run.
    (run0,) = slow_plans.flagged_runs(forged)
    want = tuple(d for j, d in zip(data["steps"]["run"], data["steps"]["decided_by"], strict=True) if j == 0)
    assert run0.decided_by == want and len(want) == data["runs"]["n_steps"][0]
    assert all(d.split(":")[0] in {"admm", "admm_governed", "refined", "backtracked", "nominal", "fallback"}
               for d in data["steps"]["decided_by"])
    # A cache part written without it is refused naming the file.
    del data["steps"]["decided_by"]
    (forged / "chunk" / "part-0000.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="part-0000.json: the cache part has no decided_by"):
        slow_plans.flagged_runs(forged)
    assert "| world | planner | settings |" in (tmp_path / "r.md").read_text()


def test_a_foreign_file_is_refused(tmp_path: Path) -> None:
    (tmp_path / "chunk").mkdir()
    (tmp_path / "chunk" / "part-0000.json").write_text(json.dumps({"inputs": {"schema": "other/1"}, "runs": {}}))
    with pytest.raises(ValueError, match="part-0000.json"):
        slow_plans.flagged_runs(tmp_path)


def _trace(vehicle_y: list[float], binding: int = 1) -> dict:
    """Two lanes [0, 3.5] and [3.5, 7] m; the ego at 10 m/s in the lower one's centre, a 2 m
    wide vehicle ahead in the upper one at ``vehicle_y`` (m) over three steps, 1 m per step."""
    n = len(vehicle_y)
    agents = np.zeros((n, 2, 3))
    agents[:, 0, 0] = 3.0 * np.arange(n)
    agents[:, 0, 1] = 1.75
    agents[:, 1, 0] = 8.0 + np.arange(n)
    agents[:, 1, 1] = vehicle_y
    plan = np.zeros((n - 1, 3, 4))
    plan[:, -1, 3] = 1.5
    return {"agents": agents, "sizes": np.array([[4.5, 2.0], [4.5, 2.0]]), "lane_bounds": np.array([0.0, 3.5, 7.0]),
            "speed": np.full(n, 10.0), "plan": plan, "binding": np.full(n - 1, binding),
            "binding_b": np.full(n - 1, -0.2)}


def test_describe_step_by_hand() -> None:
    # Step 1: the vehicle is 6 m ahead, 3.25 m to the left, moving 1 m and 0.25 m towards the ego
    # per step; its box (lower edge 4.0 m, then 3.2 m) reaches 0.3 m into the ego's lane one step on.
    got = slow_plans.describe_step(_trace([5.25, 5.0, 4.2]), 1, "here")
    assert got["category"] == "enters"
    assert (got["dx"], got["dy"]) == pytest.approx((6.0, 3.25))
    assert got["speed"] == pytest.approx(1.0 / nudge.DT)
    assert got["toward"] == pytest.approx(0.25 / nudge.DT)
    assert (got["entry_now"], got["entry_max"]) == pytest.approx((0.0, 0.3))
    assert (got["ego_speed"], got["plan_end_speed"], got["binding_b"]) == (10.0, 1.5, -0.2)
    # Moving away it stays "ahead"; already across the line it is "in_lane".
    assert slow_plans.describe_step(_trace([5.25, 5.3, 5.4]), 1, "here")["category"] == "ahead"
    assert slow_plans.describe_step(_trace([5.25, 4.3, 4.3]), 1, "here")["category"] == "in_lane"
    assert slow_plans.describe_step(_trace([5.25, 5.0, 4.2], binding=0), 1, "here")["category"] == "none"
    # At step 0 nothing is observed before: no speeds, but the geometry still counts.
    first = slow_plans.describe_step(_trace([5.25, 5.0, 4.2]), 0, "here")
    assert math.isnan(first["speed"]) and first["category"] == "enters"
    with pytest.raises(ValueError, match="here: the binding vehicle 1 has no position"):
        slow_plans.describe_step(_trace([5.25, float("nan"), 4.2]), 1, "here")
    off = _trace([5.25, 5.0, 4.2])
    off["agents"][1, 0, 1] = -0.5
    with pytest.raises(ValueError, match="here: the ego's centre"):
        slow_plans.describe_step(off, 1, "here")


# ------------------------------------------------- the cache read as untrusted input (issue 49)


def _part(**edits: object) -> dict:
    """A minimal, well-formed closed-loop cache part with one flagged run."""
    part = {"inputs": {"schema": closed_loop.CACHE_SCHEMA, "planner": "student", "world": "idm", "settings": {},
                       "config": {}},
            "runs": {"scenario": ["us101-11_1-t02.1-ego144"], "seed": [3], "success": [False],
                     "slow_planned_free_steps": [1]},
            "steps": {"run": [0, 0], "decided_by": ["admm", "refined"]}}
    for path, value in edits.items():
        *head, last = path.split("__")
        node = part
        for k in head:
            node = node[k]
        if value is _DELETE:
            del node[last]
        else:
            node[last] = value
    return part


_DELETE = object()


def _write(tmp_path: Path, part: dict | str) -> Path:
    (tmp_path / "chunk").mkdir(exist_ok=True)
    text = part if isinstance(part, str) else json.dumps(part)
    (tmp_path / "chunk" / "part-0000.json").write_text(text)
    return tmp_path


def test_a_well_formed_part_is_read(tmp_path: Path) -> None:
    (r,) = slow_plans.flagged_runs(_write(tmp_path, _part()))
    assert (r.scene, r.seed, r.decided_by) == ("us101-11_1-t02.1-ego144", 3, ("admm", "refined"))


@pytest.mark.parametrize(("edits", "match"), [
    ({"runs__scenario": ["../../etc/passwd"]}, r"part-0000\.json.*runs\.scenario\[0\].*not a scene name"),
    ({"runs__scenario": ["/abs/scene"]}, r"runs\.scenario\[0\].*not a scene name"),
    ({"runs__scenario": [".hidden"]}, r"runs\.scenario\[0\].*not a scene name"),
    ({"runs__scenario": [7]}, r"runs\.scenario\[0\]"),
    ({"runs__seed": [1.5]}, r"runs\.seed\[0\].*integer"),
    ({"runs__seed": [3, 4]}, r"runs.*same length"),
    ({"runs__success": _DELETE}, r"runs\.success.*missing"),
    ({"runs__slow_planned_free_steps": ["x"]}, r"runs\.slow_planned_free_steps\[0\].*integer"),
    ({"runs": []}, r"runs.*object"),
    ({"steps__decided_by": ["admm"]}, r"steps.*same length"),
    ({"steps__run": [0, "a"]}, r"steps\.run\[1\].*integer"),
    ({"inputs__planner": 5}, r"inputs\.planner"),
    ({"inputs__settings": _DELETE}, r"inputs\.settings.*missing"),
    ({"inputs__settings": {"cost": {"w_y": "heavy"}}}, r"inputs\.settings"),
    ({"inputs__config": [1]}, r"inputs\.config"),
])
def test_malformed_cache_parts_are_typed_errors_naming_the_part(tmp_path: Path, edits: dict, match: str) -> None:
    """Before: a `..` scene name loaded a file outside --scenes, malformed parts ended in bare
    KeyError/TypeError tracebacks. Now each is a ConfigError naming the file and the part."""
    from nudge_train.errors import ConfigError

    with pytest.raises(ConfigError, match=match):
        slow_plans.flagged_runs(_write(tmp_path, _part(**edits)))


def test_repeated_keys_and_non_json_parts_are_refused(tmp_path: Path) -> None:
    from nudge_train.errors import ConfigError

    text = json.dumps(_part()).replace('"runs": {', '"runs": {"seed": [9], ', 1)
    with pytest.raises(ConfigError, match=r"part-0000\.json.*duplicate key 'seed'"):
        slow_plans.flagged_runs(_write(tmp_path, text))
    with pytest.raises(ConfigError, match=r"part-0000\.json.*not valid JSON"):
        slow_plans.flagged_runs(_write(tmp_path, "{"))


def test_a_scene_outside_the_scenes_folder_is_never_loaded(tmp_path: Path) -> None:
    """Even a FlaggedRun built by hand cannot make the re-simulation read outside --scenes."""
    from nudge_train.errors import ConfigError

    r = slow_plans.FlaggedRun(planner="student", world="idm", scene="../outside", seed=0,
                              settings=nudge.PlannerSettings().to_json(), config=nudge.SimConfig().to_json(),
                              slow_planned_free_steps=1, success=False, decided_by=("admm",))
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    with pytest.raises(ConfigError, match=r"\.\./outside.*not a scene name"):
        slow_plans._steps_of(r, scenes)


from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_JUNK = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**70), 2**70), st.booleans(),
                  st.none(), st.text(max_size=12), st.lists(st.integers(0, 3), max_size=3), st.just({}),
                  st.sampled_from(["../x", "/etc/passwd", "..", ".hidden", "a/b", "ok-scene"]))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_cache_reader_property(data: st.DataObject) -> None:
    """Any edit of a cache part is read as flagged runs whose scene names are plain file stems,
    or refused with a ConfigError naming the part; never another exception."""
    import tempfile

    from nudge_train.errors import ConfigError

    part = _part()
    for _ in range(data.draw(st.integers(1, 3))):
        section = data.draw(st.sampled_from(["inputs", "runs", "steps"]))
        key = data.draw(st.sampled_from(sorted(part[section]) + ["extra"]))
        if data.draw(st.booleans()) and key in part[section]:
            col = part[section][key]
            if isinstance(col, list) and col:
                col[data.draw(st.integers(0, len(col) - 1))] = data.draw(_JUNK)
                continue
        part[section][key] = data.draw(_JUNK)
    with tempfile.TemporaryDirectory() as d:
        try:
            runs = slow_plans.flagged_runs(_write(Path(d), part))
        except ConfigError as err:
            assert "part-0000.json" in str(err)
            return
    for r in runs:
        assert "/" not in r.scene and not r.scene.startswith(".") and isinstance(r.seed, int)
