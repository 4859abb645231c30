"""The Gymnasium environment nudge.env: it passes Gymnasium's checker in both action modes,
an episode is a function of its seed, out-of-bounds actions are refused (never clamped), a
foreign action is the Python planner's step, and nudge's planner run through the env gives,
run for run, the records of nudge.simulate on the shipped scenes in all three worlds."""

from __future__ import annotations

import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import gymnasium as gym
import nudge
import nudge.env
from gymnasium.utils.env_checker import check_env
from nudge.env import ENV_ID, LaneChangeEnv, NudgeAgent

WORLDS = ("teacher", "idm", "log_replay")
# Wall times: never equal between two runs.
TIMING_COLUMNS = {"mpc_s", "z_s", "z_median_s"}


def same(a: object, b: object) -> bool:
    """Equal, bit for bit for floats; the env's None (a missing value) equals NaN."""
    if a is None and isinstance(b, float):
        return math.isnan(b)
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or np.float64(a).tobytes() == np.float64(b).tobytes()
    return a == b


def episode(env: gym.Env, agent, **reset) -> tuple[list, list, dict]:
    obs, info = env.reset(**reset)
    infos, observations = [info], [obs]
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(agent(obs))
        assert not (terminated and truncated)
        infos.append(info)
        observations.append(obs)
        done = terminated or truncated
    return observations, infos, info


@pytest.mark.parametrize("mode", ["control", "trajectory"])
def test_check_env_passes(scenes: list[Path], mode: str) -> None:
    env = gym.make(ENV_ID, scenes=scenes[:2], world="log_replay", predictor="constant_velocity",
                   action_mode=mode, max_steps=5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
        # gym.make's passive checker on the wrapped env's first reset and step.
        env.reset(seed=1)
        env.step(env.action_space.sample())
        # Gymnasium's only warnings are its advice on Box bounds: normalise the action space
        # (the actions are nudge's physical inputs; gymnasium.wrappers.RescaleAction does it)
        # and bound the observation space (road-frame positions and speeds are not bounded).
    advice = ("symmetric and normalized", "value is -infinity", "value is infinity")
    assert [str(w.message) for w in caught if not any(a in str(w.message) for a in advice)] == []


def test_make_imports_the_module_itself(scenes: list[Path]) -> None:
    code = (
        "import gymnasium as gym, nudge\n"
        f"env = gym.make('nudge.env:{ENV_ID}', scenes=nudge.scene_paths()[:1], world='log_replay', max_steps=2)\n"
        "print(type(env.unwrapped).__name__, env.action_space.shape)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["LaneChangeEnv", "(2,)"]


def test_spaces_follow_the_settings(scenes: list[Path]) -> None:
    env = LaneChangeEnv(scenes[:3], world="log_replay", action_mode="trajectory", neighbours=5)
    b = nudge.PlannerSettings.default().to_dict()["bounds"]
    assert env.action_space.shape == (6, 2)
    np.testing.assert_array_equal(env.action_space.low[:, 0], -b["delta_max"])
    np.testing.assert_array_equal(env.action_space.high[:, 1], b["a_max"])
    np.testing.assert_array_equal(env.action_space.low[:, 1], b["a_min"])
    assert env.observation_space["neighbours"].shape == (5, 6)
    lanes = max(len(nudge.Scenario.load(p).lane_centres) for p in scenes[:3])
    assert env.observation_space["lanes"].shape == (lanes,)
    obs, info = env.reset(options={"scene": 1, "run_seed": 4})
    sc = nudge.Scenario.load(scenes[1])
    assert info["scenario"] == sc.name and info["run_seed"] == 4
    assert info["target_lane"] == sc.target_lane(4)
    # The road frame relative to the ego: the ego's own lane centre is the nearest lane.
    y = sc.history[0, -1, 1]
    assert obs["ego"][0] == 0.0 and obs["ego"][1] == y and obs["ego"][3] == sc.speed[0]
    np.testing.assert_array_equal(obs["lanes"][: len(sc.lane_centres)], np.asarray(sc.lane_centres) - y)
    assert obs["target"][0] == sc.lane_centres[info["target_lane"]] - y
    # The nearest neighbour is the nearest other vehicle at the last observed step, with its size.
    rel = sc.history[1:, -1] - sc.history[0, -1]
    j = int(np.argmin(np.hypot(rel[:, 0], rel[:, 1])))
    np.testing.assert_array_equal(obs["neighbours"][0, :2], rel[j])
    np.testing.assert_array_equal(obs["neighbours"][0, 4:], sc.size[j + 1])
    assert obs["neighbours_mask"].sum() == min(5, sc.n_agents - 1)


def test_same_seed_same_episode_bit_for_bit(scenes: list[Path]) -> None:
    def rollout(seed: int) -> tuple[list, list]:
        env = LaneChangeEnv(scenes, world="idm", predictor="constant_velocity", max_steps=6)
        env.action_space.seed(seed)
        obs, infos, _ = episode(env, lambda o: env.action_space.sample(), seed=seed)
        rows = [{k: v for k, v in i.items() if k not in TIMING_COLUMNS} for i in infos]
        return obs, rows

    a_obs, a = rollout(11)
    b_obs, b = rollout(11)
    _, c = rollout(12)
    assert len(a) == len(b)
    for x, y in zip(a_obs, b_obs):
        for k in x:
            assert x[k].tobytes() == y[k].tobytes(), k
    for x, y in zip(a[1:], b[1:]):
        assert x.keys() == y.keys()
        assert all(same(x[k], y[k]) for k in x if k not in ("run", "collisions")), x
    assert (a[0]["scenario"], a[0]["run_seed"]) != (c[0]["scenario"], c[0]["run_seed"])


@pytest.mark.parametrize("mode", ["control", "trajectory"])
def test_out_of_bounds_actions_are_refused_not_clamped(scenes: list[Path], mode: str) -> None:
    env = LaneChangeEnv(scenes[:1], world="log_replay", predictor="constant_velocity", action_mode=mode)
    env.reset(seed=0)
    good = np.zeros(env.action_space.shape)
    where = "action[0]" if mode == "control" else "action[0, 0]"
    for bad, what in [
        (0.2, f"{where} (steering δ (rad)) = 0.2 is outside [-0.15, 0.15]: actions are refused, never clamped"),
        (np.nan, f"{where} (steering δ (rad)) is not finite (nan)"),
    ]:
        act = good.copy()
        act.reshape(-1, 2)[0, 0] = bad
        with pytest.raises(nudge.InputError) as e:
            env.step(act)
        assert str(e.value).startswith(what)
    act = good.copy()
    act.reshape(-1, 2)[-1, 1] = -5.5
    with pytest.raises(nudge.InputError, match="outside"):
        env.step(act)
    with pytest.raises(nudge.InputError, match="shape"):
        env.step(np.zeros(3))
    # Nothing was applied: the episode is still at its first step.
    _, _, _, _, info = env.step(good)
    assert info["step"] == 0 and info["delta"] == 0.0 and info["accel"] == 0.0


def test_a_foreign_action_is_the_python_planners_step(scenes: list[Path]) -> None:
    """The same inputs through the env and through simulate(planner=...) give the same steps."""

    class Brake:
        def plan(self, obs: dict) -> dict:
            return {"delta": [0.01] * obs["horizon"], "accel": [-0.5] * obs["horizon"]}

    r = nudge.simulate(scenes[:1], "student", planner=Brake(), world="idm", max_steps=5, seed=2)
    env = LaneChangeEnv(scenes[:1], world="idm", max_steps=5)
    _, infos, last = episode(env, lambda o: np.array([0.01, -0.5]), options={"scene": 0, "run_seed": 2})
    steps = r["steps"]
    assert len(infos) - 1 == len(steps["step"])
    for k, info in enumerate(infos[1:]):
        assert info["nudge_plan"] is False
        for col, values in steps.items():
            if col in TIMING_COLUMNS or col in ("run", "ego"):
                continue
            assert same(info[col], values[k].item() if hasattr(values[k], "item") else values[k]), (k, col)


def test_nudge_through_the_env_equals_simulate_on_the_shipped_scenes(scenes: list[Path]) -> None:
    """Every runs.csv column and every step (states bit for bit) of nudge's planner run through
    the env equal nudge.simulate's, on the 10 shipped scenes in all three worlds, half of the
    worlds in each action mode."""
    assert len(scenes) == 10
    compared = 0
    for w, world in enumerate(WORLDS):
        r = nudge.simulate(scenes, "student", world=world, seed=0)
        runs, steps = r["runs"], r["steps"]
        env = LaneChangeEnv(scenes, world=world, action_mode=("control", "trajectory")[w % 2])
        agent = NudgeAgent(env)
        for i in range(len(scenes)):
            _, infos, last = episode(env, agent.act, options={"scene": i, "run_seed": i})
            row = last["run"]
            for col, values in runs.items():
                v = values[i]
                v = v.item() if hasattr(v, "item") else v
                assert same(row[col], v), (world, i, col, row[col], v)
            mine = steps["run"] == i
            assert len(infos) - 1 == int(mine.sum())
            for col, values in steps.items():
                if col in TIMING_COLUMNS or col in ("run", "ego"):
                    continue
                expected = values[mine] if isinstance(values, np.ndarray) else [v for v, m in zip(values, mine) if m]
                for k, info in enumerate(infos[1:]):
                    e = expected[k]
                    e = e.item() if hasattr(e, "item") else e
                    assert same(info[col], e), (world, i, k, col, info[col], e)
            assert all(info["nudge_plan"] for info in infos[1:])
            assert last["end_reason"] in ("settled", "max_steps", "lane_ended", "lane_not_begun", "turned_across")
            compared += 1
    assert compared == 30


def test_episode_end_follows_the_run(scenes: list[Path]) -> None:
    env = LaneChangeEnv(scenes[:1], world="log_replay", max_steps=3)
    agent = NudgeAgent(env)
    _, infos, last = episode(env, agent.act, seed=0)
    assert len(infos) - 1 == 3 and last["end_reason"] == "max_steps"
    assert last["run"]["n_steps"] == 3 and last["run"]["outcome"] in ("Unfinished", "Waiting", "Collision")
    with pytest.raises(nudge.InputError, match="ended"):
        env.step(np.zeros(2))
    env = LaneChangeEnv(scenes[:1], world="log_replay")
    _, infos, last = episode(env, NudgeAgent(env).act, seed=0)
    assert last["end_reason"] == "settled" and last["run"]["success"]
    assert last["run"]["steps_to_target"] == len(infos) - 1


def test_import_without_gymnasium_names_the_extra(tmp_path: Path) -> None:
    blocker = tmp_path / "gymnasium"
    blocker.mkdir()
    (blocker / "__init__.py").write_text("raise ImportError('no gymnasium here')\n")
    code = "import nudge; import nudge.env"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(tmp_path), "PATH": ""})
    assert out.returncode != 0
    assert "nudge-planner[env]" in out.stderr and "ImportError" in out.stderr


def test_the_native_session_refuses_misuse_with_typed_errors(scenes: list[Path]) -> None:
    from nudge._native import Session

    s = Session([str(p) for p in scenes[:1]], "constant_velocity", world="log_replay", max_steps=1,
                assets=str(nudge.assets_dir()))
    with pytest.raises(nudge.InputError, match="call reset"):
        s.step([0.0] * 6, [0.0] * 6)
    with pytest.raises(nudge.InputError, match="scene"):
        s.reset(1, 0)
    with pytest.raises(nudge.InputError, match="seed"):
        s.reset(0, -1)
    s.reset(0, 0)
    with pytest.raises(nudge.InputError, match=r'"accel": expected 6 values \(the horizon\), got 5'):
        s.step([0.0] * 6, [0.0] * 5)
    with pytest.raises(nudge.InputError, match=r'"delta"\[2\] = 0.5 is outside'):
        s.step([0.0, 0.0, 0.5, 0.0, 0.0, 0.0], [0.0] * 6)
    row, end, run, collisions = s.step([0.0] * 6, [0.0] * 6)
    assert end == "max_steps" and run["n_steps"] == 1 and row["step"] == 0
    with pytest.raises(nudge.InputError, match=r"the run ended after 1 steps \(max_steps\)"):
        s.step([0.0] * 6, [0.0] * 6)
    with pytest.raises(nudge.SettingsError, match="world"):
        Session([str(p) for p in scenes[:1]], world="nowhere")
