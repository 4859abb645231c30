"""The Intelligent Driver Model (IDM) and its follower simulator, vectorised over parameter sets.

IDM (Treiber, Hennecke & Helbing 2000), for a follower at speed ``v`` (m/s) behind a leader at
bumper-to-bumper gap ``s`` (m), approach rate ``dv = v - v_leader`` (m/s)::

    a = a_max * (1 - (v / v0)**delta - (s_star / s)**2)
    s_star = s0 + v * T + v * dv / (2 * sqrt(a_max * b))

Free road (no leader) drops the interaction term. The simulator integrates one follower behind a
GIVEN leader trajectory with the ballistic update (constant acceleration over a step, speed never
negative) and a physical deceleration limit :data:`MAX_DECEL` (m/s^2); both are part of the
model the simulator world must reproduce (recorded in ``assets/worlds/idm.json``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

MAX_DECEL = 9.0
"""Physical braking limit (m/s^2): the IDM acceleration is floored at -MAX_DECEL."""

GAP_FLOOR = 0.01
"""Gap (m) used in the interaction term when the simulated gap is <= it (a simulated collision,
always reported by :func:`simulate_follower` as ``collided``)."""

PARAM_NAMES = ("T", "s0", "a_max", "b")
"""Fitted IDM parameters, in the order of every parameter array ``[..., 4]``:
time headway T (s), jam gap s0 (m), maximum acceleration a_max (m/s^2), comfortable deceleration b (m/s^2)."""


@dataclass(frozen=True)
class IdmParams:
    """One IDM driver. Units: T s, s0 m, a_max m/s^2, b m/s^2, v0 m/s, delta dimensionless."""

    T: float
    s0: float
    a_max: float
    b: float
    v0: float
    delta: float = 4.0

    def validate(self) -> None:
        """Raise ValueError naming the first non-finite or non-positive field."""
        for k, v in asdict(self).items():
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"IDM parameter {k} must be finite and > 0, got {v!r}")

    def array(self) -> np.ndarray:
        """The fitted part as ``[4]`` in :data:`PARAM_NAMES` order."""
        return np.array([self.T, self.s0, self.a_max, self.b], dtype=np.float64)


def desired_gap(v: np.ndarray, dv: np.ndarray, T: np.ndarray, s0: np.ndarray, a_max: np.ndarray,
                b: np.ndarray) -> np.ndarray:
    """IDM desired gap s* (m) for speed ``v`` and approach rate ``dv`` (m/s); broadcasts."""
    return s0 + v * T + v * dv / (2.0 * np.sqrt(a_max * b))


def idm_accel(v: np.ndarray, dv: np.ndarray, s: np.ndarray, v0: np.ndarray, T: np.ndarray,
              s0: np.ndarray, a_max: np.ndarray, b: np.ndarray, delta: float = 4.0) -> np.ndarray:
    """IDM acceleration (m/s^2) floored at -MAX_DECEL; broadcasts over every argument.

    ``s`` is the bumper-to-bumper gap (m); ``s = inf`` means free road. Gaps <= GAP_FLOOR use
    GAP_FLOOR (callers detect the collision themselves).
    """
    free = 1.0 - np.power(np.maximum(v, 0.0) / v0, delta)
    s_eff = np.maximum(s, GAP_FLOOR)
    inter = np.where(np.isfinite(s_eff), (np.maximum(desired_gap(v, dv, T, s0, a_max, b), 0.0) / s_eff) ** 2, 0.0)
    return np.maximum(a_max * (free - inter), -MAX_DECEL)


def equilibrium_gap(v: np.ndarray, v0: float, T: float, s0: float, delta: float = 4.0) -> np.ndarray:
    """Steady-state gap s_e(v) = (s0 + v T) / sqrt(1 - (v/v0)^delta) (m) for 0 <= v < v0."""
    v = np.asarray(v, dtype=np.float64)
    return (s0 + v * T) / np.sqrt(1.0 - (v / v0) ** delta)


@dataclass
class SimResult:
    """Simulated follower: front position ``x`` [P, K] (m), speed ``v`` [P, K] (m/s), acceleration
    ``a`` [P, K] (m/s^2, the one applied over step k -> k+1; last column repeats), gap ``s``
    [P, K] (m), and ``collided`` [P] (gap <= 0 at some step)."""

    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    s: np.ndarray
    collided: np.ndarray


def simulate_follower(x_init: float, v_init: float, lead_rear: np.ndarray, lead_v: np.ndarray,
                      params: np.ndarray, v0: np.ndarray | float, dt: float, delta: float = 4.0) -> SimResult:
    """Simulate a follower behind a given leader for K steps, for P parameter sets at once.

    ``x_init``/``v_init``: follower front position (m) and speed (m/s) at step 0;
    ``lead_rear`` [K] leader rear-bumper position (m, NaN or +inf where there is no leader: free
    road); ``lead_v`` [K] leader speed (m/s); ``params`` [P, 4] (:data:`PARAM_NAMES`);
    ``v0`` desired speed(s) [P] or scalar (m/s); ``dt`` step (s).
    Ballistic update: v' = max(v + a dt, 0), x' = x + (v + v') / 2 * dt.
    """
    params = np.atleast_2d(np.asarray(params, dtype=np.float64))
    p = params.shape[0]
    k = lead_rear.shape[0]
    T, s0, a_max, b = (params[:, i] for i in range(4))
    v0 = np.broadcast_to(np.asarray(v0, dtype=np.float64), (p,))
    xs = np.empty((p, k))
    vs = np.empty((p, k))
    acc = np.empty((p, k))
    gaps = np.empty((p, k))
    x = np.full(p, float(x_init))
    v = np.full(p, float(v_init))
    lead_ok = np.isfinite(lead_rear)
    for i in range(k):
        xs[:, i] = x
        vs[:, i] = v
        if lead_ok[i]:
            s = lead_rear[i] - x
            a = idm_accel(v, v - lead_v[i], s, v0, T, s0, a_max, b, delta)
        else:
            s = np.full(p, np.inf)
            a = idm_accel(v, np.zeros(p), s, v0, T, s0, a_max, b, delta)
        gaps[:, i] = s
        acc[:, i] = a
        v_next = np.maximum(v + a * dt, 0.0)
        x = x + 0.5 * (v + v_next) * dt
        v = v_next
    collided = np.any(gaps <= 0.0, axis=1)
    return SimResult(x=xs, v=vs, a=acc, s=gaps, collided=collided)


@dataclass
class PairBatch:
    """Several leader-follower records padded to a common length K (B records).

    ``xf``, ``vf``, ``lead_rear``, ``vl`` [B, K] as in :class:`nudge_train.idm.pairs.Pair`
    (padding: last value repeated); ``valid`` [B, K] (False on padding); ``v_ref`` [B] (m/s) the
    follower's highest logged speed (desired speed v0 = ratio * v_ref); ``dt`` (s).
    """

    xf: np.ndarray
    vf: np.ndarray
    lead_rear: np.ndarray
    vl: np.ndarray
    valid: np.ndarray
    v_ref: np.ndarray
    dt: float

    @staticmethod
    def of(records: list) -> "PairBatch":
        """Pad records exposing ``xf``, ``vf``, ``lead_rear``, ``vl`` [K_i] and ``dt``."""
        if not records:
            raise ValueError("PairBatch.of needs at least one record")
        dts = {float(r.dt) for r in records}
        if len(dts) != 1:
            raise ValueError(f"records with different time steps {sorted(dts)}")
        k = max(r.xf.shape[0] for r in records)
        b = len(records)

        def pad(name: str) -> np.ndarray:
            out = np.empty((b, k))
            for i, r in enumerate(records):
                a = getattr(r, name)
                out[i, : a.shape[0]] = a
                out[i, a.shape[0]:] = a[-1]
            return out

        valid = np.zeros((b, k), dtype=bool)
        for i, r in enumerate(records):
            valid[i, : r.xf.shape[0]] = True
        v_ref = np.array([float(np.max(r.vf)) for r in records])
        return PairBatch(xf=pad("xf"), vf=pad("vf"), lead_rear=pad("lead_rear"), vl=pad("vl"), valid=valid,
                         v_ref=v_ref, dt=dts.pop())


@dataclass
class BatchErrors:
    """Squared-error sums per (parameter set, record): ``sse_gap``, ``sse_speed`` [P, B];
    ``n`` [B] valid samples; ``collided`` [P, B]."""

    sse_gap: np.ndarray
    sse_speed: np.ndarray
    n: np.ndarray
    collided: np.ndarray

    def rmse_gap(self) -> np.ndarray:
        """Gap RMSE [P, B] (m)."""
        return np.sqrt(self.sse_gap / self.n)

    def rmse_speed(self) -> np.ndarray:
        """Speed RMSE [P, B] (m/s)."""
        return np.sqrt(self.sse_speed / self.n)


def batch_errors(batch: PairBatch, params: np.ndarray, v0_ratio: np.ndarray, delta: float = 4.0) -> BatchErrors:
    """Simulate every record of ``batch`` with every parameter set and sum the errors.

    ``params`` [P, 4] (:data:`PARAM_NAMES`) or [P, B, 4] (one set per record); ``v0_ratio`` [P] or
    [P, B] (desired speed = ratio * batch.v_ref). Each follower starts at its logged front position
    and speed and follows its logged leader. Error = simulated minus logged (gap error equals the
    position error with the sign flipped).
    """
    params = np.asarray(params, dtype=np.float64)
    b, k = batch.xf.shape
    if params.ndim == 2:
        params = np.broadcast_to(params[:, None, :], (params.shape[0], b, 4))
    p = params.shape[0]
    T, s0, a_max, bb = (params[..., i] for i in range(4))
    v0 = np.broadcast_to(np.asarray(v0_ratio, dtype=np.float64).reshape(p, -1), (p, b)) * batch.v_ref[None, :]
    sqrt_ab2 = 2.0 * np.sqrt(a_max * bb)
    x = np.broadcast_to(batch.xf[:, 0], (p, b)).copy()
    v = np.broadcast_to(batch.vf[:, 0], (p, b)).copy()
    sse_g = np.zeros((p, b))
    sse_v = np.zeros((p, b))
    collided = np.zeros((p, b), dtype=bool)
    dt = batch.dt
    for i in range(k):
        m = batch.valid[:, i]
        ex = x - batch.xf[:, i]
        ev = v - batch.vf[:, i]
        sse_g += np.where(m, ex * ex, 0.0)
        sse_v += np.where(m, ev * ev, 0.0)
        s = batch.lead_rear[:, i] - x
        collided |= (s <= 0.0) & m
        s_star = np.maximum(s0 + v * T + v * (v - batch.vl[:, i]) / sqrt_ab2, 0.0)
        a = a_max * (1.0 - (np.maximum(v, 0.0) / v0) ** delta - (s_star / np.maximum(s, GAP_FLOOR)) ** 2)
        a = np.maximum(a, -MAX_DECEL)
        v_next = np.maximum(v + a * dt, 0.0)
        x = x + 0.5 * (v + v_next) * dt
        v = v_next
    return BatchErrors(sse_gap=sse_g, sse_speed=sse_v, n=batch.valid.sum(axis=1).astype(np.float64), collided=collided)


def constant_speed_errors(batch: PairBatch) -> BatchErrors:
    """Errors [1, B] of the baseline that keeps the follower's initial speed."""
    t = np.arange(batch.xf.shape[1]) * batch.dt
    x = batch.xf[:, :1] + batch.vf[:, :1] * t[None, :]
    ex = np.where(batch.valid, x - batch.xf, 0.0)
    ev = np.where(batch.valid, batch.vf[:, :1] - batch.vf, 0.0)
    s = batch.lead_rear - x
    return BatchErrors(sse_gap=(ex ** 2).sum(axis=1)[None], sse_speed=(ev ** 2).sum(axis=1)[None],
                       n=batch.valid.sum(axis=1).astype(np.float64),
                       collided=np.any((s <= 0) & batch.valid, axis=1)[None])
