"""The interaction experiment's pieces on hand-made cases: the blocked-lane rule, the dense-scene
selection on the shipped scenes, the paired statistics and the issue's bar."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import nudge
from nudge_train.experiments.interaction import (
    SEED_TRIES,
    InteractionConfig,
    blocked,
    dense_runs,
    paired,
    start_geometry,
    verdict,
)

REPO = Path(__file__).resolve().parents[3]


def _scene(others: list[tuple[float, float, float]], ego_length: float = 4.5) -> SimpleNamespace:
    """The ego at (0, 0) in lane 1 ([-1.85, 1.85]); lane 2 is [1.85, 5.55]; others (x, y, length)."""
    pos = [(0.0, 0.0)] + [(x, y) for x, y, _ in others]
    history = np.zeros((len(pos), 8, 2))
    history[:, -1, :] = pos
    size = np.array([[ego_length, 1.9]] + [[length, 1.9] for _, _, length in others])
    return SimpleNamespace(history=history, size=size, lane_bounds=np.array([-5.55, -1.85, 1.85, 5.55]))


@pytest.mark.parametrize(("others", "lane", "margin", "want"), [
    ([(0.0, 3.7, 4.5)], 2, 0.0, True),            # alongside
    ([(6.4, 3.7, 4.5)], 2, 2.0, True),            # centre distance 6.4 < 4.5 + 2
    ([(6.6, 3.7, 4.5)], 2, 2.0, False),           # 6.6 > 6.5: a 2.1 m bumper gap
    ([(-6.4, 3.7, 4.5)], 2, 2.0, True),           # behind as well
    ([(-6.4, 3.7, 4.5)], 2, 1.0, False),          # a smaller margin
    ([(0.0, 3.7, 4.5)], 0, 2.0, False),           # another lane
    ([(0.0, 1.85, 4.5)], 2, 2.0, True),           # on the lower bound: in the lane
    ([(0.0, 5.55, 4.5)], 2, 2.0, False),          # on the upper bound: the next lane
    ([(8.0, 3.7, 12.0)], 2, 0.0, True),           # a long truck reaching back over the ego (rear at 2.0)
    ([(9.0, 3.7, 12.0)], 2, 0.0, False),          # its rear at 3.0, the ego's front at 2.25
    ([], 2, 2.0, False),
])
def test_blocked_by_hand(others: list, lane: int, margin: float, want: bool) -> None:
    assert blocked(_scene(others), lane, margin) is want


def test_dense_runs_keep_only_seeds_that_draw_a_blocked_lane() -> None:
    files = sorted((REPO / "assets" / "scenes").glob("*.safetensors"))
    runs = dense_runs(files, 3, 2.0, 0)
    bases = np.random.default_rng([0, 2]).integers(0, 2**31, size=len(files)).tolist()
    by_name = {p: b for p, b in zip(files, bases, strict=True)}
    assert runs, "some shipped scene is dense"
    for path, seeds in runs:
        sc = nudge.Scenario.load(path)
        tried = [by_name[path] + r for r in range(SEED_TRIES)]
        # Independently: the first three seeds whose lane has a vehicle within the ego's extent + 2 m.
        pos, length, bounds = sc.history[:, -1, :], sc.size[:, 0], sc.lane_bounds
        want = []
        for s in tried:
            lane = sc.target_lane(s)
            hit = any(bounds[lane] <= pos[j, 1] < bounds[lane + 1]
                      and abs(pos[j, 0] - pos[0, 0]) < (length[0] + length[j]) / 2 + 2.0
                      for j in range(1, sc.n_agents))
            if hit:
                want.append(s)
        assert seeds == want[:3]
    assert len(runs) < len(files) or all(len(s) == 3 for _, s in runs)


def _cols(scenes: list[str], seeds: list[int], success: list[bool], lane_steps: list[int],
          lanes: list[int] | None = None) -> dict[str, list]:
    n = len(scenes)
    return {"scenario": scenes, "seed": seeds, "success": success, "steps_to_lane": lane_steps,
            "steps_to_target": lane_steps, "target_lane": lanes or [1] * n, "error": [None] * n}


def test_paired_by_hand() -> None:
    a = _cols(["s1", "s1", "s2", "s3"], [1, 2, 5, 7], [True, False, False, True], [10, -1, -1, 4])
    # b lacks (s3, 7), has an extra run, in another order.
    b = _cols(["s2", "s1", "s1", "s4"], [5, 2, 1, 9], [True, True, True, True], [8, 20, 10, 3])
    p = paired(a, b, budget=30, n_boot=200)
    assert p["pairs"] == 3 and p["scenes"] == 2
    assert (p["both"], p["only_a"], p["only_b"], p["neither"]) == (1, 0, 2, 0)
    assert p["p"] == pytest.approx(0.5)
    # Success 1/3 -> 3/3: +66.7 pp; time to lane (s1,1) 3.0 -> 3.0, (s1,2) 9.0 -> 6.0, (s2,5) 9.0 -> 2.4.
    assert p["d_success_pp"][0] == pytest.approx(200.0 / 3.0)
    assert p["d_ttl"][0] == pytest.approx((0.0 - 3.0 - 6.6) / 3.0)
    # Reaching the lane at all: (s1,2) and (s2,5) only in b.
    assert (p["lane_only_a"], p["lane_only_b"]) == (0, 2)


def test_paired_refuses_pairs_with_different_lanes() -> None:
    a = _cols(["s1"], [1], [True], [3], lanes=[0])
    b = _cols(["s1"], [1], [True], [3], lanes=[2])
    with pytest.raises(ValueError, match="target lanes"):
        paired(a, b, budget=30, n_boot=10)


def test_verdict_needs_the_size_and_an_interval_excluding_zero() -> None:
    base = {"pairs": 10, "d_success_pp": (0.0, -5.0, 5.0), "d_ttl": (0.0, -0.1, 0.1)}
    assert verdict(base) == "not met"
    assert verdict({**base, "d_success_pp": (12.0, 1.0, 20.0)}) == "**met**"
    assert verdict({**base, "d_success_pp": (12.0, -1.0, 20.0)}) == "not met"
    assert verdict({**base, "d_ttl": (-0.6, -1.0, -0.2)}) == "**met**"
    assert verdict({**base, "d_ttl": (-0.4, -1.0, -0.2)}) == "not met"
    assert verdict({**base, "d_ttl": (-0.6, -1.0, 0.1)}) == "not met"
    assert verdict({"pairs": 0}) == "–"


def test_start_geometry_by_hand() -> None:
    # Ego (4.5 x 1.9) at y = 0, lanes [-1.85, 1.85] and [1.85, 5.55]; a 4.5 x 1.9 car at (5.5, 3.7).
    sc = _scene([(5.5, 3.7, 4.5), (40.0, 3.7, 4.5)])
    s = nudge.PlannerSettings.default()
    gap, need, depth = start_geometry(sc, 2, s)
    assert gap == pytest.approx(1.0)  # 5.5 - 4.5
    assert need == pytest.approx(np.sqrt(2.0) * 4.5 + 1.5 - 4.5)
    # Level with it, the ego's centre stays sqrt(2) * 1.9 + 0.3 below 3.7; its edge 0.95 above that.
    assert depth == pytest.approx((3.7 - 1.85) - (np.sqrt(2.0) * 1.9 + 0.3) + 0.95)
    assert start_geometry(sc, 0, s) is None


def test_horizon_10_leaves_the_6_step_students_out(tmp_path: Path) -> None:
    """At 10 steps only the teacher can plan among the models (the students decode 6 steps: the typed
    refusal decides, not a list); every arm's settings carry the horizon; a bad horizon names itself."""
    from nudge_train.experiments.interaction import InteractionConfig, serves, start_reactions

    student = tmp_path / "s.safetensors"
    student.write_bytes(nudge.model_path("student").read_bytes())
    cfg = InteractionConfig(horizon=10, candidate=student)
    assert cfg.planners() == [("teacher", "teacher")]
    assert cfg.arm_settings(True).model["horizon"] == 10 and cfg.arm_settings(True).safety["ablate_reaction"]
    assert [p for p, _ in InteractionConfig(candidate=student).planners()] == ["teacher", "student", "student_react"]
    assert [p for p, _ in InteractionConfig(horizon=6, compare_horizon=10).planners()] == ["teacher"]
    assert serves("teacher", 10) and not serves("student", 10) and serves("student", 6)
    with pytest.raises(ValueError, match="--horizon"):
        InteractionConfig(horizon=0).validate()
    # The reaction at the dense starts read at the last of 10 steps (3.0 s).
    runs = dense_runs(nudge.scene_paths(), 1, 2.0, 0)[:2]
    r6, r10 = start_reactions(runs, {"teacher": "teacher"}), start_reactions(runs, {"teacher": "teacher"}, 10)
    assert r6["teacher"].shape == r10["teacher"].shape and r6["teacher"].size > 0
    assert not np.array_equal(r6["teacher"], r10["teacher"])


def test_settings_file_is_the_base_of_every_arm(tmp_path: Path) -> None:
    """``--settings``: every arm starts from the file (``ablate_reaction`` is set per arm); a
    missing file or a bad field is refused naming it."""
    assert InteractionConfig().base_settings() == nudge.PlannerSettings.default()
    good = tmp_path / "wide.json"
    good.write_text('{"safety": {"margin_y": 0.5}, "cost": {"w_y": 20.0}}')
    cfg = InteractionConfig(settings=good)
    cfg.validate()
    s = cfg.base_settings()
    assert s.safety["margin_y"] == 0.5 and s.cost["w_y"] == 20.0 and not s.safety["ablate_reaction"]
    with pytest.raises(ValueError, match="no such file"):
        InteractionConfig(settings=tmp_path / "none.json").validate()
    bad = tmp_path / "bad.json"
    bad.write_text('{"safety": {"margin_y": 50.0}}')
    with pytest.raises(ValueError, match="margin_y"):
        InteractionConfig(settings=bad).validate()
    # The arm's horizon overrides the file's; ablate_reaction is per arm.
    arm = InteractionConfig(settings=good, horizon=10).arm_settings(True)
    assert arm.safety["margin_y"] == 0.5 and arm.model["horizon"] == 10 and arm.safety["ablate_reaction"]


def test_merge_runs_are_the_scenes_whose_ego_lane_ends() -> None:
    from safetensors.numpy import load_file

    from nudge_train.data.scenarios import is_merge_scenario
    from nudge_train.experiments.interaction import is_merge, merge_runs

    files = sorted((REPO / "assets" / "scenes").glob("*.safetensors")) + sorted(
        (REPO / "assets" / "scenes" / "merge").glob("*.safetensors"))
    runs = merge_runs(files, 2, 0)
    bases = np.random.default_rng([0, 2]).integers(0, 2**31, size=len(files)).tolist()
    by_name = {p: b for p, b in zip(files, bases, strict=True)}
    # Independently: the build-time rule on the file's raw tensors.
    want = [p for p in files if is_merge_scenario(load_file(str(p)))]
    assert len(want) >= 7, "the shipped merge scenes are merges"
    assert [p for p, _ in runs] == want
    assert all(is_merge(nudge.Scenario.load(p)) == (p in want) for p in files)
    for path, seeds in runs:
        assert seeds == [by_name[path], by_name[path] + 1]
        sc = nudge.Scenario.load(path)
        ego = sc.ego_lane
        for s in seeds:
            lane = sc.target_lane(s)
            assert abs(lane - ego) == 1
            # The target outlasts the ego's lane, which ends ahead.
            assert sc.lane_extents[lane][1] > sc.lane_extents[ego][1]


def test_merge_scenes_setting_is_checked() -> None:
    with pytest.raises(ValueError, match="--scenes"):
        InteractionConfig(scenes="merges").validate()


def test_vehicle_of_drops_the_start_time_only() -> None:
    from nudge_train.experiments.interaction import vehicle_of

    assert vehicle_of("us101-23_1-t06.6-ego90") == "us101-23_1-ego90"
    assert vehicle_of("us101-9_1-t02.1-ego434") == vehicle_of("us101-9_1-t03.9-ego434")
    assert vehicle_of("us101-9_1-t02.1-ego434") != vehicle_of("us101-9_1-t02.1-ego433")
    assert vehicle_of("i80-3-t12-ego7") == "i80-3-ego7"
    assert vehicle_of("plain") == "plain"


def test_paired_by_vehicle_resamples_vehicles() -> None:
    # Two start times of one vehicle and one of another: 2 clusters by vehicle, 3 by scene.
    names = ["a-t01.0-ego1", "a-t01.3-ego1", "a-t01.0-ego2"]
    a = _cols(names, [0, 0, 0], [True, True, False], [3, 3, -1])
    b = _cols(names, [0, 0, 0], [True, True, True], [3, 3, 4])
    assert paired(a, b, 30, 200)["clusters"] == 3
    p = paired(a, b, 30, 200, by_vehicle=True)
    assert p["clusters"] == 2 and p["scenes"] == 3 and p["only_b"] == 1


def test_one_cluster_has_no_interval_and_never_meets_the_bar() -> None:
    # Three start times of one vehicle: by vehicle one cluster, so no interval, whatever the gain.
    names = ["a-t01.0-ego1", "a-t01.3-ego1", "a-t01.6-ego1"]
    a = _cols(names, [0, 0, 0], [False, False, False], [-1, -1, -1])
    b = _cols(names, [0, 0, 0], [True, True, True], [3, 3, 3])
    p = paired(a, b, 30, 200, by_vehicle=True)
    assert p["d_success_pp"][0] == pytest.approx(100.0)
    assert all(np.isnan(p["d_success_pp"][1:])) and all(np.isnan(p["d_ttl"][1:]))
    assert verdict(p) == "not met"
    assert verdict(paired(a, b, 30, 200)) == "**met**"  # by scene: three clusters
