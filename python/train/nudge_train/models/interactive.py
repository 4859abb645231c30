"""Interactive prediction: how the other agents react to each ego candidate trajectory.

Both functions take the scene history ``[N, obs_len, 2]`` (agent 0 = ego, absolute positions in
metres, one step = ``cfg.dt`` s) and ego candidates ``[B, t_plan, 2]`` (the ego's positions at steps
1..t_plan after the last observed one) and return the others' positions ``[B, N − 1, t_plan, 2]``.
Each candidate is its own scene in the batch, so candidates never see each other.
They are the reference semantics the Rust predictor (crates/predictor) reproduces.
"""

from __future__ import annotations

import torch
from torch import Tensor

from nudge_train.models.networks import TrajectoryGenerator

__all__ = ["batch_scenes", "student_interactive", "teacher_interactive"]


def _check_inputs(
    gen: TrajectoryGenerator, history: Tensor, candidates: Tensor, horizon: int | None = None
) -> tuple[int, int]:
    cfg = gen.cfg
    t_plan = cfg.t_plan if horizon is None else horizon
    if history.dim() != 3 or history.shape[1] != cfg.obs_len or history.shape[2] != 2:
        raise ValueError(f"history: expected shape [N, {cfg.obs_len}, 2], got {list(history.shape)}")
    if history.shape[0] < 1:
        raise ValueError("history: needs at least the ego (N >= 1)")
    if candidates.dim() != 3 or candidates.shape[1] != t_plan or candidates.shape[2] != 2:
        raise ValueError(
            f"candidates: expected shape [B, {t_plan}, 2], got {list(candidates.shape)}"
        )
    if candidates.shape[0] < 1:
        raise ValueError("candidates: needs at least one candidate (B >= 1)")
    if not torch.isfinite(history).all():
        raise ValueError("history: contains NaN or infinite values")
    if not torch.isfinite(candidates).all():
        raise ValueError("candidates: contains NaN or infinite values")
    return int(history.shape[0]), int(candidates.shape[0])


def batch_scenes(num_agents: int, num_scenes: int, device: torch.device | str) -> Tensor:
    """``seq_start_end`` ``[num_scenes, 2]`` for ``num_scenes`` equal scenes of ``num_agents``."""
    starts = torch.arange(num_scenes, device=device, dtype=torch.int64) * num_agents
    return torch.stack([starts, starts + num_agents], dim=1)


def teacher_interactive(
    gen: TrajectoryGenerator,
    history: Tensor,
    candidates: Tensor,
    z: Tensor | None = None,
    horizon: int | None = None,
) -> Tensor:
    """Recursive teacher prediction: ``t_plan`` one-step generator calls per candidate.

    For τ = 1..t_plan: run the whole generator on the last ``obs_len`` positions of every agent
    (displacements recomputed, first one 0), keep the others' one-step prediction, put the ego at
    ``candidates[:, τ−1]``, append, slide the window. The same z (``z`` ``[noise_dim]``, default
    the generator's ``fixed_noise``) is used for every candidate and every step. Step τ = 1 does not
    depend on the candidate, so it is computed once for the history and shared.

    Args:
        gen: teacher generator (``pred_len`` 1).
        history: ``[N, obs_len, 2]`` positions (m), agent 0 = ego.
        candidates: ``[B, t_plan, 2]`` ego positions (m).
        z: ``[noise_dim]`` noise, or None for ``gen.fixed_noise``.
        horizon: steps to roll out (``t_plan`` above), or None for ``gen.cfg.t_plan``; the
            network predicts one step per call, so any horizon >= 1 is the same network rolled
            out longer or shorter.

    Returns:
        ``[B, N − 1, t_plan, 2]`` predicted positions (m) of agents 1..N−1.
    """
    if horizon is not None and horizon < 1:
        raise ValueError(f"horizon: expected >= 1 steps, got {horizon}")
    n, b = _check_inputs(gen, history, candidates, horizon)
    cfg = gen.cfg
    t_plan = cfg.t_plan if horizon is None else horizon
    device = gen.device
    dtype = gen.encoder.spatial_embedding.weight.dtype
    history = history.to(device=device, dtype=dtype)
    candidates = candidates.to(device=device, dtype=dtype)
    noise_one: Tensor | None = None
    if cfg.noise_dim > 0:
        zz = gen.fixed_noise if z is None else z.to(device=device, dtype=dtype)
        if tuple(zz.shape) != (cfg.noise_dim,):
            raise ValueError(f"z: expected shape [{cfg.noise_dim}], got {list(zz.shape)}")
        noise_one = zz.unsqueeze(0)
    elif z is not None and z.numel() > 0:
        raise ValueError(f"z: this generator has noise_dim 0, got shape {list(z.shape)}")

    was_training = gen.training
    if was_training:
        gen.eval()
    try:
        with torch.inference_mode():
            # τ = 1: history only, one scene, shared by every candidate.
            window1 = history.transpose(0, 1)  # [T, N, 2]
            first, _ = gen(window1, batch_scenes(n, 1, device), noise=noise_one, steps=1)
            step1 = first[0].unsqueeze(0).expand(b, n, 2).clone()  # [B, N, 2]
            step1[:, 0] = candidates[:, 0]
            window = history.unsqueeze(0).expand(b, n, cfg.obs_len, 2)  # [B, N, T, 2]
            window = torch.cat([window[:, :, 1:], step1.unsqueeze(2)], dim=2)
            outputs = [step1[:, 1:]]
            sse = batch_scenes(n, b, device)
            noise = None if noise_one is None else noise_one.expand(b, -1)
            for tau in range(1, t_plan):
                obs = window.reshape(b * n, cfg.obs_len, 2).transpose(0, 1)  # [T, B·N, 2]
                pred, _ = gen(obs, sse, noise=noise, steps=1)
                step = pred[0].reshape(b, n, 2).clone()
                step[:, 0] = candidates[:, tau]
                outputs.append(step[:, 1:])
                window = torch.cat([window[:, :, 1:], step.unsqueeze(2)], dim=2)
            return torch.stack(outputs, dim=2)  # [B, N-1, t_plan, 2]
    finally:
        if was_training:
            gen.train()


def student_interactive(gen: TrajectoryGenerator, history: Tensor, candidates: Tensor) -> Tensor:
    """One-pass student prediction with the ego candidate imposed at every decoder step.

    Encoder + pooling + context run once on the history (they do not depend on the candidate);
    the decoder then runs ``t_plan`` steps for all candidates at once, each candidate its own scene.

    Args:
        gen: student generator (``pred_len`` = t_plan, usually no noise).
        history: ``[N, obs_len, 2]`` positions (m), agent 0 = ego.
        candidates: ``[B, t_plan, 2]`` ego positions (m).

    Returns:
        ``[B, N − 1, t_plan, 2]`` predicted positions (m) of agents 1..N−1.
    """
    n, b = _check_inputs(gen, history, candidates)
    cfg = gen.cfg
    if cfg.pred_len != cfg.t_plan:
        raise ValueError(f"pred_len: the student must decode t_plan={cfg.t_plan} steps, has {cfg.pred_len}")
    device = gen.device
    dtype = gen.encoder.spatial_embedding.weight.dtype
    history = history.to(device=device, dtype=dtype)
    candidates = candidates.to(device=device, dtype=dtype)
    was_training = gen.training
    if was_training:
        gen.eval()
    try:
        with torch.inference_mode():
            obs_one = history.transpose(0, 1)  # [T, N, 2]
            ctx = gen.context(obs_one, gen.scene_index(batch_scenes(n, 1, device), n))  # [N, C]
            scenes = gen.scene_index(batch_scenes(n, b, device), n * b)
            obs = obs_one.repeat(1, b, 1)  # [T, B·N, 2]
            noise = None
            if cfg.noise_dim > 0:
                noise = gen.fixed_noise.unsqueeze(0).expand(b, -1)
            pred, _ = gen.decode(
                ctx.repeat(b, 1),
                obs,
                scenes,
                noise=noise,
                ego_future=candidates.transpose(0, 1),  # [t_plan, B, 2]
                steps=cfg.t_plan,
            )
            # pred [t_plan, B·N, 2] → [B, N, t_plan, 2]
            return pred.reshape(cfg.t_plan, b, n, 2).permute(1, 2, 0, 3)[:, 1:].contiguous()
    finally:
        if was_training:
            gen.train()
