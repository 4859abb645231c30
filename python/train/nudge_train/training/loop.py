"""Training of the Social-GAN generators: best-of-k variety loss + optional adversarial loss.

One command trains one configuration (``nudge-train train --config FILE``):

* the config is a TOML file with a ``[model]`` table (any :class:`ModelConfig` field) and a
  ``[train]`` table (:class:`TrainConfig`), see :mod:`nudge_train.training.config`;
* L_G = k_var · L_var + I_adv · L_adv (paper eq. 5). L_var: ``k_samples`` draws of z per scene, per
  draw the scene's summed squared displacement error over its agents and decoded steps, minimum
  over draws, divided by agents × steps, mean over scenes. L_adv: the non-saturating generator
  loss against a per-agent discriminator on the whole (observed + future) displacement sequence;
* Adam, gradient clipping, seeded shuffling and noise; a checkpoint (``last.pt``) after every epoch
  and ``best.pt`` on every validation improvement; ``--resume`` continues from ``last.pt``; early
  stopping on validation ADE (single sample, fixed z); ``metrics.jsonl`` logs every epoch.
* Integrity (docs/reliability_data.md): checkpoints carry a content hash and are verified on
  resume (:mod:`nudge_train.training.checkpoint`); a non-finite loss or validation metric stops
  training with a :class:`~nudge_train.errors.TrainingError` naming epoch and batch. Every file
  is written temp-then-rename, in the order ``best.pt``, ``last.pt`` (which holds the metrics rows
  so far), ``metrics.jsonl`` (rewritten from those rows), so the checkpoint is the one commit
  point of an epoch: a resume after a kill at any moment replays at most the unfinished epoch and
  ends with the same weights and metrics rows as an uninterrupted run.

The teacher decodes ``train_steps`` (6) steps from one call during training so that every future
step supervises it, while the planner calls it recursively with one step; both uses share every
weight. The student is trained the same way on the distillation set (ego imposed).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F
from tqdm import tqdm

from nudge_train.artefacts import atomic_write_text, remove_stale_temps
from nudge_train.data.loader import Batch, WindowSet, load_split
from nudge_train.errors import ArtefactError, NudgeTrainError, TrainingError
from nudge_train.models.config import ModelConfig
from nudge_train.models.networks import TrajectoryGenerator, build_model, positions_to_rel
from nudge_train.training.checkpoint import load_checkpoint, save_checkpoint
from nudge_train.training.config import TrainConfig, load_config
from nudge_train.training.log import METRICS_FILE, metrics_text

__all__ = ["FaultHook", "load_best", "run", "train", "variety_loss"]

FaultHook = Callable[[str, int, "int | None"], None]
"""Called as ``hook(point, epoch, batch)`` at the named points of an epoch (``"batch"`` after
each optimiser step, ``"validated"``, ``"best_written"``, ``"checkpoint_temp"`` (last.pt's temp
file complete, not renamed), ``"checkpoint"``, ``"metrics"``); used by the tests to interrupt
training anywhere. ``batch`` is None except at ``"batch"``."""


def resolve_device(name: str) -> torch.device:
    """``"auto"`` → CUDA if available else CPU; anything else as given."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def variety_loss(pred: Tensor, fut: Tensor, seq_start_end: Tensor) -> Tensor:
    """Best-of-k loss.

    Args:
        pred: ``[k, K, A, 2]`` k sampled predictions of K steps (m).
        fut: ``[K, A, 2]`` ground truth (m).
        seq_start_end: ``[S, 2]`` scene ranges.

    Returns:
        scalar: mean over scenes of min over samples of (Σ_agents,steps ‖error‖²) / (agents × K).
    """
    err = ((pred - fut.unsqueeze(0)) ** 2).sum(dim=-1).sum(dim=1)  # [k, A]
    sizes = (seq_start_end[:, 1] - seq_start_end[:, 0]).to(err.device)
    scene_of = torch.repeat_interleave(torch.arange(len(sizes), device=err.device), sizes)
    per_scene = torch.zeros(err.shape[0], len(sizes), device=err.device, dtype=err.dtype)
    per_scene.index_add_(1, scene_of, err)  # [k, S]
    best = per_scene.min(dim=0).values / (sizes.to(err.dtype) * pred.shape[1])
    return best.mean()


def _sample_predictions(
    gen: TrajectoryGenerator, batch: Batch, k: int, steps: int, rng: torch.Generator | None
) -> tuple[Tensor, Tensor]:
    """k predictions ``[k, steps, A, 2]`` (positions) and displacements.

    The history-only context is computed once; the k draws are decoded in ONE call by stacking k
    copies of the batch as separate scenes (same result as k calls, far fewer kernel launches).
    """
    a = batch.obs.shape[1]
    scenes = gen.scene_index(batch.seq_start_end, a)
    ctx = gen.context(batch.obs, scenes)
    s = scenes.num_scenes
    shift = (torch.arange(k, device=batch.seq_start_end.device) * a).view(k, 1, 1)
    sse_k = (batch.seq_start_end.unsqueeze(0) + shift).reshape(k * s, 2)
    scenes_k = gen.scene_index(sse_k, k * a)
    ego_future = None
    if gen.cfg.kind == "student":
        ego_future = batch.fut[:steps, scenes.ego].repeat(1, k, 1)
    noise = None
    if gen.cfg.noise_dim > 0:
        noise = torch.randn(k * s, gen.cfg.noise_dim, generator=rng).to(ctx.device)
    p, r = gen.decode(
        ctx.repeat(k, 1), batch.obs.repeat(1, k, 1), scenes_k, noise=noise, ego_future=ego_future, steps=steps
    )
    return p.view(steps, k, a, 2).transpose(0, 1), r.view(steps, k, a, 2).transpose(0, 1)


def _full_rel(obs: Tensor, fut_rel: Tensor) -> Tensor:
    return torch.cat([positions_to_rel(obs), fut_rel], dim=0)


@torch.inference_mode()
def validation_ade(gen: TrajectoryGenerator, data: WindowSet, steps: int, device: torch.device) -> float:
    """Single-sample (fixed z) ADE over ``steps`` decoded steps, all agents (m)."""
    gen.eval()
    total, count = 0.0, 0
    for batch in data.batches(256, shuffle=False):
        batch = batch.to(device)
        scenes = gen.scene_index(batch.seq_start_end, batch.obs.shape[1])
        ctx = gen.context(batch.obs, scenes)
        ego_future = batch.fut[:steps, scenes.ego] if gen.cfg.kind == "student" else None
        pred, _ = gen.decode(ctx, batch.obs, scenes, ego_future=ego_future, steps=steps)
        err = torch.linalg.norm(pred - batch.fut[:steps], dim=-1)  # [K, A]
        if gen.cfg.kind == "student":
            keep = torch.ones(err.shape[1], dtype=torch.bool, device=err.device)
            keep[scenes.ego] = False
            err = err[:, keep]
        total += float(err.sum())
        count += err.numel()
    gen.train()
    return total / max(count, 1)


def epoch_lr(tcfg: TrainConfig, epoch: int) -> float:
    """Learning rate of ``epoch`` (0-based) under ``tcfg.lr_schedule``."""
    if tcfg.lr_schedule == "constant" or tcfg.epochs == 1:
        return tcfg.lr
    frac = epoch / (tcfg.epochs - 1)
    low = tcfg.lr * tcfg.lr_final_fraction
    return low + 0.5 * (tcfg.lr - low) * (1.0 + math.cos(math.pi * frac))


def train(
    mcfg: ModelConfig,
    tcfg: TrainConfig,
    resume: bool = False,
    train_set: WindowSet | None = None,
    val_set: WindowSet | None = None,
    progress: bool = True,
    fault_hook: FaultHook | None = None,
) -> dict[str, Any]:
    """Trains one configuration; returns a summary (best epoch, best validation ADE, paths).

    ``train_set``/``val_set`` default to the ``train``/``val`` splits of ``tcfg.data``.
    Resuming needs ``out_dir/last.pt``. ``fault_hook``: see :data:`FaultHook`.

    Raises:
        FileNotFoundError: resuming without ``last.pt``.
        ArtefactError: ``last.pt`` fails its content hash or holds non-finite values (naming it).
        TrainingError: a non-finite loss or validation metric (naming epoch and batch).
    """
    tcfg.validate()
    mcfg.validate()
    if tcfg.threads:
        torch.set_num_threads(tcfg.threads)
    device = resolve_device(tcfg.device)
    out = Path(tcfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(out)
    hook: FaultHook = fault_hook or (lambda point, epoch, batch: None)
    if train_set is None:
        train_set = load_split(Path(tcfg.data), "train", tcfg.max_train_windows or None)
    if val_set is None:
        val_set = load_split(Path(tcfg.data), "val")
    if tcfg.max_val_windows and len(val_set) > tcfg.max_val_windows:
        val_set = val_set.subset(np.linspace(0, len(val_set) - 1, tcfg.max_val_windows).round().astype(np.int64))

    gen, disc = build_model(mcfg, device)
    opt_g = torch.optim.Adam(gen.parameters(), lr=tcfg.lr)
    opt_d = torch.optim.Adam(disc.parameters(), lr=tcfg.lr)
    rng = torch.Generator().manual_seed(tcfg.seed)
    start_epoch, best_ade, best_epoch, stale = 0, math.inf, -1, 0
    metrics_path = out / METRICS_FILE
    last = out / "last.pt"
    rows: list[dict[str, Any]] = []
    if resume:
        if not last.exists():
            raise FileNotFoundError(f"cannot resume: no checkpoint at {last}")
        state = load_checkpoint(last)
        try:
            gen.load_state_dict(state["generator"])
            disc.load_state_dict(state["discriminator"])
            opt_g.load_state_dict(state["opt_g"])
            opt_d.load_state_dict(state["opt_d"])
            rng.set_state(state["rng"])
            start_epoch = int(state["epoch"]) + 1
            best_ade, best_epoch, stale = float(state["best_ade"]), int(state["best_epoch"]), int(state["stale"])
            rows = list(state["metrics"])
        except (KeyError, RuntimeError, ValueError, TypeError) as err:
            raise ArtefactError(last, f"does not fit this configuration ({err})") from None
        if [r.get("epoch") for r in rows] != list(range(start_epoch)):
            raise ArtefactError(last, f"holds metrics rows for epochs {[r.get('epoch') for r in rows]}, "
                                f"expected 0..{start_epoch - 1}")
    # The log always equals the checkpoint's rows: rows of an epoch the checkpoint does not hold
    # (a kill after they were written) are dropped here and rewritten when the epoch is redone.
    atomic_write_text(metrics_path, metrics_text(rows))
    atomic_write_text(out / "config.json",
                      json.dumps({"model": mcfg.to_dict(), "train": dataclasses.asdict(tcfg)}, indent=2))

    gen.train()
    disc.train()
    per_epoch = min(tcfg.samples_per_epoch or len(train_set), len(train_set))
    n_batches = math.ceil(per_epoch / tcfg.batch_size)
    for epoch in range(start_epoch, tcfg.epochs):
        if stale >= tcfg.patience:
            break
        t0 = time.perf_counter()
        lr = epoch_lr(tcfg, epoch)
        for opt in (opt_g, opt_d):
            for group in opt.param_groups:
                group["lr"] = lr
        sums = {"loss_var": 0.0, "loss_adv": 0.0, "loss_d": 0.0}
        bar = tqdm(
            train_set.batches(tcfg.batch_size, shuffle=True, generator=rng, limit=per_epoch),
            total=n_batches,
            desc=f"epoch {epoch + 1}/{tcfg.epochs}",
            disable=not progress,
            leave=False,
        )
        for i, batch in enumerate(bar):
            batch = batch.to(device)
            pred, rel = _sample_predictions(gen, batch, tcfg.k_samples, tcfg.train_steps, rng)
            fut = batch.fut[: tcfg.train_steps]
            loss_var = variety_loss(pred, fut, batch.seq_start_end)
            loss = tcfg.k_var * loss_var
            loss_adv = torch.zeros((), device=device)
            if tcfg.i_adv:
                fake_logits = disc(_full_rel(batch.obs, rel[0]))
                loss_adv = F.binary_cross_entropy_with_logits(fake_logits, torch.ones_like(fake_logits))
                loss = loss + loss_adv
            if not bool(torch.isfinite(loss)):
                raise TrainingError(f"non-finite generator loss (variety {float(loss_var.detach()):.4g}, "
                                    f"adversarial {float(loss_adv.detach()):.4g})", epoch, i)
            opt_g.zero_grad(set_to_none=True)
            loss.backward()
            if tcfg.clip_grad > 0:
                torch.nn.utils.clip_grad_norm_(gen.parameters(), tcfg.clip_grad)
            opt_g.step()
            if tcfg.i_adv:
                real_rel = _full_rel(batch.obs, positions_to_rel(torch.cat([batch.obs[-1:], fut]))[1:])
                real = disc(real_rel)
                fake = disc(_full_rel(batch.obs, rel[0].detach()))
                loss_d = F.binary_cross_entropy_with_logits(
                    real, torch.ones_like(real)
                ) + F.binary_cross_entropy_with_logits(fake, torch.zeros_like(fake))
                if not bool(torch.isfinite(loss_d)):
                    raise TrainingError(f"non-finite discriminator loss ({float(loss_d.detach()):.4g})", epoch, i)
                opt_d.zero_grad(set_to_none=True)
                loss_d.backward()
                if tcfg.clip_grad > 0:
                    torch.nn.utils.clip_grad_norm_(disc.parameters(), tcfg.clip_grad)
                opt_d.step()
                sums["loss_d"] += float(loss_d.detach())
            sums["loss_var"] += float(loss_var.detach())
            sums["loss_adv"] += float(loss_adv.detach())
            bar.set_postfix(var=f"{sums['loss_var'] / (i + 1):.4f}", adv=f"{sums['loss_adv'] / (i + 1):.3f}")
            hook("batch", epoch, i)
        if tcfg.val_metric == "recursive_fde":
            from nudge_train.training.evaluate import evaluate_generator

            val_ade = evaluate_generator(gen, val_set, mode="recursive").fde6
            gen.train()
        else:
            val_ade = validation_ade(gen, val_set, tcfg.train_steps, device)
        if not math.isfinite(val_ade):
            raise TrainingError(f"non-finite validation metric ({tcfg.val_metric} = {val_ade})", epoch)
        hook("validated", epoch, None)
        improved = val_ade < best_ade
        if improved:
            best_ade, best_epoch, stale = val_ade, epoch, 0
            save_checkpoint(out / "best.pt", {"generator": gen.state_dict(), "epoch": epoch})
            hook("best_written", epoch, None)
        else:
            stale += 1
        row = {
            "epoch": epoch,
            **{k: v / max(n_batches, 1) for k, v in sums.items()},
            "val_ade": val_ade,
            "best_val_ade": best_ade,
            "lr": lr,
            "seconds": time.perf_counter() - t0,
        }
        rows.append(row)
        if progress:
            tqdm.write(
                f"epoch {epoch + 1}: var {row['loss_var']:.4f} adv {row['loss_adv']:.3f} "
                f"val ADE {val_ade:.4f} m{' *' if improved else ''} ({row['seconds']:.1f} s)"
            )
        save_checkpoint(
            last,
            {
                "generator": gen.state_dict(),
                "discriminator": disc.state_dict(),
                "opt_g": opt_g.state_dict(),
                "opt_d": opt_d.state_dict(),
                "rng": rng.get_state(),
                "epoch": epoch,
                "best_ade": best_ade,
                "best_epoch": best_epoch,
                "stale": stale,
                "metrics": rows,
            },
            before_rename=lambda: hook("checkpoint_temp", epoch, None),
        )
        hook("checkpoint", epoch, None)
        atomic_write_text(metrics_path, metrics_text(rows))
        hook("metrics", epoch, None)
    summary = {"best_epoch": best_epoch, "best_val_ade": best_ade, "out_dir": str(out)}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2))
    return summary


def load_best(out_dir: Path, mcfg: ModelConfig, device: torch.device | str = "cpu") -> TrajectoryGenerator:
    """The best-validation generator of a finished run."""
    gen, _ = build_model(mcfg, device)
    path = Path(out_dir) / "best.pt"
    state = load_checkpoint(path)
    gen.load_state_dict(state["generator"])
    gen.eval()
    return gen


def run(*, config: Path, resume: bool, out_dir: str | None, data: str | None, epochs: int | None) -> int:
    """``nudge-train train``: trains the configuration in the TOML file ``config``, with
    ``out_dir`` / ``data`` / ``epochs`` (when given) overriding its ``[train]`` table; prints the
    summary as JSON. Returns the exit status (2 on a bad config, missing data or checkpoint)."""
    try:
        mcfg, tcfg = load_config(config)
        over = {k: v for k, v in (("out_dir", out_dir), ("data", data), ("epochs", epochs)) if v is not None}
        tcfg = dataclasses.replace(tcfg, **over).validate()
        summary = train(mcfg, tcfg, resume=resume)
    except (ValueError, FileNotFoundError, RuntimeError, NudgeTrainError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(json.dumps(summary))
    return 0
