"""Distillation with a loss on the reaction itself (``nudge-train student-react``).

The plain distillation loss (:mod:`nudge_train.training.loop`) is L2 on the predicted positions of
one candidate at a time. The teacher's reaction to the ego (how the forecast moves between two
candidates of the same history, a few centimetres, docs/results/reaction.md) is tiny next to the
position error, so a student can reach a low position loss while ignoring the candidate. Here
every batch holds several candidates of each sampled planner call (context), and the loss is

    L = L_pos + reaction_weight · L_react

* ``L_pos``: per candidate, the squared position error against the teacher summed over the other
  agents and the 6 steps, divided by agents × steps (the plain student loss); mean over candidates;
* ``L_react``: the same, of the error minus its mean over the candidates of the same context:
  Σ_r ‖e_r − ē‖² = (1 / 2R) Σ_{r,s} ‖e_r − e_s‖², so it penalises the error of every pairwise
  difference of predictions against the teacher's difference, and nothing else.

A batch samples ``contexts_per_batch`` contexts; per context, ``planner_candidates`` random
candidates the planner evaluated and ``keep_lane_pairs`` (candidate, keep-lane counterfactual)
pairs: candidates that move at least ``min_lateral`` m sideways by step 6, each with the same
candidate's lateral position held at the ego's (the teacher's prediction for it computed once
before training with the Rust teacher, which the tests check against PyTorch).

Selection on the distillation validation split: every ``eval_every`` steps, the position fidelity
(ADE over 6 steps against the teacher on up to 16 candidates per validation context) and the
reaction error (median over validation contexts of |student − teacher| target-lane follower
reaction at 1.8 s, :mod:`nudge_train.training.reaction_measure`). The kept checkpoint is the one with
the lowest reaction error among those whose fidelity is not worse than the reference student's
(``reference``, the shipped one) on the same validation sample; the lowest ADE when none is.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nudge_train.artefacts import atomic_write_text
from nudge_train.distill.contexts import Context, load_contexts
from nudge_train.errors import ConfigError, TrainingError
from nudge_train.models.config import ModelConfig, student_config
from nudge_train.models.networks import PoolHiddenNet, TrajectoryGenerator, build_model
from nudge_train.training.export import export_generator, load_generator, read_weights
from nudge_train.training.reaction_measure import keep_lane, model_predictor, per_context, planner_reactions

__all__ = ["ReactionTrainConfig", "TrainSet", "build_train_set", "load_reaction_config", "reaction_loss", "train"]


@dataclass(frozen=True)
class ReactionTrainConfig:
    """Settings of one reaction-distillation run (the ``[train]`` table of its TOML file)."""

    data: str = "runs/distill"
    """Distillation set (``nudge-train distill --out``)."""
    scenes: str = "data/processed/scenes"
    """Planner scenes of the set (their lane bounds)."""
    out_dir: str = "runs/student_react"
    """Checkpoint, metrics log and exported weights."""
    teacher: str = "assets/models/teacher.safetensors"
    """The teacher the set was generated with (labels the keep-lane counterfactuals)."""
    reference: str = "assets/models/student.safetensors"
    """The student whose validation fidelity the selection must not lose to."""
    init: str = ""
    """Weights to start from ("" = seeded random initialisation)."""
    reaction_weight: float = 20.0
    """Weight of L_react against L_pos."""
    contexts_per_batch: int = 32
    """Contexts (planner calls) per batch."""
    planner_candidates: int = 4
    """Random planner candidates per context per batch."""
    keep_lane_pairs: int = 2
    """(candidate, keep-lane counterfactual) pairs per context per batch."""
    pairs_per_context: int = 8
    """Counterfactual pairs labelled per training context before training."""
    min_lateral: float = 0.5
    """Lateral reach (m) at step 6 of the candidates given a keep-lane counterfactual."""
    lr: float = 3e-3
    """Adam learning rate at the start (cosine decay to ``lr_final_fraction`` · lr)."""
    lr_final_fraction: float = 0.05
    """Final learning rate as a fraction of ``lr``."""
    steps: int = 6000
    """Optimiser steps."""
    eval_every: int = 500
    """Validation every this many steps (and at the end)."""
    time_budget_s: float = 0.0
    """Stop (after a validation) once training has run this long; 0 = no limit."""
    soft_pool_start: float = 0.0
    """Initial temperature of the smooth maximum in the pooling (0 = Social-GAN's max throughout;
    :attr:`nudge_train.models.networks.PoolHiddenNet.soft_temperature`)."""
    soft_pool_end: float = 0.01
    """Temperature reached (geometric decay) at ``soft_pool_until`` of the run; the max after it."""
    soft_pool_until: float = 0.6
    """Share of the run (steps or time budget, whichever is further along) with the smooth maximum."""
    clip_grad: float = 1.0
    """Gradient-norm clipping (0 = off)."""
    seed: int = 0
    """Seed of initialisation and sampling."""
    threads: int = 1
    """torch CPU threads."""

    def validate(self) -> ReactionTrainConfig:
        """Raises ValueError naming the first impossible field."""
        checks = [
            ("reaction_weight", self.reaction_weight >= 0 and math.isfinite(self.reaction_weight)),
            ("contexts_per_batch", self.contexts_per_batch >= 1),
            ("planner_candidates", self.planner_candidates >= 0),
            ("keep_lane_pairs", self.keep_lane_pairs >= 0),
            ("pairs_per_context", self.pairs_per_context >= self.keep_lane_pairs),
            ("min_lateral", self.min_lateral >= 0),
            ("lr", self.lr > 0 and math.isfinite(self.lr)),
            ("lr_final_fraction", 0 < self.lr_final_fraction <= 1),
            ("steps", self.steps >= 1),
            ("eval_every", self.eval_every >= 1),
            ("time_budget_s", self.time_budget_s >= 0),
            ("clip_grad", self.clip_grad >= 0),
            ("soft_pool_start", self.soft_pool_start >= 0 and math.isfinite(self.soft_pool_start)),
            ("soft_pool_end", 0 < self.soft_pool_end <= max(self.soft_pool_start, self.soft_pool_end)),
            ("soft_pool_until", 0 <= self.soft_pool_until <= 1),
            ("threads", self.threads >= 1),
        ]
        for name, ok in checks:
            if not ok:
                raise ValueError(f"{name}: invalid value {getattr(self, name)!r}")
        if self.planner_candidates + 2 * self.keep_lane_pairs < 2:
            raise ValueError("planner_candidates + 2 * keep_lane_pairs: at least 2 candidates per context are needed")
        return self


def load_reaction_config(path: Path) -> tuple[ModelConfig, ReactionTrainConfig]:
    """The ``[model]`` (student overrides) and ``[train]`` tables of a TOML file.

    Raises:
        ConfigError: unreadable TOML, an unknown table or key (naming it), or an impossible value.
    """
    try:
        doc = tomllib.loads(Path(path).read_text())
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(path, f"not valid TOML: {err}") from None
    extra = set(doc) - {"model", "train"}
    if extra:
        raise ConfigError(path, f"unknown table {sorted(extra)[0]!r}", key=sorted(extra)[0])
    model = dict(doc.get("model", {}))
    if model.pop("kind", "student") != "student":
        raise ConfigError(path, "model.kind: the reaction distillation trains a student", key="kind")
    known = {f.name for f in dataclasses.fields(ReactionTrainConfig)}
    train_tab = doc.get("train", {})
    for key in train_tab:
        if key not in known:
            raise ConfigError(path, f"unknown key train.{key}", key=key)
    try:
        mcfg = dataclasses.replace(student_config(), **model).validate()
        tcfg = ReactionTrainConfig(**train_tab).validate()
    except (TypeError, ValueError) as err:
        raise ConfigError(path, str(err)) from None
    return mcfg, tcfg


@dataclass
class TrainSet:
    """Training contexts with their keep-lane pairs: ``pairs[c]`` = (candidates ``[P, 6, 2]``,
    their keep-lane counterfactuals ``[P, 6, 2]``, the teacher under the counterfactuals
    ``[P, N - 1, 6, 2]``; the candidates' own labels are in the context)."""

    contexts: list[Context]
    pair_index: list[np.ndarray]
    keep: list[np.ndarray]
    keep_teacher: list[np.ndarray]


def pair_candidates(ctx: Context, count: int, min_lateral: float) -> np.ndarray:
    """Up to ``count`` candidate indices of ``ctx`` reaching at least ``min_lateral`` m sideways
    by step 6, evenly spaced over them sorted by reach (deterministic)."""
    reach = np.abs(ctx.candidates[:, -1, 1] - ctx.history[0, -1, 1])
    idx = np.flatnonzero(reach >= min_lateral)
    if idx.shape[0] > count:
        idx = idx[np.argsort(reach[idx], kind="stable")]
        idx = idx[np.linspace(0, len(idx) - 1, count).round().astype(np.int64)]
    return idx


def build_train_set(contexts: list[Context], teacher_path: Path, count: int, min_lateral: float) -> TrainSet:
    """Labels the keep-lane counterfactuals of :func:`pair_candidates` with the Rust teacher."""
    import nudge

    teacher = nudge.Predictor.load(teacher_path)
    idx_all, keeps, labels = [], [], []
    for ctx in contexts:
        idx = pair_candidates(ctx, count, min_lateral)
        keep = keep_lane(ctx.candidates[idx], float(ctx.history[0, -1, 1]))
        if idx.shape[0]:
            lab = np.asarray(teacher.predict(ctx.history.astype(np.float64), keep.astype(np.float64)), np.float32)
        else:
            lab = np.zeros((0, ctx.history.shape[0] - 1, 6, 2), np.float32)
        idx_all.append(idx)
        keeps.append(keep)
        labels.append(lab)
    return TrainSet(contexts, idx_all, keeps, labels)


def reaction_loss(err: torch.Tensor, group: torch.Tensor, n_groups: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(L_pos, L_react) of prediction errors ``err`` ``[R, A, T, 2]`` (m) of R candidate rows of
    A other agents each, ``group`` ``[R]`` the context of every row (0..n_groups-1); rows of one
    context share their agents (same A). Both losses: per row, Σ over agents and steps of the
    squared error divided by A × T, mean over rows; L_react after subtracting from each row the mean
    error of its context's rows."""
    r, a, t, _ = err.shape
    pos = (err**2).sum(dim=(1, 2, 3)) / (a * t)
    sums = torch.zeros((n_groups, a, t, 2), dtype=err.dtype, device=err.device).index_add_(0, group, err)
    counts = torch.zeros(n_groups, dtype=err.dtype, device=err.device).index_add_(0, group, torch.ones_like(group, dtype=err.dtype))
    centred = err - (sums / counts.clamp(min=1).view(-1, 1, 1, 1))[group]
    react = (centred**2).sum(dim=(1, 2, 3)) / (a * t)
    return pos.mean(), react.mean()


def _batch(ts: TrainSet, tcfg: ReactionTrainConfig, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per sampled context: (history [N,8,2], candidates [R,6,2], labels [R,N-1,6,2]), shifted so
    the ego's last observed position is the origin."""
    out = []
    for c in rng.choice(len(ts.contexts), size=tcfg.contexts_per_batch, replace=len(ts.contexts) < tcfg.contexts_per_batch):
        ctx = ts.contexts[c]
        m = len(ctx.candidates)
        pick = rng.choice(m, size=min(tcfg.planner_candidates, m), replace=False)
        cands, labels = [ctx.candidates[pick]], [ctx.teacher[pick]]
        p = len(ts.pair_index[c])
        if p and tcfg.keep_lane_pairs:
            q = rng.choice(p, size=min(tcfg.keep_lane_pairs, p), replace=False)
            cands += [ctx.candidates[ts.pair_index[c][q]], ts.keep[c][q]]
            labels += [ctx.teacher[ts.pair_index[c][q]], ts.keep_teacher[c][q]]
        o = ctx.history[0, -1]
        out.append((ctx.history - o, np.concatenate(cands) - o, np.concatenate(labels) - o))
    return out


def student_rows(gen: TrajectoryGenerator, items: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> list[torch.Tensor]:
    """The student's predictions (with gradients) ``[R, N - 1, 6, 2]`` for each item's candidates:
    one context computation per history, one decoder pass for all candidates of all items."""
    obs, sse, ctx_rows, ego, start = [], [], [], [], 0
    hist = [torch.from_numpy(h).transpose(0, 1) for h, _, _ in items]  # [8, N, 2]
    h_sse, s0 = [], 0
    for h in hist:
        h_sse.append((s0, s0 + h.shape[1]))
        s0 += h.shape[1]
    h_all = torch.cat(hist, dim=1)
    h_idx = gen.scene_index(torch.tensor(h_sse, dtype=torch.int64), h_all.shape[1])
    ctx_all = gen.context(h_all, h_idx)
    for (h, c, _), (a0, a1), hh in zip(items, h_sse, hist):
        n, r = h.shape[0], c.shape[0]
        obs.append(hh.repeat(1, r, 1))
        ctx_rows.append(ctx_all[a0:a1].repeat(r, 1))
        for _ in range(r):
            sse.append((start, start + n))
            start += n
        ego.append(torch.from_numpy(c).transpose(0, 1))  # [6, R, 2]
    scenes = gen.scene_index(torch.tensor(sse, dtype=torch.int64), start)
    pred, _ = gen.decode(torch.cat(ctx_rows), torch.cat(obs, dim=1), scenes, ego_future=torch.cat(ego, dim=1),
                         steps=gen.cfg.t_plan)
    out, a = [], 0
    for h, c, _ in items:
        n, r = h.shape[0], c.shape[0]
        out.append(pred[:, a : a + n * r].reshape(gen.cfg.t_plan, r, n, 2).permute(1, 2, 0, 3)[:, 1:])
        a += n * r
    return out


@torch.inference_mode()
def fidelity(gen: TrajectoryGenerator, contexts: list[Context], per_context_max: int = 16) -> tuple[float, float]:
    """(ADE over 6 steps, FDE at 1.8 s) (m) of ``gen`` against the teacher labels on up to
    ``per_context_max`` evenly spaced candidates of every context: mean over agents (others) of
    the mean / last-step L2 error."""
    gen.eval()
    ade_sum, fde_sum, agents = 0.0, 0.0, 0
    for i in range(0, len(contexts), 32):
        items = []
        for ctx in contexts[i : i + 32]:
            m = len(ctx.candidates)
            sel = np.linspace(0, m - 1, min(per_context_max, m)).round().astype(np.int64)
            o = ctx.history[0, -1]
            items.append((ctx.history - o, ctx.candidates[sel] - o, ctx.teacher[sel] - o))
        for p, (_, _, lab) in zip(student_rows(gen, items), items):
            err = torch.linalg.norm(p - torch.from_numpy(lab), dim=-1)  # [R, N-1, 6]
            ade_sum += float(err.mean(dim=2).sum())
            fde_sum += float(err[:, :, -1].sum())
            agents += err.shape[0] * err.shape[1]
    gen.train()
    return ade_sum / max(agents, 1), fde_sum / max(agents, 1)


def set_soft_pool(gen: TrajectoryGenerator, temperature: float) -> None:
    """Sets the pooling temperature of every pooling module of ``gen`` (0 = the max)."""
    for m in gen.modules():
        if isinstance(m, PoolHiddenNet):
            m.soft_temperature = float(temperature)


def pool_temperature(tcfg: ReactionTrainConfig, progress: float) -> float:
    """Temperature at ``progress`` (0..1) of the run: geometric from ``soft_pool_start`` to
    ``soft_pool_end`` over the first ``soft_pool_until`` of it, then 0 (the max)."""
    if tcfg.soft_pool_start <= 0 or progress >= tcfg.soft_pool_until:
        return 0.0
    frac = progress / tcfg.soft_pool_until
    return tcfg.soft_pool_start * (tcfg.soft_pool_end / tcfg.soft_pool_start) ** frac


def reaction_error(student: np.ndarray, teacher: np.ndarray) -> float:
    """Median over contexts of |student − teacher| per-context reaction (m)."""
    return float(np.median(np.abs(student - teacher)))


def train(mcfg: ModelConfig, tcfg: ReactionTrainConfig, progress: bool = True) -> dict[str, Any]:
    """Trains one student with the reaction loss; writes ``best.pt``, ``metrics.jsonl``,
    ``summary.json`` and ``student.safetensors`` (the selected weights) into ``out_dir``.

    Raises:
        TrainingError: a non-finite loss (naming the step).
    """
    torch.set_num_threads(tcfg.threads)
    torch.manual_seed(tcfg.seed)
    out = Path(tcfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data, scenes = Path(tcfg.data), Path(tcfg.scenes)
    t0 = time.perf_counter()
    train_ctx = load_contexts(data, "train", scenes)
    val_ctx = load_contexts(data, "val", scenes)
    ts = build_train_set(train_ctx, Path(tcfg.teacher), tcfg.pairs_per_context, tcfg.min_lateral)
    teacher = load_generator(Path(tcfg.teacher))
    ref = load_generator(Path(tcfg.reference))
    val_react = planner_reactions(val_ctx, {"teacher": model_predictor(teacher), "reference": model_predictor(ref)})
    val_t = per_context(val_react, "teacher")
    ref_ade, ref_fde = fidelity(ref, val_ctx)
    ref_err = reaction_error(per_context(val_react, "reference"), val_t)
    if progress:
        print(f"set-up {time.perf_counter() - t0:.0f} s: {len(train_ctx)} train / {len(val_ctx)} val contexts, "
              f"{sum(len(i) for i in ts.pair_index)} keep-lane pairs, {len(val_react)} val reaction contexts; "
              f"reference: val ADE {ref_ade:.4f} m, reaction error {ref_err:.4f} m (teacher median {np.median(val_t):+.4f} m)")

    gen, _ = build_model(mcfg, "cpu")
    if tcfg.init:
        gen.load_state_dict(load_generator(Path(tcfg.init)).state_dict())
    gen.train()
    opt = torch.optim.Adam(gen.parameters(), lr=tcfg.lr)
    rng = np.random.default_rng(tcfg.seed)
    rows: list[dict[str, Any]] = []
    best: dict[str, Any] | None = None
    t_train = time.perf_counter()
    sums = {"pos": 0.0, "react": 0.0, "n": 0}
    for step in range(tcfg.steps):
        # Progress: steps, or the time budget when it runs out first (so the schedules finish).
        frac = step / max(tcfg.steps - 1, 1)
        if tcfg.time_budget_s > 0:
            frac = min(max(frac, (time.perf_counter() - t_train) / tcfg.time_budget_s), 1.0)
        low = tcfg.lr * tcfg.lr_final_fraction
        for g in opt.param_groups:
            g["lr"] = low + 0.5 * (tcfg.lr - low) * (1.0 + math.cos(math.pi * frac))
        tau = pool_temperature(tcfg, frac)
        set_soft_pool(gen, tau)
        items = _batch(ts, tcfg, rng)
        preds = student_rows(gen, items)
        pos_l, react_l = torch.zeros(()), torch.zeros(())
        for p, (_, _, lab) in zip(preds, items):
            lp, lr_ = reaction_loss(p - torch.from_numpy(lab), torch.zeros(p.shape[0], dtype=torch.int64), 1)
            pos_l = pos_l + lp / len(items)
            react_l = react_l + lr_ / len(items)
        loss = pos_l + tcfg.reaction_weight * react_l
        if not bool(torch.isfinite(loss)):
            raise TrainingError(f"non-finite loss (position {float(pos_l):.4g}, reaction {float(react_l):.4g})", 0, step)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if tcfg.clip_grad > 0:
            torch.nn.utils.clip_grad_norm_(gen.parameters(), tcfg.clip_grad)
        opt.step()
        sums["pos"] += float(pos_l.detach())
        sums["react"] += float(react_l.detach())
        sums["n"] += 1
        last = step == tcfg.steps - 1
        over = tcfg.time_budget_s > 0 and time.perf_counter() - t_train > tcfg.time_budget_s
        if (step + 1) % tcfg.eval_every == 0 or last or over:
            set_soft_pool(gen, 0.0)  # validation (and the exported model) use the max
            ade, fde = fidelity(gen, val_ctx)
            gen.eval()
            s_react = per_context(planner_reactions(val_ctx, {"s": model_predictor(gen)}), "s")
            gen.train()
            err = reaction_error(s_react, val_t)
            row = {"step": step + 1, "loss_pos": sums["pos"] / sums["n"], "loss_react": sums["react"] / sums["n"],
                   "val_ade": ade, "val_fde": fde, "val_reaction_error": err,
                   "val_reaction_median": float(np.median(s_react)), "pool_temperature": tau,
                   "seconds": time.perf_counter() - t_train}
            sums = {"pos": 0.0, "react": 0.0, "n": 0}
            ok = ade <= ref_ade
            key = (0 if ok else 1, err if ok else ade)
            improved = best is None or key < best["key"]
            if improved:
                best = {"key": key, "row": row}
                torch.save(gen.state_dict(), out / "best.pt")
            rows.append(row)
            atomic_write_text(out / "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in rows))
            if progress:
                print(f"step {step + 1} (tau {tau:.3g}): pos {row['loss_pos']:.4f} react {row['loss_react']:.5f} | val ADE {ade:.4f} "
                      f"FDE {fde:.4f} reaction {row['val_reaction_median']:+.4f} (teacher {np.median(val_t):+.4f}) "
                      f"error {err:.4f}{' *' if improved else ''} ({row['seconds']:.0f} s)", flush=True)
            if over:
                break
    assert best is not None
    set_soft_pool(gen, 0.0)
    gen.load_state_dict(torch.load(out / "best.pt", weights_only=True))
    gen.eval()
    summary = {"best": best["row"], "reference": {"val_ade": ref_ade, "val_fde": ref_fde, "val_reaction_error": ref_err},
               "teacher_val_reaction_median": float(np.median(val_t)), "val_reaction_contexts": len(val_react),
               "train_contexts": len(train_ctx), "keep_lane_pairs": int(sum(len(i) for i in ts.pair_index)),
               "train_seconds": time.perf_counter() - t_train, "config": dataclasses.asdict(tcfg)}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2))
    return {"generator": gen, "summary": summary}


def run(*, config: Path, out_dir: str | None, steps: int | None, time_budget_s: float | None, export: str | None) -> int:
    """``nudge-train student-react``: trains the configuration in ``config`` (see the module doc),
    exports the selected student to ``export`` (default ``<out_dir>/student.safetensors``) with its
    provenance. Returns the exit status (2 on a bad config or missing data)."""
    import sys

    from nudge_train import paths
    from nudge_train.provenance import git_commit, sha256_file

    try:
        mcfg, tcfg = load_reaction_config(config)
        over = {k: v for k, v in (("out_dir", out_dir), ("steps", steps), ("time_budget_s", time_budget_s)) if v is not None}
        tcfg = dataclasses.replace(tcfg, **over).validate()
        res = train(mcfg, tcfg)
    except (ConfigError, FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    target = Path(export) if export else Path(tcfg.out_dir) / "student.safetensors"
    data = Path(tcfg.data)
    prov = {
        "data": paths.repo_relative(data),
        "distill_manifest_sha256": sha256_file(data / "manifest.json"),
        "teacher_sha256": sha256_file(Path(tcfg.teacher)),
        "split": "distillation train (selected on distillation val: reaction error, fidelity not worse than the reference)",
        "config": Path(config).name,
        "train": dataclasses.asdict(tcfg),
        "selected": res["summary"]["best"],
        "reference": res["summary"]["reference"],
        "commit": git_commit(),
        "hardware": f"{torch.get_num_threads()} CPU threads",
        # How the student it was fine-tuned from was made (a chain back to the position-only one).
        "init_provenance": read_weights(Path(tcfg.init)).provenance if tcfg.init else None,
    }
    export_generator(res["generator"], mcfg, target, trained=True, provenance=prov)
    print(f"exported the student to {target}")
    return 0
