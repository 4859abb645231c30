"""nudge.simulate: columns, determinism across thread counts, recorded examples, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import nudge

TIMING = {"mpc_s", "z_s", "z_median_s"}
STATUSES = {"Converged", "MaxIterations", "Refined", "Unsafe", "BudgetExhausted", "Backtracked", "Fallback", "SolverFailed"}


def _same_records(a: dict, b: dict) -> None:
    for table in ("runs", "steps"):
        assert a[table].keys() == b[table].keys()
        for k, va in a[table].items():
            if k in TIMING:
                continue
            vb = b[table][k]
            if isinstance(va, np.ndarray):
                np.testing.assert_array_equal(va, vb, err_msg=f"{table}.{k}")
            else:
                assert va == vb, f"{table}.{k}"


def test_columns_and_lengths(scenes: list[Path]) -> None:
    r = nudge.simulate(scenes[:3], "constant_velocity", seed=1, runs=2, threads=2, max_steps=4)
    runs, steps = r["runs"], r["steps"]
    assert len(runs["scenario"]) == 6
    # Scene-major runs; scene i, run r draws seed + i * runs + r.
    np.testing.assert_array_equal(runs["seed"], [1, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(runs["scene_index"], [0, 0, 1, 1, 2, 2])
    assert runs["error"] == [None] * 6
    assert runs["world"] == ["teacher"] * 6 and runs["predictor"] == ["constant_velocity"] * 6
    assert int(runs["n_steps"].sum()) == len(steps["run"])
    assert steps["ego"].shape == (len(steps["run"]), 4)
    np.testing.assert_array_equal(steps["ego"], np.stack([steps[k] for k in ("x", "y", "psi", "v")], axis=1))
    assert (steps["mpc_s"] > 0).all() and (runs["n_steps"] <= 4).all() and (runs["n_steps"] >= 1).all()
    assert set(steps["status"]) <= STATUSES
    # Schema-1 scenes have no lane extents: no plan ever has a lane violation (-1 = none).
    assert steps["lane_violation"].dtype == np.int64
    np.testing.assert_array_equal(steps["lane_violation"], -1)
    # One Z-update per ADMM iteration (no QP failed here); z_s sums them.
    np.testing.assert_array_equal(steps["z_updates"], steps["iterations"])
    assert (steps["z_s"] >= steps["z_median_s"]).all() and (steps["z_median_s"] > 0).all()
    for run in range(6):
        np.testing.assert_array_equal(steps["step"][steps["run"] == run], np.arange(runs["n_steps"][run]))
    assert "examples" not in r


def test_config_and_overrides_set_the_closed_loop(scenes: list[Path]) -> None:
    """A SimConfig (settle_* included) and keyword overrides of its fields reach the runs."""
    cfg = nudge.SimConfig(world="log_replay", settle_steps=1000, max_steps=5)
    r = nudge.simulate(scenes[:2], "constant_velocity", config=cfg)
    assert r["runs"]["world"] == ["log_replay"] * 2
    # settle_steps beyond max_steps: no run can succeed, every run takes max_steps.
    assert not r["runs"]["success"].any() and (r["runs"]["n_steps"] == 5).all()
    o = nudge.simulate(scenes[:2], "constant_velocity", config=cfg, max_steps=2, settle_y=1e-9)
    assert (o["runs"]["n_steps"] == 2).all()
    with pytest.raises(nudge.SettingsError, match="settle_y"):
        nudge.simulate(scenes[:1], "constant_velocity", settle_y=-1.0)
    with pytest.raises(nudge.SettingsError, match="bogus"):
        nudge.simulate(scenes[:1], "constant_velocity", bogus=1)


def test_thread_count_does_not_change_results(scenes: list[Path]) -> None:
    a = nudge.simulate(scenes[:4], "student", world="teacher", world_predictor="teacher", seed=5, threads=1,
                       max_steps=3)
    b = nudge.simulate(scenes[:4], "student", seed=5, threads=2, max_steps=3)
    _same_records(a, b)
    assert set(a["runs"]["world"]) == {"teacher"} and set(a["runs"]["predictor"]) == {"student"}


def test_first_step_equals_planner_call(scenes: list[Path], teacher: nudge.Predictor) -> None:
    r = nudge.simulate(scenes[:1], "teacher", seed=2, max_steps=1)
    sc = nudge.Scenario.load(scenes[0])
    plan = nudge.Planner(None, teacher).plan_scenario(sc, seed=2)
    assert r["runs"]["target_lane"][0] == plan["target_lane"]
    assert r["steps"]["cost"][0] == plan["cost"]
    assert r["steps"]["iterations"][0] == plan["iterations"]
    assert r["steps"]["delta"][0] == plan["delta"][0] and r["steps"]["accel"][0] == plan["accel"][0]


def test_recorded_examples_are_teacher_predictions(scenes: list[Path], teacher: nudge.Predictor) -> None:
    r = nudge.simulate(scenes[:2], "teacher", seed=0, max_steps=3, record=True)
    ex = r["examples"]
    e = len(ex["example_context"])
    assert e > 0
    co, po = ex["context_offsets"], ex["prediction_offsets"]
    assert co[-1] == len(ex["history"]) and po[-1] == len(ex["prediction"]) and len(po) == e + 1
    assert ex["candidate"].shape == (e, 6, 2) and ex["candidate"].dtype == np.float32
    assert len(ex["context_run"]) == len(co) - 1
    # Each context is a step of its run: context_run is non-decreasing.
    assert (np.diff(ex["context_run"]) >= 0).all()
    # Re-predict a sample with the teacher: identical up to float32 rounding of the storage.
    rng = np.random.default_rng(0)
    for i in rng.choice(e, size=min(e, 25), replace=False):
        c = ex["example_context"][i]
        h = ex["history"][co[c]:co[c + 1]].astype(np.float64)
        got = ex["prediction"][po[i]:po[i + 1]]
        assert got.shape == (len(h) - 1, 6, 2)
        # the recorder saw float64 inputs; float32 storage moves them by < 1e-4 m
        want = teacher.predict(h, ex["candidate"][i:i + 1].astype(np.float64))[0]
        np.testing.assert_allclose(got, want, atol=5e-3)
    # Candidates are distinct within each context.
    for c in range(len(co) - 1):
        cands = ex["candidate"][ex["example_context"] == c]
        assert len(np.unique(cands.reshape(len(cands), -1), axis=0)) == len(cands)
    # Predictor calls over all steps >= distinct examples.
    assert int(r["steps"]["predictor_calls"].sum()) >= e


def test_errors(scenes: list[Path], tmp_path: Path) -> None:
    with pytest.raises(nudge.ScenarioError, match="nope.safetensors"):
        nudge.simulate([tmp_path / "nope.safetensors"], "constant_velocity")
    with pytest.raises(nudge.WeightsError, match="missing.safetensors"):
        nudge.simulate(scenes[:1], tmp_path / "missing.safetensors")
    with pytest.raises(nudge.SettingsError, match="world"):
        nudge.simulate(scenes[:1], "constant_velocity", world="mars")
    with pytest.raises(nudge.SettingsError, match="world"):
        nudge.simulate(scenes[:1], "constant_velocity", world="predictor")
    with pytest.raises(nudge.InputError, match="must be a teacher"):
        nudge.simulate(scenes[:1], "constant_velocity", world_predictor="student")
    with pytest.raises(nudge.InputError, match="log_replay"):
        nudge.simulate(scenes[:1], "constant_velocity", world="log_replay", world_predictor="teacher")
    with pytest.raises(nudge.InputError, match="idm"):
        nudge.simulate(scenes[:1], "constant_velocity", world="teacher", idm=nudge.assets_dir() / "worlds" / "idm.json")
    with pytest.raises(nudge.WorldFileError, match="missing.json"):
        nudge.simulate(scenes[:1], "constant_velocity", world="idm", idm=tmp_path / "missing.json")
    bad = tmp_path / "bad_idm.json"
    bad.write_text((nudge.assets_dir() / "worlds" / "idm.json").read_text().replace('"nudge.idm/1"', '"nudge.idm/9"'))
    with pytest.raises(nudge.WorldFileError, match="schema"):
        nudge.simulate(scenes[:1], "constant_velocity", world="idm", idm=bad)
    with pytest.raises(nudge.SettingsError, match="fault_brake_limit"):
        nudge.simulate(scenes[:1], "constant_velocity", fault_brake_limit=-1.0)
    with pytest.raises(nudge.SettingsError, match="stall_progress"):
        nudge.simulate(scenes[:1], "constant_velocity", stall_progress=-0.1)
    for bad_crawl in (1.5, -0.1, float("nan")):
        with pytest.raises(nudge.SettingsError, match="crawl_fraction"):
            nudge.simulate(scenes[:1], "constant_velocity", crawl_fraction=bad_crawl)
    with pytest.raises(nudge.InputError, match="threads"):
        nudge.simulate(scenes[:1], "constant_velocity", threads=0)
    with pytest.raises(nudge.InputError, match="runs"):
        nudge.simulate(scenes[:1], "constant_velocity", runs=0)
    with pytest.raises(nudge.InputError, match="on_error"):
        nudge.simulate(scenes[:1], "constant_velocity", on_error="ignore")
    # The student decodes a fixed 6 steps; the teacher rolls out any horizon
    # (python/train/tests/test_horizon.py plans with it at 10).
    with pytest.raises(nudge.SettingsError, match="`model.horizon` = 5 does not fit: the student predicts 6"):
        nudge.simulate(scenes[:1], "student", settings=nudge.PlannerSettings(model={"horizon": 5}))


def test_one_lane_scene_raises_or_is_skipped(scenes: list[Path], tmp_path: Path) -> None:
    """A scene whose road has one lane has no target lane: ScenarioError, or an error row."""
    from safetensors.numpy import load_file, save_file
    from safetensors import safe_open

    src = scenes[0]
    with safe_open(str(src), "numpy") as f:
        meta = f.metadata()
    t = load_file(str(src))
    b = t["lane_bounds"]
    t["lane_bounds"] = np.array([b[0], b[-1]])
    t["lane_centres"] = np.array([(b[0] + b[-1]) / 2])
    t["ego_lane"] = np.array([0], dtype=t["ego_lane"].dtype)
    one = tmp_path / "one_lane.safetensors"
    save_file(t, str(one), metadata=meta)
    try:
        nudge.Scenario.load(one)
    except nudge.ScenarioError:
        pytest.skip("the scenario reader rejects this one-lane road itself")
    with pytest.raises(nudge.ScenarioError, match="no lane adjacent"):
        nudge.simulate([one], "constant_velocity")
    r = nudge.simulate([one, src], "constant_velocity", on_error="skip", max_steps=2, world="log_replay")
    assert "no lane adjacent" in r["runs"]["error"][0] and r["runs"]["error"][1] is None
    assert r["runs"]["n_steps"][0] == 0 and (r["steps"]["run"] == 1).all()


def test_scene_seeds(scenes: list[Path]) -> None:
    a = nudge.simulate(scenes[:2], "constant_velocity", scene_seeds=[7, 11], runs=2, max_steps=1)
    np.testing.assert_array_equal(a["runs"]["seed"], [7, 8, 11, 12])
    # Without per-scene seeds, scene i starts at seed + i * runs.
    b = nudge.simulate(scenes[:2], "constant_velocity", seed=9, runs=2, max_steps=1)
    np.testing.assert_array_equal(b["runs"]["seed"], [9, 10, 11, 12])
    np.testing.assert_array_equal(a["runs"]["target_lane"][2:], b["runs"]["target_lane"][2:])
    with pytest.raises(nudge.InputError, match="scene_seeds"):
        nudge.simulate(scenes[:2], "constant_velocity", scene_seeds=[1])


def test_limits(scenes: list[Path]) -> None:
    with pytest.raises(nudge.InputError, match="`threads`: must be in 1..=256"):
        nudge.simulate(scenes[:1], "constant_velocity", threads=10**6)
    with pytest.raises(nudge.SettingsError, match="max_steps"):
        nudge.simulate(scenes[:1], "constant_velocity", max_steps=10**9)
    with pytest.raises(nudge.SettingsError, match="max_steps"):
        nudge.simulate(scenes[:1], "constant_velocity", max_steps=0)


def test_abort_columns_and_switch(scenes: list[Path]) -> None:
    """`aborts` / `y_goal` are reported; with aborts disabled the goal is always the target lane,
    and with them the goal only ever leaves the target for the ego's own lane after a run of
    unsafe planning steps."""
    off = nudge.simulate(scenes, "constant_velocity", seed=3, threads=2, abort_after=0, max_steps=12,
                         world="log_replay")
    runs, steps = off["runs"], off["steps"]
    assert (runs["aborts"] == 0).all()
    np.testing.assert_array_equal(steps["y_goal"], runs["y_target"][steps["run"]])
    on = nudge.simulate(scenes, "constant_velocity", seed=3, threads=2, abort_after=1, abort_hold=2, max_steps=12,
                        world="log_replay")
    runs, steps = on["runs"], on["steps"]
    for r in range(len(runs["scenario"])):
        rows = np.nonzero(steps["run"] == r)[0]
        goal = steps["y_goal"][rows]
        away = np.nonzero(goal != runs["y_target"][r])[0]
        assert (len(away) > 0) == (runs["aborts"][r] > 0)
        for k in away:
            # Each hold starts right after a step without a safe plan, or continues a hold.
            assert k >= 1
            status = steps["status"][rows[k - 1]]
            assert status in ("Fallback", "Unsafe", "SolverFailed") or goal[k - 1] != runs["y_target"][r]


def test_bad_abort_settings_raise(scenes: list[Path]) -> None:
    with pytest.raises(nudge.SettingsError, match="abort_after"):
        nudge.simulate(scenes[:1], "constant_velocity", abort_after=10_000)


def test_idm_world_is_seeded_and_its_metrics_are_consistent(scenes: list[Path]) -> None:
    """The idm world gives the same runs for the same seeds, and the run metrics agree with the
    step columns they summarise."""
    a = nudge.simulate(scenes[:3], "constant_velocity", world="idm", seed=4, runs=2, threads=2)
    b = nudge.simulate(scenes[:3], "constant_velocity", world="idm", seed=4, runs=2, threads=1)
    for k in ("x", "y", "v", "ttc", "traffic_v"):
        np.testing.assert_array_equal(a["steps"][k], b["steps"][k])
    runs, steps = a["runs"], a["steps"]
    assert runs["world"] == ["idm"] * 6
    for r in range(6):
        m = steps["run"] == r
        assert runs["off_road_steps"][r] == steps["off_road"][m].sum()
        assert runs["straddle_steps"][r] == steps["straddle"][m].sum()
        assert runs["slow_steps"][r] == steps["slow"][m].sum()
        assert runs["slow_planned_steps"][r] == steps["slow_planned"][m].sum()
        assert runs["slow_planned_free_steps"][r] == steps["slow_planned_free"][m].sum()
        # On a free road: nobody in the path within 2 s at the faster of the ego and the traffic.
        speed = np.fmax(steps["v"][m], steps["traffic_v"][m])
        free = steps["lead_gap"][m] >= 2.0 * speed
        np.testing.assert_array_equal(steps["slow_planned_free"][m], steps["slow_planned"][m] & free)
        assert runs["min_ttc"][r] == steps["ttc"][m].min()
        assert runs["progress"][r] == steps["progress"][m][-1]
        inside = np.flatnonzero(steps["in_target_lane"][m])
        assert runs["steps_to_lane"][r] == (inside[0] + 1 if inside.size else -1)
        jerk = steps["jerk"][m][1:]
        assert np.isnan(steps["jerk"][m][0]) and runs["max_abs_jerk"][r] == np.abs(jerk).max(initial=0.0)
        assert runs["success"][r] == (runs["steps_to_target"][r] >= 0 and not runs["collision"][r])


def test_idm_world_file_fifo_and_device_are_refused_without_blocking(scenes: list[Path], tmp_path: Path) -> None:
    """Issue 49 class 2: a FIFO as the idm world file blocked forever (Ctrl-C did not end it),
    /dev/zero was read until memory ran out; both are refused by name before reading."""
    import os
    import subprocess
    import sys

    fifo = tmp_path / "idm.fifo"
    os.mkfifo(fifo)
    code = ("import sys, nudge\n"
            "try:\n"
            f"    nudge.simulate([{str(scenes[0])!r}], 'constant_velocity', world='idm', idm=sys.argv[1])\n"
            "except nudge.WorldFileError as e:\n"
            "    print(e)\n")
    for path, what in ((fifo, "a FIFO"), (Path("/dev/zero"), "a character device")):
        try:
            out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=60)
        except subprocess.TimeoutExpired:
            pytest.fail(f"reading {path} as the idm world file blocked")
        assert str(path) in out.stdout and what in out.stdout, out.stdout + out.stderr
