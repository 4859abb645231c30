"""The log-replay extrapolation fit (``nudge_train.experiments.replay_extrapolation``) against
tracks whose sideways motion decays by a known factor, written as scene files, and against the
step-by-step rule of the Rust world it fits."""

from __future__ import annotations

import numpy as np
import pytest
from safetensors.numpy import save_file

from nudge_train.data.errors import DataError
from nudge_train.experiments.replay_extrapolation import GRID, fit, lateral_offset, pairs, rmse


def _write_scenes(folder, rho: float, n_scenes: int, seed: int, noise: float = 0.0) -> None:
    """Scenes of 1 ego + 5 vehicles whose sideways displacement per step is Δy at the end of
    their history and ρ times the previous one after it (plus Gaussian position noise of
    ``noise`` m on the future), 8 observed and 20 future steps; one vehicle per scene loses
    its log after 7 future steps."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    for s in range(n_scenes):
        n, t_obs, t_fut = 6, 8, 20
        hist = np.zeros((n, t_obs, 2))
        fut = np.zeros((n, t_fut, 2))
        valid = np.ones((n, t_fut), dtype=np.uint8)
        for i in range(n):
            v, dy = rng.uniform(8, 20), rng.normal(0, 0.1)
            x0, y0 = rng.uniform(-30, 30), rng.uniform(-5, 5)
            hist[i, :, 0] = x0 + v * 0.3 * np.arange(t_obs)
            hist[i, :, 1] = y0 + dy * np.arange(t_obs)
            y, step = hist[i, -1, 1], dy
            for k in range(t_fut):
                step *= rho
                y += step
                fut[i, k] = (hist[i, -1, 0] + v * 0.3 * (k + 1), y + rng.normal(0, noise) if noise else y)
        valid[1, 7:] = 0
        save_file({"history": hist, "future": fut, "future_valid": valid}, str(folder / f"s{s:03d}.safetensors"))


def test_the_closed_form_is_the_step_by_step_rule_of_the_world() -> None:
    # The Rust world repeats rho times the last sideways displacement each step.
    dy = np.array([0.12, -0.07, 0.0])
    for rho in (0.0, 0.3, 0.75, 1.0):
        y, step = np.zeros(3), dy.copy()
        for k in range(1, 25):
            step = rho * step
            y = y + step
            assert np.allclose(lateral_offset(dy, np.full(3, k), rho), y, atol=1e-12), (rho, k)
    with pytest.raises(ValueError, match="rho"):
        lateral_offset(dy, np.ones(3), 1.5)


@pytest.mark.parametrize("rho", [0.0, 0.6, 0.75, 1.0])
def test_the_fit_recovers_the_decay_the_tracks_were_drawn_with(tmp_path, rho: float) -> None:
    _write_scenes(tmp_path / "s", rho, n_scenes=30, seed=1, noise=0.02)
    p = pairs(tmp_path / "s", progress=False)
    assert p.scenes == 30 and p.anchors == 30 * 5
    # 4 full vehicles × 20 steps + one cut at 7, per scene
    assert p.k.size == 30 * (4 * 20 + 7)
    assert fit(p) == rho
    # Noise only: the true rho's error is the noise level, and every other grid value does worse.
    assert rmse(p, rho) == pytest.approx(0.02, rel=0.15)
    assert all(rmse(p, r) > rmse(p, rho) for r in GRID if r != rho)


def test_a_scene_without_the_tracks_is_a_typed_error_naming_it(tmp_path) -> None:
    (tmp_path / "s").mkdir()
    save_file({"history": np.zeros((2, 8, 2))}, str(tmp_path / "s" / "bad.safetensors"))
    with pytest.raises(DataError, match="bad.safetensors.*'future'"):
        pairs(tmp_path / "s", progress=False)
    with pytest.raises(DataError, match="no scene files"):
        pairs(tmp_path / "empty", progress=False)
    _write_scenes(tmp_path / "n", 0.5, n_scenes=1, seed=2)
    f = tmp_path / "n" / "s000.safetensors"
    from safetensors.numpy import load_file

    d = load_file(str(f))
    d["future"][3, 2, 1] = np.nan
    save_file(d, str(f))
    with pytest.raises(DataError, match="agent 3: a non-finite"):
        pairs(tmp_path / "n", progress=False)
