"""ADE / FDE of prediction models on held-out windows, with a constant-velocity baseline.

Two ways of predicting 6 steps (1.8 s) with one generator:

* ``decoder``: one generator call decoding 6 steps (Social-GAN's usual evaluation), all agents;
* ``recursive``: the planner's use of the teacher, 6 one-step calls with each window's ego set to
  its logged future after every step (the interactive prediction), scored on the other agents.

Each with the fixed noise vector (single sample, what the planner uses) and best-of-k (per scene,
the draw with the lowest summed ADE over its agents; Social-GAN's protocol). ADE = mean L2 error
over agents and steps 1..t; FDE = mean L2 error at step t (metres); at t = 1 both coincide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from nudge_train.data.loader import Batch, WindowSet
from nudge_train.models.networks import TrajectoryGenerator

__all__ = ["Metrics", "evaluate_constant_velocity", "evaluate_constant_velocity_at", "evaluate_generator",
           "evaluate_generator_at"]


@dataclass
class Metrics:
    """Errors (m) at horizons 1 and 6 over ``agents`` agents of ``scenes`` scenes."""

    ade1: float
    ade6: float
    fde6: float
    scenes: int
    agents: int

    @property
    def fde1(self) -> float:
        """FDE at one step (= ADE at one step)."""
        return self.ade1


class _Acc:
    def __init__(self) -> None:
        self.e1 = 0.0
        self.e_all = 0.0
        self.e6 = 0.0
        self.agents = 0
        self.scenes = 0

    def add(self, err: Tensor, scenes: int) -> None:
        """``err`` ``[6, A]`` L2 errors of the kept agents."""
        self.e1 += float(err[0].sum())
        self.e_all += float(err.mean(dim=0).sum())
        self.e6 += float(err[-1].sum())
        self.agents += err.shape[1]
        self.scenes += scenes

    def result(self) -> Metrics:
        a = max(self.agents, 1)
        return Metrics(self.e1 / a, self.e_all / a, self.e6 / a, self.scenes, self.agents)


def _keep_mask(batch: Batch, skip_ego: bool) -> Tensor:
    keep = torch.ones(batch.obs.shape[1], dtype=torch.bool)
    if skip_ego:
        keep[batch.seq_start_end[:, 0]] = False
    return keep


def _scene_of(batch: Batch) -> Tensor:
    sizes = batch.seq_start_end[:, 1] - batch.seq_start_end[:, 0]
    return torch.repeat_interleave(torch.arange(len(sizes)), sizes)


def _recursive(gen: TrajectoryGenerator, batch: Batch, noise: Tensor | None) -> Tensor:
    """Teacher's interactive roll-out with the egos on their logged future: ``[6, A, 2]``."""
    window = batch.obs
    egos = batch.seq_start_end[:, 0]
    out = []
    for tau in range(batch.fut.shape[0]):
        pred, _ = gen(window, batch.seq_start_end, noise=noise, steps=1)
        step = pred[0].clone()
        step[egos] = batch.fut[tau, egos]
        out.append(step)
        window = torch.cat([window[1:], step.unsqueeze(0)], dim=0)
    return torch.stack(out)


def _predict(gen: TrajectoryGenerator, batch: Batch, mode: str, noise: Tensor | None) -> Tensor:
    if mode == "recursive":
        return _recursive(gen, batch, noise)
    scenes = gen.scene_index(batch.seq_start_end, batch.obs.shape[1])
    ego_future = batch.fut[:, scenes.ego] if gen.cfg.kind == "student" else None
    pred, _ = gen(batch.obs, batch.seq_start_end, noise=noise, ego_future=ego_future, steps=batch.fut.shape[0])
    return pred


@torch.inference_mode()
def evaluate_generator(
    gen: TrajectoryGenerator,
    data: WindowSet,
    mode: str = "decoder",
    samples: int = 1,
    seed: int = 0,
    subset: np.ndarray | None = None,
    batch_size: int = 128,
) -> Metrics:
    """Metrics of ``gen`` on ``data`` (optionally only the windows in ``subset``).

    ``samples`` = 1 uses the fixed noise vector; > 1 draws that many z per scene (seeded) and keeps
    each scene's best draw. ``mode`` is ``"decoder"`` or ``"recursive"`` (see module doc); the
    recursive mode and the student skip the ego (it is imposed, not predicted).
    """
    if mode not in ("decoder", "recursive"):
        raise ValueError(f"mode: expected 'decoder' or 'recursive', got {mode!r}")
    gen.eval()
    device = gen.device
    rng = torch.Generator().manual_seed(seed)
    acc = _Acc()
    windows = np.arange(len(data)) if subset is None else np.asarray(subset)
    skip_ego = mode == "recursive" or gen.cfg.kind == "student"
    for i in range(0, len(windows), batch_size):
        batch = data.batch(windows[i : i + batch_size])
        dev = batch.to(device)
        s = batch.seq_start_end.shape[0]
        keep = _keep_mask(batch, skip_ego)
        scene_of = _scene_of(batch)
        best_err: Tensor | None = None
        best_score: Tensor | None = None
        for k in range(samples):
            noise = None
            if gen.cfg.noise_dim > 0 and samples > 1:
                noise = torch.randn(s, gen.cfg.noise_dim, generator=rng).to(device)
            pred = _predict(gen, dev, mode, noise).cpu()
            err = torch.linalg.norm(pred - batch.fut, dim=-1)  # [6, A]
            err = torch.where(keep.unsqueeze(0), err, torch.zeros_like(err))
            score = torch.zeros(s).index_add_(0, scene_of, err.mean(dim=0))
            if best_err is None or best_score is None:
                best_err, best_score = err, score
            else:
                better = score < best_score
                take = better[scene_of]
                best_err = torch.where(take.unsqueeze(0), err, best_err)
                best_score = torch.where(better, score, best_score)
            if gen.cfg.noise_dim == 0 or samples == 1:
                break
        assert best_err is not None
        acc.add(best_err[:, keep], s)
    return acc.result()


def evaluate_constant_velocity(
    data: WindowSet, skip_ego: bool = False, subset: np.ndarray | None = None
) -> Metrics:
    """Constant-velocity baseline: last observed displacement repeated."""
    acc = _Acc()
    windows = np.arange(len(data)) if subset is None else np.asarray(subset)
    for i in range(0, len(windows), 512):
        batch = data.batch(windows[i : i + 512])
        v = batch.obs[-1] - batch.obs[-2]
        steps = torch.arange(1, batch.fut.shape[0] + 1, dtype=v.dtype).view(-1, 1, 1)
        pred = batch.obs[-1].unsqueeze(0) + steps * v.unsqueeze(0)
        err = torch.linalg.norm(pred - batch.fut, dim=-1)
        keep = _keep_mask(batch, skip_ego)
        acc.add(err[:, keep], batch.seq_start_end.shape[0])
    return acc.result()


@torch.inference_mode()
def evaluate_generator_at(
    gen: TrajectoryGenerator,
    data: WindowSet,
    horizons: tuple[int, ...],
    samples: int = 1,
    seed: int = 0,
    subset: np.ndarray | None = None,
    batch_size: int = 128,
) -> dict[int, Metrics]:
    """Recursive-mode metrics of ``gen`` at several horizons (steps) on the same windows: one
    roll-out over the windows' whole future (``data.pred_len`` >= every horizon), scored per
    horizon h as :func:`evaluate_generator` would score an h-step future (``ade6``/``fde6`` of the
    returned :class:`Metrics` hold ADE/FDE at h); with ``samples`` > 1 each scene's best z draw is
    chosen per horizon (lowest summed ADE over steps 1..h), the same draws for every horizon."""
    if max(horizons) > data.pred_len or min(horizons) < 1:
        raise ValueError(f"horizons {list(horizons)}: the windows hold {data.pred_len} future steps")
    gen.eval()
    device = gen.device
    rng = torch.Generator().manual_seed(seed)
    accs = {h: _Acc() for h in horizons}
    windows = np.arange(len(data)) if subset is None else np.asarray(subset)
    for i in range(0, len(windows), batch_size):
        batch = data.batch(windows[i : i + batch_size])
        dev = batch.to(device)
        s = batch.seq_start_end.shape[0]
        keep = _keep_mask(batch, skip_ego=True)
        scene_of = _scene_of(batch)
        best: dict[int, tuple[Tensor, Tensor]] = {}
        for _ in range(samples):
            noise = None
            if gen.cfg.noise_dim > 0 and samples > 1:
                noise = torch.randn(s, gen.cfg.noise_dim, generator=rng).to(device)
            err = torch.linalg.norm(_recursive(gen, dev, noise).cpu() - batch.fut, dim=-1)  # [T, A]
            err = torch.where(keep.unsqueeze(0), err, torch.zeros_like(err))
            for h in horizons:
                e = err[:h]
                score = torch.zeros(s).index_add_(0, scene_of, e.mean(dim=0))
                if h not in best:
                    best[h] = (e, score)
                else:
                    better = score < best[h][1]
                    take = better[scene_of]
                    best[h] = (torch.where(take.unsqueeze(0), e, best[h][0]), torch.where(better, score, best[h][1]))
            if gen.cfg.noise_dim == 0 or samples == 1:
                break
        for h in horizons:
            accs[h].add(best[h][0][:, keep], s)
    return {h: a.result() for h, a in accs.items()}


def evaluate_constant_velocity_at(
    data: WindowSet, horizons: tuple[int, ...], skip_ego: bool = True, subset: np.ndarray | None = None
) -> dict[int, Metrics]:
    """:func:`evaluate_constant_velocity` at several horizons (steps) on the same windows
    (``ade6``/``fde6`` of the returned :class:`Metrics` hold ADE/FDE at h)."""
    if max(horizons) > data.pred_len or min(horizons) < 1:
        raise ValueError(f"horizons {list(horizons)}: the windows hold {data.pred_len} future steps")
    accs = {h: _Acc() for h in horizons}
    windows = np.arange(len(data)) if subset is None else np.asarray(subset)
    for i in range(0, len(windows), 512):
        batch = data.batch(windows[i : i + 512])
        v = batch.obs[-1] - batch.obs[-2]
        steps = torch.arange(1, batch.fut.shape[0] + 1, dtype=v.dtype).view(-1, 1, 1)
        err = torch.linalg.norm(batch.obs[-1].unsqueeze(0) + steps * v.unsqueeze(0) - batch.fut, dim=-1)
        keep = _keep_mask(batch, skip_ego)
        for h in horizons:
            accs[h].add(err[:h][:, keep], batch.seq_start_end.shape[0])
    return {h: a.result() for h, a in accs.items()}
