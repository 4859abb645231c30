"""Training loop, config parsing, loss, checkpoint/resume and evaluation metrics."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from nudge_train import paths
from nudge_train.data.loader import WindowSet
from nudge_train.models.config import teacher_config
from nudge_train.models.networks import build_model
from nudge_train.training.config import TrainConfig, load_config
from nudge_train.training.evaluate import (
    evaluate_constant_velocity,
    evaluate_constant_velocity_at,
    evaluate_generator,
    evaluate_generator_at,
)
from nudge_train.training.loop import train, variety_loss


def _windows(n_windows: int = 24, seed: int = 0, pred_len: int = 6) -> WindowSet:
    """Highway-like windows: agents in lanes 3.7 m apart at 8–25 m/s, some drifting laterally."""
    rng = np.random.default_rng(seed)
    pos, offs, inter = [], [0], []
    t = np.arange(8 + pred_len, dtype=np.float64) * 0.3
    for _ in range(n_windows):
        n = int(rng.integers(1, 7))
        x0 = rng.uniform(-40, 40, n)
        x0[0] = 0.0
        lane = rng.integers(0, 4, n) * 3.7
        v = rng.uniform(8, 25, n)
        drift = rng.choice([0.0, 0.0, 0.8], n)
        p = np.stack([x0[:, None] + v[:, None] * t, lane[:, None] + drift[:, None] * t], axis=-1)
        pos.append(p.astype(np.float32))
        offs.append(offs[-1] + n)
        inter.append(int(drift.any()))
    return WindowSet(np.concatenate(pos), np.array(offs, np.int64), np.array(inter, np.uint8), pred_len)


def _truncated(data: WindowSet, pred_len: int) -> WindowSet:
    return WindowSet(data.positions[:, : 8 + pred_len].copy(), data.offsets, data.interactive, pred_len)


def test_variety_loss_matches_brute_force() -> None:
    g = torch.Generator().manual_seed(1)
    pred = torch.randn(5, 6, 7, 2, generator=g)
    fut = torch.randn(6, 7, 2, generator=g)
    sse = torch.tensor([[0, 3], [3, 4], [4, 7]])
    expected = []
    for a, b in sse.tolist():
        per_k = [float(((pred[k, :, a:b] - fut[:, a:b]) ** 2).sum()) / ((b - a) * 6) for k in range(5)]
        expected.append(min(per_k))
    assert float(variety_loss(pred, fut, sse)) == pytest.approx(np.mean(expected), rel=1e-6)


def test_config_rejects_unknown_keys_and_bad_sizes(tmp_path: Path) -> None:
    bad_key = tmp_path / "a.toml"
    bad_key.write_text('[model]\nkind = "teacher"\nencoder_hdim = 32\n')
    with pytest.raises(ValueError, match="encoder_hdim"):
        load_config(bad_key)
    bad_size = tmp_path / "b.toml"
    bad_size.write_text('[model]\nkind = "teacher"\nmlp_dim = -4\n')
    with pytest.raises(ValueError, match="mlp_dim"):
        load_config(bad_size)
    bad_train = tmp_path / "c.toml"
    bad_train.write_text("[train]\nlearning_rate = 0.1\n")
    with pytest.raises(ValueError, match="learning_rate"):
        load_config(bad_train)
    bad_table = tmp_path / "d.toml"
    bad_table.write_text("[optim]\nlr = 0.1\n")
    with pytest.raises(ValueError, match="optim"):
        load_config(bad_table)
    with pytest.raises(ValueError, match="batch_size"):
        TrainConfig(batch_size=0).validate()


def test_shipped_teacher_configs_parse() -> None:
    planner_cfg = load_config(paths.configs() / "teacher_planner.toml")
    assert planner_cfg[1].train_steps == 1 and planner_cfg[1].val_metric == "recursive_fde"
    configs = sorted(paths.configs().glob("teacher_k*_adv*.toml"))
    assert len(configs) == 5
    pairs = set()
    for path in configs:
        mcfg, tcfg = load_config(path)
        assert mcfg.kind == "teacher" and mcfg.pool_hidden_dim == 512
        assert tcfg.k_samples == 20 and tcfg.train_steps == 1
        pairs.add((tcfg.k_var, tcfg.i_adv))
    assert pairs == {(1, 1), (1, 0), (30, 1), (64, 1), (64, 0)}
    smcfg, stcfg = load_config(paths.configs() / "student.toml")
    assert smcfg.kind == "student" and smcfg.noise_dim == 0 and smcfg.pool_every_timestep
    assert stcfg.k_samples == 1 and stcfg.train_steps == 6 and stcfg.data == "data/distill"


def _small_train_cfg(tmp_path: Path, **kw: object) -> TrainConfig:
    base = TrainConfig(out_dir=str(tmp_path / "run"), epochs=3, patience=5, batch_size=8, k_samples=3,
                       lr=3e-3, device="cpu", seed=3)
    return dataclasses.replace(base, **kw)


def test_training_lowers_validation_error_and_resumes(tmp_path: Path) -> None:
    data = _windows(32)
    mcfg = teacher_config().replace(pool_hidden_dim=32)
    gen0, _ = build_model(mcfg)
    before = evaluate_generator(gen0, data).ade6
    tcfg = _small_train_cfg(tmp_path, epochs=4, i_adv=1)
    summary = train(mcfg, tcfg, train_set=data, val_set=data, progress=False)
    assert summary["best_val_ade"] < before
    lines = (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()
    assert len(lines) == 4
    # Resume with more epochs continues from epoch 4 (log grows, nothing restarts).
    more = dataclasses.replace(tcfg, epochs=5)
    train(mcfg, more, resume=True, train_set=data, val_set=data, progress=False)
    assert len((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()) == 5


def test_training_is_deterministic(tmp_path: Path) -> None:
    data = _windows(16)
    mcfg = teacher_config().replace(pool_hidden_dim=16)
    a = train(mcfg, _small_train_cfg(tmp_path / "a", epochs=2), train_set=data, val_set=data, progress=False)
    b = train(mcfg, _small_train_cfg(tmp_path / "b", epochs=2), train_set=data, val_set=data, progress=False)
    assert a["best_val_ade"] == b["best_val_ade"]


def test_corrupted_checkpoint_is_named(tmp_path: Path) -> None:
    data = _windows(8)
    mcfg = teacher_config().replace(pool_hidden_dim=16)
    tcfg = _small_train_cfg(tmp_path, epochs=1)
    train(mcfg, tcfg, train_set=data, val_set=data, progress=False)
    last = tmp_path / "run" / "last.pt"
    last.write_bytes(last.read_bytes()[:100])
    with pytest.raises(RuntimeError, match="last.pt"):
        train(mcfg, dataclasses.replace(tcfg, epochs=2), resume=True, train_set=data, val_set=data, progress=False)


def test_constant_velocity_is_exact_on_constant_velocity_motion() -> None:
    data = _windows(10)
    m = evaluate_constant_velocity(data)
    assert m.ade6 < 1e-4 or data.interactive.any()  # drift is linear too: CV is exact
    assert m.fde6 < 1e-4
    assert m.agents == data.n_agents


def test_best_of_k_is_monotone_in_k() -> None:
    data = _windows(12)
    gen, _ = build_model(teacher_config().replace(pool_hidden_dim=16))
    best4 = evaluate_generator(gen, data, mode="recursive", samples=4, seed=5)
    best8 = evaluate_generator(gen, data, mode="recursive", samples=8, seed=5)
    # Same seed: the 8 draws extend the 4, so each scene's minimum can only go down.
    assert best8.ade6 <= best4.ade6 + 1e-12
    assert best8.agents == best4.agents == data.n_agents - len(data)


def test_samples_per_epoch_draws_a_seeded_subset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``samples_per_epoch`` visits that many distinct training windows per epoch, a different
    seeded subset each epoch."""
    import nudge_train.training.loop as training_mod

    data = _windows(40)
    val = _windows(6, seed=1)
    seen: list[list[int]] = []
    orig_batches, orig_lr = WindowSet.batches, training_mod.epoch_lr

    def spy(self: WindowSet, *a: object, **k: object):  # type: ignore[no-untyped-def]
        for b in orig_batches(self, *a, **k):  # type: ignore[arg-type]
            if self is data:
                seen[-1].extend(b.window.tolist())
            yield b

    def new_epoch(t: TrainConfig, e: int) -> float:
        seen.append([])
        return orig_lr(t, e)

    monkeypatch.setattr(WindowSet, "batches", spy)
    monkeypatch.setattr(training_mod, "epoch_lr", new_epoch)
    mcfg = teacher_config().replace(pool_hidden_dim=16)
    train(mcfg, _small_train_cfg(tmp_path, epochs=2, samples_per_epoch=12), train_set=data, val_set=val,
          progress=False)
    assert len(seen) == 2
    for epoch in seen:
        assert len(epoch) == 12 and len(set(epoch)) == 12
    assert seen[0] != seen[1]
    with pytest.raises(ValueError, match="samples_per_epoch"):
        TrainConfig(samples_per_epoch=-1).validate()


def test_scores_at_several_horizons_match_the_shorter_windows() -> None:
    """One 10-step roll-out scored at 6 and 10 steps: at 6 it is the 6-step evaluation of the same
    windows cut to 6 future steps (fixed z and best of k, the same draws), at 10 the 10-step one."""
    data = _windows(10, seed=3, pred_len=10)
    six = _truncated(data, 6)
    gen, _ = build_model(teacher_config().replace(pool_hidden_dim=16))
    for samples in (1, 4):
        at = evaluate_generator_at(gen, data, (6, 10), samples=samples, seed=2)
        for h, windows in ((6, six), (10, data)):
            want = evaluate_generator(gen, windows, mode="recursive", samples=samples, seed=2)
            got = at[h]
            assert (got.agents, got.scenes) == (want.agents, want.scenes)
            for k in ("ade1", "ade6", "fde6"):
                assert getattr(got, k) == pytest.approx(getattr(want, k), rel=1e-6, abs=1e-9), (samples, h, k)
    assert at[10].fde6 != at[6].fde6
    cv = evaluate_constant_velocity_at(data, (6, 10))
    for h, windows in ((6, six), (10, data)):
        want = evaluate_constant_velocity(windows, skip_ego=True)
        assert (cv[h].ade6, cv[h].fde6, cv[h].agents) == pytest.approx((want.ade6, want.fde6, want.agents))
    with pytest.raises(ValueError, match="10 future steps"):
        evaluate_generator_at(gen, data, (12,))
    with pytest.raises(ValueError, match=r"expected \[A, 14, 2\]"):
        WindowSet(data.positions, data.offsets, data.interactive)
