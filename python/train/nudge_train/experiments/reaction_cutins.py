"""Real cut-ins as reaction tests of the prediction models.

For every event of ``assets/worlds/cutins.json`` (``nudge-train idm cutins``) the prediction starts
at ``t_s`` = the centre crossing minus ``lead_s``: the cut-in vehicle (the intruder) plays the ego,
the 8 observed steps (0.3 s apart, ending at ``t_s``) hold every vehicle observed at all of them
within ``radius`` m (longitudinal) of the intruder, and

* the candidate is the intruder's logged path over the next 6 steps (1.8 s);
* its keep-lane counterfactual is the same path with the lateral position held at the intruder's
  at ``t_s`` (the same rule as for planner candidates, :func:`nudge_train.training.reaction_measure.keep_lane`);
* the truth is the real follower's fall-back 1.8 s after ``t_s``: ``x_F(t_s + 1.8) − x_F(t_s) −
  v_F(t_s) · 1.8`` (m, negative = behind its constant-speed path, :func:`nudge_train.idm.cutins.fall_back`),
  and the same minus the median fall-back of followers WITHOUT a cut-in in the same source
  (:func:`nudge_train.idm.cutins.control_fall_backs`), the part a cut-in adds.

A model's *fall-back* is its predicted follower x at 1.8 s minus the same constant-speed
reference (directly comparable to the real one); its *reaction* is the predicted follower x under
the real path minus under the keep-lane counterfactual. Positions are the data pipeline's road
frame (x along the road, y left, vehicle centres), the frame the models were trained in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nudge_train.constants import DT, OBS_LEN, PRED_LEN
from nudge_train.idm.cutins import CutIn, Tracks, fall_back
from nudge_train.training.reaction_measure import REACTION_STEP, PredictFn, keep_lane

__all__ = ["CutInCase", "cutin_case", "cutin_reactions"]

HORIZON_S = (REACTION_STEP + 1) * DT
"""Time after ``t_s`` the reaction is read at (s): 1.8."""


@dataclass(frozen=True)
class CutInCase:
    """One real cut-in prepared for prediction (m, road frame; rows of ``history``: 0 = the
    intruder, ``follower`` = the real follower). ``real_fb``: the follower's real fall-back at
    1.8 s (NaN when its track ends before); ``x0``, ``v0``: the follower's x (m) and speed (m/s)
    at ``t_s``."""

    key: str
    source: str
    split: str
    history: np.ndarray
    candidate: np.ndarray
    keep: np.ndarray
    follower: int
    x0: float
    v0: float
    real_fb: float
    real_fbs: np.ndarray | None = None
    """``[steps]`` the follower's real fall-back at every step 1..steps (m; NaN once its track ends)."""


def cutin_case(tr: Tracks, e: CutIn, lead_s: float, radius: float = 60.0, steps: int = PRED_LEN) -> CutInCase | None:
    """The prediction problem of event ``e`` on its tracks ``tr``, starting ``lead_s`` s before the
    centre crossing; None when the intruder's or the follower's history, or the intruder's next
    ``steps`` steps (default 6: 1.8 s), are not all observed. ``real_fb`` is the follower's real
    fall-back at ``steps`` · 0.3 s, ``real_fbs`` at every step 1..``steps``."""
    t_s = e.t_centre - lead_s
    t_obs = t_s + DT * np.arange(-(OBS_LEN - 1), 1)
    t_fut = t_s + DT * np.arange(1, steps + 1)

    def path(vid: int, t: np.ndarray) -> np.ndarray:
        return np.stack([tr.series(vid, "x", t), tr.series(vid, "y", t)], axis=-1)

    ego_hist, ego_fut = path(e.intruder, t_obs), path(e.intruder, t_fut)
    fol_hist = path(e.follower, t_obs)
    if not (np.isfinite(ego_hist).all() and np.isfinite(ego_fut).all() and np.isfinite(fol_hist).all()):
        return None
    rows = [ego_hist, fol_hist]
    frame = int(round(t_s / tr.dt))
    others = sorted({int(tr.table.vehicle[r]) for r in tr.at(frame)} - {e.intruder, e.follower})
    for vid in others:
        h = path(vid, t_obs)
        if np.isfinite(h).all() and abs(h[-1, 0] - ego_hist[-1, 0]) <= radius:
            rows.append(h)
    history = np.stack(rows).astype(np.float64)
    x0 = float(fol_hist[-1, 0])
    v0 = float(tr.series(e.follower, "speed", np.array([t_s]))[0])
    fbs = fall_back(tr, e.follower, t_s, DT * np.arange(0, steps + 1))[1:]
    cand = ego_fut[None].astype(np.float64)
    return CutInCase(key=e.key, source=e.source, split=e.split, history=history, candidate=cand,
                     keep=keep_lane(cand, float(ego_hist[-1, 1])).astype(np.float64), follower=1,
                     x0=x0, v0=v0, real_fb=float(fbs[-1]), real_fbs=fbs.astype(np.float64))


def cutin_reactions(cases: list[CutInCase], predictors: dict[str, PredictFn],
                    step: int = REACTION_STEP) -> dict[str, dict[str, np.ndarray]]:
    """Per predictor: ``fall_back`` ``[E]`` (predicted follower x at step index ``step``, default
    1.8 s, under the real path minus the constant-speed reference) and ``reaction`` ``[E]`` (under
    the real path minus under the keep-lane counterfactual), metres, in the order of ``cases``."""
    at_s = (step + 1) * DT
    out: dict[str, dict[str, np.ndarray]] = {}
    for name, fn in predictors.items():
        fb, re = [], []
        for c in cases:
            p = fn(c.history.astype(np.float32), np.concatenate([c.candidate, c.keep]).astype(np.float32))
            x_c = float(p[0, c.follower - 1, step, 0])
            x_k = float(p[1, c.follower - 1, step, 0])
            fb.append(x_c - (c.x0 + c.v0 * at_s))
            re.append(x_c - x_k)
        out[name] = {"fall_back": np.array(fb), "reaction": np.array(re)}
    return out
