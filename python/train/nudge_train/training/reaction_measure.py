"""Reaction: how a prediction model's forecast of the other vehicles changes with the ego's plan.

The reaction of a model to an ego candidate is its prediction under that candidate MINUS its
prediction under the *keep-lane counterfactual* of the candidate (same history, same longitudinal
positions, the lateral position held at the ego's last observed one): the part of the forecast
that the lane change itself causes. The vehicle it matters for is the *target-lane follower*,
the nearest vehicle behind the ego (last observed x below the ego's) whose last observed centre
lies in the lane the candidate moves into; the measure is its longitudinal position at 1.8 s
(step 6), in metres, negative = the follower is predicted to fall back.

The measure is shared by the training library (the checkpoint selection of
:mod:`nudge_train.training.reaction`) and the experiments (``nudge-train reaction``, ``horizon``).

Two places it is measured (:func:`planner_reactions`, :mod:`nudge_train.experiments.reaction_cutins`):

* held-out planner candidates (the distillation set's test split): for every planner call whose
  ego is not yet in the target lane, the candidates that move at least ``min_lateral`` m towards
  the target lane by step 6, each against its keep-lane counterfactual; the context's value is
  the mean over its candidates (one number per planner call, so calls with many candidates do not
  dominate);
* real cut-ins (``assets/worlds/cutins.json``): the cut-in vehicle plays the ego, its logged path
  is the candidate, and the real follower's fall-back is the truth.

Medians over contexts (events) with 95 % percentile-bootstrap intervals.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from nudge_train.distill.contexts import Context
from nudge_train.models.interactive import student_interactive, teacher_interactive
from nudge_train.models.networks import TrajectoryGenerator

__all__ = [
    "REACTION_STEP",
    "ContextReaction",
    "PredictFn",
    "model_predictor",
    "follower_row",
    "keep_lane",
    "lane_change_candidates",
    "planner_reactions",
    "predict",
    "reaction",
]

REACTION_STEP = 5
"""Index of the step the reaction is read at: step 6 = 1.8 s after the last observed one."""

PredictFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""An interactive predictor: (history ``[N, 8, 2]``, ego candidates ``[B, 6, 2]``) -> the other
agents' positions ``[B, N - 1, 6, 2]`` (m)."""


def keep_lane(candidates: np.ndarray, y0: float) -> np.ndarray:
    """Keep-lane counterfactuals ``[B, T, 2]`` of ``candidates`` ``[B, T, 2]`` (m): the same x,
    y = ``y0`` (the ego's last observed lateral position, m) at every step."""
    out = np.array(candidates, dtype=np.float32, copy=True)
    out[..., 1] = np.float32(y0)
    return out


def lane_of(y: float, bounds: np.ndarray) -> int:
    """Lane index (0 = lowest y) of lateral position ``y`` (m) under ascending ``bounds`` [L + 1];
    -1 outside the road."""
    if not (bounds[0] <= y < bounds[-1]):
        return -1
    return int(np.searchsorted(bounds, y, side="right") - 1)


def follower_row(history: np.ndarray, bounds: np.ndarray, lane: int) -> int:
    """Row (>= 1) of ``history`` ``[N, T, 2]`` of the nearest vehicle behind the ego (row 0) at
    the last observed step whose centre lies in ``lane``; -1 when there is none."""
    ego_x = history[0, -1, 0]
    best, gap = -1, np.inf
    for r in range(1, history.shape[0]):
        x, y = history[r, -1]
        if x < ego_x and lane_of(float(y), bounds) == lane and ego_x - x < gap:
            best, gap = r, float(ego_x - x)
    return best


def lane_change_candidates(ctx: Context, min_lateral: float) -> np.ndarray:
    """Indices of the candidates of ``ctx`` whose position at step 6 is at least ``min_lateral``
    m (lateral) beyond the ego's last observed one, towards the target lane; none when the ego is
    already in the target lane."""
    y0 = float(ctx.history[0, -1, 1])
    b = ctx.lane_bounds
    if lane_of(y0, b) == ctx.target_lane:
        return np.zeros(0, dtype=np.int64)
    centre = 0.5 * (b[ctx.target_lane] + b[ctx.target_lane + 1])
    towards = np.sign(centre - y0) * (ctx.candidates[:, -1, 1] - y0)
    return np.flatnonzero(towards >= min_lateral)


def reaction(pred_candidate: np.ndarray, pred_keep: np.ndarray, follower: int, step: int = REACTION_STEP) -> np.ndarray:
    """Follower reaction ``[B]`` (m): x of history row ``follower`` (>= 1) at ``step`` under each
    candidate minus under its keep-lane counterfactual. Predictions ``[B, N - 1, T, 2]`` cover rows
    1..N-1, so row r is prediction index r - 1."""
    if follower < 1:
        raise ValueError(f"follower: a history row >= 1 expected, got {follower}")
    return pred_candidate[:, follower - 1, step, 0] - pred_keep[:, follower - 1, step, 0]


def predict(gen: TrajectoryGenerator, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """The model's interactive prediction ``[B, N - 1, T, 2]`` (m) of a history ``[N, 8, 2]`` and
    ego candidates ``[B, T, 2]``: the teacher's recursive one-step roll-out over T steps (its fixed
    z), the student's one pass (T = its 6 steps). Positions are shifted so the ego's last observed one is the origin (the
    networks are translation invariant; float32 keeps more precision near 0)."""
    origin = history[0, -1].astype(np.float32)
    h = torch.from_numpy((history - origin).astype(np.float32))
    c = torch.from_numpy((candidates - origin).astype(np.float32))
    if gen.cfg.kind == "teacher":
        out = teacher_interactive(gen, h, c, horizon=c.shape[1])
    else:
        out = student_interactive(gen, h, c)
    return out.cpu().numpy() + origin


def model_predictor(gen: TrajectoryGenerator) -> PredictFn:
    """:func:`predict` with ``gen`` bound."""
    return lambda history, candidates: predict(gen, history, candidates)


@dataclass(frozen=True)
class ContextReaction:
    """Reactions of one planner call: ``follower`` history row, ``candidates`` indices used,
    ``models`` predictor name -> reactions ``[B]`` (m)."""

    scene: str
    follower: int
    candidates: np.ndarray
    models: dict[str, np.ndarray]


def planner_reactions(
    contexts: list[Context],
    predictors: dict[str, PredictFn],
    min_lateral: float = 1.0,
    max_candidates: int = 8,
) -> list[ContextReaction]:
    """Reactions of every predictor on the planner calls of ``contexts`` that have a target-lane
    follower and lane-change candidates (:func:`lane_change_candidates`); at most
    ``max_candidates`` per call, evenly spaced over the call's qualifying candidates (sorted by
    their lateral reach) so that the choice is deterministic."""
    out = []
    for ctx in contexts:
        idx = lane_change_candidates(ctx, min_lateral)
        fol = follower_row(ctx.history, ctx.lane_bounds, ctx.target_lane)
        if idx.shape[0] == 0 or fol < 0:
            continue
        if idx.shape[0] > max_candidates:
            order = idx[np.argsort(np.abs(ctx.candidates[idx, -1, 1] - ctx.history[0, -1, 1]), kind="stable")]
            idx = order[np.linspace(0, len(order) - 1, max_candidates).round().astype(np.int64)]
        cand = ctx.candidates[idx]
        keep = keep_lane(cand, float(ctx.history[0, -1, 1]))
        both = np.concatenate([cand, keep])
        vals = {}
        for name, fn in predictors.items():
            p = fn(ctx.history, both)
            vals[name] = reaction(p[: len(idx)], p[len(idx):], fol)
        out.append(ContextReaction(scene=ctx.scene, follower=fol, candidates=idx, models=vals))
    return out


def per_context(reactions: list[ContextReaction], model: str) -> np.ndarray:
    """One value per planner call ``[C]`` (m): the mean reaction over its candidates."""
    return np.array([float(np.mean(r.models[model])) for r in reactions], dtype=np.float64)
