"""Reaction measures (nudge_train.training.reaction_measure, nudge_train.experiments.reaction_*,
nudge_train.training.reaction): the metric on synthetic cases with a known answer, the reaction
loss against its pairwise definition, a synthetic cut-in against the analytic fall-back, a collapse
guard on the shipped teacher, and the student report's training stages read from a weights file's
provenance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from nudge_train.data.tracks import LaneMap, TrackTable
from nudge_train.distill.contexts import Context
from nudge_train.training.reaction_measure import (
    follower_row,
    keep_lane,
    lane_change_candidates,
    model_predictor,
    per_context,
    planner_reactions,
    predict,
    reaction,
)
from nudge_train.experiments.reaction_cutins import cutin_case, cutin_reactions
from nudge_train.experiments.reaction_report import meets_target
from nudge_train.idm.cutins import CutIn, Tracks
from nudge_train.training.reaction import reaction_loss

REPO = Path(__file__).resolve().parents[3]
BOUNDS = np.array([-1.75, 1.75, 5.25, 8.75])  # three 3.5 m lanes; lane 0 centred on y = 0
T6 = 0.3 * np.arange(1, 7)


def _history(rows: list[tuple[float, float, float]]) -> np.ndarray:
    """[N, 8, 2] constant-velocity histories ending at (x, y) with speed v (x only)."""
    t = 0.3 * np.arange(-7, 1)
    return np.stack([np.stack([x + v * t, np.full(8, y)], -1) for x, y, v in rows]).astype(np.float32)


def _yielding(gain: float):
    """A synthetic predictor: every other agent moves at its last speed, minus ``gain`` times the
    ego candidate's lateral offset from its last observed y (so the reaction is known)."""

    def fn(history: np.ndarray, cands: np.ndarray) -> np.ndarray:
        v = (history[1:, -1, 0] - history[1:, -2, 0]) / 0.3
        base = history[1:, -1][None, :, None, :] + np.zeros((len(cands), 1, 6, 1), np.float32)
        base[..., 0] += v[None, :, None] * T6[None, None, :]
        lat = np.abs(cands[:, :, 1] - history[0, -1, 1])  # [B, 6]
        base[..., 0] -= gain * lat[:, None, :]
        return base

    return fn


def _context(history: np.ndarray, reaches: list[float], target: int) -> Context:
    x0, y0 = history[0, -1]
    cands = np.stack([np.stack([x0 + 20 * T6, y0 + r * (T6 / 1.8)], -1) for r in reaches]).astype(np.float32)
    teacher = np.zeros((len(reaches), history.shape[0] - 1, 6, 2), np.float32)
    return Context(history=history, candidates=cands, teacher=teacher, lane_bounds=BOUNDS, target_lane=target,
                   scene="synthetic", interactive=False)


def test_follower_is_the_nearest_vehicle_behind_in_the_lane() -> None:
    h = _history([(100, 0, 20), (90, 3.5, 20), (80, 3.5, 20), (110, 3.5, 20), (95, 0, 20), (99, 7.0, 20)])
    assert follower_row(h, BOUNDS, 1) == 1  # 90 beats 80; 110 is ahead
    assert follower_row(h, BOUNDS, 0) == 4  # own lane
    assert follower_row(h, BOUNDS, 2) == 5
    assert follower_row(h[:1], BOUNDS, 1) == -1


def test_keep_lane_holds_y_and_keeps_x() -> None:
    c = np.random.default_rng(0).normal(size=(3, 6, 2)).astype(np.float32)
    k = keep_lane(c, 1.25)
    assert np.array_equal(k[..., 0], c[..., 0])
    assert np.all(k[..., 1] == np.float32(1.25))
    assert not np.shares_memory(k, c)


def test_planner_reaction_of_a_synthetic_yielding_model_is_known() -> None:
    # Ego in lane 0, follower in lane 1 at 90 m, a vehicle ahead in lane 1 (ignored).
    h = _history([(100, 0, 20), (90, 3.5, 18), (120, 3.5, 20)])
    ctx = _context(h, [0.5, 1.5, 2.5, -2.0], target=1)  # 0.5: too little; -2.0: the wrong way
    assert list(lane_change_candidates(ctx, 1.0)) == [1, 2]
    res = planner_reactions([ctx], {"y": _yielding(0.2), "none": _yielding(0.0)}, min_lateral=1.0)
    assert len(res) == 1 and res[0].follower == 1
    np.testing.assert_allclose(res[0].models["y"], [-0.2 * 1.5, -0.2 * 2.5], atol=1e-5)
    assert per_context(res, "y")[0] == pytest.approx(-0.4, abs=1e-5)
    assert per_context(res, "none")[0] == 0.0
    # Already in the target lane, or no follower there: the call is not counted.
    assert planner_reactions([_context(h, [1.5], target=0)], {"y": _yielding(0.2)}) == []
    lonely = _history([(100, 0, 20), (120, 3.5, 20)])
    assert planner_reactions([_context(lonely, [1.5], target=1)], {"y": _yielding(0.2)}) == []


def test_reaction_reads_the_follower_at_1_8_s() -> None:
    p = np.zeros((2, 3, 6, 2), np.float32)
    k = np.zeros_like(p)
    p[0, 1, 5, 0], p[1, 1, 5, 0], p[0, 1, 4, 0] = -0.3, 0.1, 9.0
    np.testing.assert_allclose(reaction(p, k, follower=2), [-0.3, 0.1])
    with pytest.raises(ValueError, match="follower"):
        reaction(p, k, follower=0)


def test_reaction_loss_is_the_pairwise_difference_error() -> None:
    g = torch.Generator().manual_seed(3)
    err = torch.randn(5, 4, 6, 2, generator=g, dtype=torch.float64)
    group = torch.tensor([0, 0, 1, 1, 1])
    pos, react = reaction_loss(err, group, 2)
    assert float(pos) == pytest.approx(float((err**2).sum() / (4 * 6) / 5))
    # (1 / R) sum_r |e_r - mean|^2 = (1 / 2R^2) sum_{r,s} |e_r - e_s|^2, per group.
    expect = 0.0
    for rows in ([0, 1], [2, 3, 4]):
        e = err[rows]
        d = ((e[:, None] - e[None, :]) ** 2).sum(dim=(2, 3, 4)) / (4 * 6)
        expect += float(d.sum()) / (2 * len(rows))
    assert float(react) == pytest.approx(expect / 5)
    # The same error on every candidate of a context (an offset): no reaction error.
    same = err[:1].expand(3, -1, -1, -1)
    assert float(reaction_loss(same, torch.zeros(3, dtype=torch.int64), 1)[1]) == pytest.approx(0.0, abs=1e-12)


def test_target_is_within_30_percent_of_the_teacher() -> None:
    assert meets_target(-0.08, -0.1) and meets_target(-0.12, -0.1)
    assert not meets_target(-0.06, -0.1) and not meets_target(0.0, -0.1) and not meets_target(0.0, 0.0)


def _cutin_tracks(decel: float) -> tuple[Tracks, CutIn]:
    """Intruder (1) moving from y = 0 to y = 3.5 between t = 1 and 5 s (centre crossing the line
    y = 1.75 at t = 3 s); follower (2) in the new lane braking at ``decel`` from t = 3 s; a
    vehicle (3) 200 m away (outside the radius); 0.1 s frames."""
    t = np.round(np.arange(0, 80) * 0.1, 1)
    u = np.clip((t - 1.0) / 4.0, 0, 1)
    rows = {
        1: (50 + 20 * t, 3.5 * (3 * u**2 - 2 * u**3), np.full_like(t, 20.0)),
        2: (30 + 20 * t - 0.5 * decel * np.maximum(t - 3.0, 0) ** 2, np.full_like(t, 3.5),
            20 - decel * np.maximum(t - 3.0, 0)),
        3: (250 + 20 * t, np.zeros_like(t), np.full_like(t, 20.0)),
    }
    cols = {k: [] for k in ("vehicle", "t", "x", "y", "speed")}
    for vid, (x, y, v) in rows.items():
        cols["vehicle"].append(np.full(t.shape, vid))
        cols["t"].append(t)
        cols["x"].append(x)
        cols["y"].append(y)
        cols["speed"].append(v)
    c = {k: np.concatenate(v) for k, v in cols.items()}
    n = len(c["t"])
    lane = np.where(c["y"] > 1.75, 0, 1)
    table = TrackTable(scene="syn", source="syn", vehicle=c["vehicle"].astype(np.int64), t=c["t"], x=c["x"], y=c["y"],
                       heading=np.zeros(n), speed=c["speed"], length=np.full(n, 4.5), width=np.full(n, 1.8),
                       lane=lane.astype(np.int64), flags=np.zeros(n, np.int64),
                       lanes=LaneMap(bounds=np.array([-1.75, 1.75, 5.25]), x_range=(0.0, 2000.0)))
    event = CutIn(source="us101", scene="syn", group="g", split="test", intruder=1, follower=2, old_leader=-1,
                  lane_from=1, lane_to=0, t_centre=3.0, t_edge=None, gap=15.5, follower_speed=20.0,
                  intruder_speed=20.0, time_headway=0.8, follower_after_s=4.2, follower_before_s=3.0)
    return Tracks(table), event


def test_cutin_case_matches_the_synthetic_tracks() -> None:
    tr, e = _cutin_tracks(decel=1.0)
    case = cutin_case(tr, e, lead_s=0.9)
    assert case is not None
    assert case.history.shape == (2, 8, 2)  # the far vehicle is left out
    t_s = 2.1
    np.testing.assert_allclose(case.history[0, -1], [50 + 20 * t_s, tr.series(1, "y", np.array([t_s]))[0]], atol=1e-9)
    np.testing.assert_allclose(case.candidate[0, :, 0], 50 + 20 * (t_s + T6), atol=1e-9)
    assert np.all(case.keep[0, :, 1] == np.float32(case.history[0, -1, 1]))
    # Follower brakes from t = 3.0 s: at t_s + 1.8 = 3.9 s it is 0.5 * 1.0 * 0.9^2 behind constant speed.
    assert case.real_fb == pytest.approx(-0.405, abs=1e-9)
    assert (case.x0, case.v0) == pytest.approx((30 + 20 * t_s, 20.0))
    # Too early for the history: no case.
    assert cutin_case(tr, e, lead_s=1.2) is None
    r = cutin_reactions([case], {"y": _yielding(0.2)})
    lat = abs(case.candidate[0, 5, 1] - case.history[0, -1, 1])
    assert r["y"]["reaction"][0] == pytest.approx(-0.2 * lat, abs=1e-4)
    assert r["y"]["fall_back"][0] == pytest.approx(-0.2 * lat, abs=1e-3)  # constant speed otherwise


def test_cutin_case_over_a_3_s_horizon() -> None:
    """The same event over 10 steps: the candidate is the intruder's next 3 s; the real fall-back
    is read at every step (1.8 s as the 6-step case, 3.0 s: 0.5 · 1.0 · 2.1² behind)."""
    tr, e = _cutin_tracks(decel=1.0)
    six, ten = cutin_case(tr, e, lead_s=0.9), cutin_case(tr, e, lead_s=0.9, steps=10)
    assert six is not None and ten is not None
    assert ten.candidate.shape == (1, 10, 2) and ten.real_fbs is not None and ten.real_fbs.shape == (10,)
    np.testing.assert_array_equal(ten.candidate[:, :6], six.candidate)
    assert ten.real_fbs[5] == pytest.approx(six.real_fb, abs=1e-9)
    assert ten.real_fb == ten.real_fbs[9] == pytest.approx(-0.5 * 2.1**2, abs=1e-9)
    # The predicted fall-back is read at the step asked for (a constant-speed predictor: 0 at 1.8 and 3.0 s).
    def constant_speed(history: np.ndarray, cands: np.ndarray) -> np.ndarray:
        v = history[1:, -1] - history[1:, -2]
        k = np.arange(1, cands.shape[1] + 1)[None, :, None]
        return np.broadcast_to(history[1:, -1][:, None] + k * v[:, None], (len(cands), len(history) - 1,
                                                                            cands.shape[1], 2))
    for step in (5, 9):
        r = cutin_reactions([ten], {"cv": constant_speed}, step=step)["cv"]
        assert r["fall_back"][0] == pytest.approx(0.0, abs=1e-3) and r["reaction"][0] == 0.0


# ------------------------------------------------------------------ shipped models (collapse guard)

SCENES = sorted((REPO / "assets" / "scenes").glob("*.safetensors"))


def _lane_change_pairs():
    nudge = pytest.importorskip("nudge")
    for p in SCENES:
        sc = nudge.Scenario.load(p)
        h = np.asarray(sc.history, np.float32)
        b, c = np.asarray(sc.lane_bounds), np.asarray(sc.lane_centres)
        x0, y0 = h[0, -1]
        for lane in (sc.ego_lane - 1, sc.ego_lane + 1):
            fol = follower_row(h, b, lane) if 0 <= lane < len(c) else -1
            if fol < 0:
                continue
            u = T6 / 1.8
            cand = np.stack([x0 + float(sc.speed[0]) * T6, y0 + (c[lane] - y0) * (3 * u**2 - 2 * u**3)], -1)
            cand = cand[None].astype(np.float32)
            yield h, np.concatenate([cand, keep_lane(cand, float(y0))]), fol


@pytest.mark.skipif(not SCENES, reason="no shipped scenes")
def test_shipped_teacher_reacts_to_a_lane_change() -> None:
    """A full lane change (constant speed, smoothstep to the adjacent lane's centre in 1.8 s)
    against keeping the lane, on every shipped scene with a follower in that lane: the shipped
    teacher's follower falls back (median -0.09 m over 8 cases when written); fails if that
    reaction collapses below a third of it."""
    from nudge_train.training.export import load_generator

    teacher = load_generator(REPO / "assets" / "models" / "teacher.safetensors")
    vals = []
    for h, both, fol in _lane_change_pairs():
        p = predict(teacher, h, both)
        vals.append(float(reaction(p[:1], p[1:], fol)[0]))
    assert len(vals) >= 6
    assert np.median(vals) < -0.03
    assert np.mean(np.array(vals) < -0.01) >= 0.5


@pytest.mark.skipif(not SCENES, reason="no shipped scenes")
def test_rust_teacher_labels_the_keep_lane_pairs_like_pytorch() -> None:
    """The reaction distillation labels its keep-lane counterfactuals with the Rust teacher."""
    nudge = pytest.importorskip("nudge")
    from nudge_train.training.export import load_generator

    path = REPO / "assets" / "models" / "teacher.safetensors"
    torch_fn = model_predictor(load_generator(path))
    rust = nudge.Predictor.load(path)
    h, both, _ = next(iter(_lane_change_pairs()))
    got = np.asarray(rust.predict(h.astype(np.float64), both.astype(np.float64)))
    np.testing.assert_allclose(got, torch_fn(h, both), atol=2e-3, rtol=0)


# -------------------------------------------------------------------- training-time smooth pooling


def _pool_case():
    from nudge_train.models.networks import PoolHiddenNet, SceneIndex

    torch.manual_seed(0)
    net = PoolHiddenNet(embedding_dim=4, h_dim=5, pool_hidden_dim=8, bottleneck_dim=6).double()
    h = torch.randn(5, 5, dtype=torch.float64, requires_grad=True)
    pos = torch.randn(5, 2, dtype=torch.float64) * 10
    scenes = SceneIndex.build(torch.tensor([[0, 3], [3, 5]]), 5, "cpu")
    return net, h, pos, scenes


def test_smooth_pool_tends_to_the_max_and_reaches_every_neighbour() -> None:
    net, h, pos, scenes = _pool_case()
    hard = net(h, pos, scenes)
    for tau in (1.0, 0.1, 1e-3):
        net.soft_temperature = tau
        soft = net(h, pos, scenes)
        # max <= smooth max <= max + tau * log(n), n = 3 and 2 agents per scene.
        assert torch.all(soft >= hard - 1e-12)
        assert torch.all(soft <= hard + tau * np.log(3) + 1e-12)
    # Gradient of agent 0's pooled features w.r.t. every member's hidden state of its scene:
    # the max gives it to the winners only, the smooth maximum to all (none to the other scene).
    net.soft_temperature = 0.0
    (g_hard,) = torch.autograd.grad(net(h, pos, scenes)[0].sum(), h)
    net.soft_temperature = 1.0
    (g_soft,) = torch.autograd.grad(net(h, pos, scenes)[0].sum(), h)
    assert torch.all(g_soft[:3].abs().sum(dim=1) > 0)
    assert torch.all(g_soft[3:] == 0) and torch.all(g_hard[3:] == 0)
    assert int((g_hard[:3].abs().sum(dim=1) > 0).sum()) <= int((g_soft[:3].abs().sum(dim=1) > 0).sum())


def test_reaction_configs_parse_and_unknown_keys_are_refused(tmp_path: Path) -> None:
    from nudge_train.errors import ConfigError
    from nudge_train.training.reaction import load_reaction_config, pool_temperature

    for name in ("student_react.toml", "student_react_cont.toml", "student_react_hard.toml",
                 "student_react_l200.toml"):
        mcfg, tcfg = load_reaction_config(REPO / "python" / "train" / "configs" / name)
        assert mcfg.kind == "student" and mcfg.pool_every_timestep
    _, soft = load_reaction_config(REPO / "python" / "train" / "configs" / "student_react.toml")
    assert pool_temperature(soft, 0.0) == soft.soft_pool_start
    assert pool_temperature(soft, soft.soft_pool_until * 0.999) == pytest.approx(soft.soft_pool_end, rel=0.02)
    assert pool_temperature(soft, soft.soft_pool_until) == 0.0
    bad = tmp_path / "bad.toml"
    bad.write_text('[model]\nkind = "student"\n[train]\nreaction_wieght = 3.0\n')
    with pytest.raises(ConfigError, match="reaction_wieght"):
        load_reaction_config(bad)


def test_student_report_lists_every_training_stage_from_the_provenance(tmp_path: Path) -> None:
    """The student report's training section follows ``init_provenance`` from the newest
    reaction stage back to the position-only student, with each stage's own numbers."""
    from nudge_train.experiments.student import _training_lines
    from nudge_train.models.config import student_config
    from nudge_train.models.networks import build_model
    from nudge_train.training.export import export_generator

    base = {"config": "student.toml", "data": "data/distill", "best_epoch": 30, "best_val_ade": 0.1176,
            "commit": "a" * 40}

    def stage(config: str, init: str, step: int, ade: float, parent: dict) -> dict:
        return {"config": config, "data": "runs/distill", "commit": "b" * 40, "hardware": "1 CPU threads",
                "train": {"init": init, "reference": "l2.safetensors", "reaction_weight": 1000.0, "lr": 5e-4,
                          "time_budget_s": 900.0, "eval_every": 500},
                "selected": {"step": step, "val_ade": ade, "val_fde": 2 * ade, "val_reaction_error": 0.04},
                "reference": {"val_ade": 0.1117, "val_fde": 0.2271, "val_reaction_error": 0.0596},
                "init_provenance": parent}

    first = stage("student_react.toml", "l2.safetensors", 5000, 0.1220, base)
    cont = stage("student_react_cont.toml", "runs/student_react/student.safetensors", 2500, 0.1053, first)
    cfg = student_config()
    path = export_generator(build_model(cfg)[0], cfg, tmp_path / "s.safetensors", trained=True, provenance=cont)
    lines = _training_lines(path)
    assert len(lines) == 3
    assert "student_react_cont.toml" in lines[0] and "kept step 2500" in lines[0] and "0.1053 / 0.2106" in lines[0]
    assert "from `runs/student_react/student.safetensors`" in lines[0]
    assert "student_react.toml" in lines[1] and "kept step 5000" in lines[1] and "from `l2.safetensors`" in lines[1]
    assert "nudge-train student --config python/train/configs/student.toml" in lines[2]
    assert "best epoch 31" in lines[2] and "0.1176" in lines[2]
    # A student without a recorded start is one stage.
    path = export_generator(build_model(cfg)[0], cfg, tmp_path / "p.safetensors", trained=True, provenance=base)
    assert len(_training_lines(path)) == 1
