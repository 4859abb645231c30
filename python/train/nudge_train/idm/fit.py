"""Per-follower and pooled IDM calibration on real leader-follower records.

Calibration by simulation: each follower starts at its logged position and speed, follows its
logged leader with IDM, and the parameters minimise the RMSE of the bumper-to-bumper gap over
the whole record (the spacing-based measure the car-following calibration literature recommends,
e.g. Punzo, Ciuffo & Montanino 2012; Punzo, Zheng & Montanino 2021). The optimiser is scipy's
differential evolution, vectorised over its population and seeded per follower.

Fitted per driver: T, s0, a_max, b and the desired-speed ratio v0 / v_ref (v_ref = the
follower's highest logged speed); delta is fixed (``FitConfig.delta``). The search box is the
plausibility box: a fit on its face is reported "at bound" for that parameter.
"""

from __future__ import annotations

import json
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import differential_evolution
from tqdm import tqdm

from nudge_train.jsonio import loads_json

from .model import PairBatch, batch_errors, constant_speed_errors
from .pairs import Pair

FIT_NAMES = ("T", "s0", "a_max", "b", "v0_ratio")
"""Driver parameter vector [5]: T (s), s0 (m), a_max (m/s^2), b (m/s^2), v0 / v_ref (1)."""


@dataclass(frozen=True)
class FitConfig:
    """Calibration settings (the one source of their defaults).

    ``bounds``: plausibility box per parameter (FIT_NAMES order), also the search box.
    ``at_bound_frac``: a parameter within this fraction of its range from a bound is "at bound".
    ``max_rmse_gap``: a driver whose calibrated gap RMSE exceeds this (m) is a bad fit, excluded
    from the population; so is one whose calibrated simulation collides with its leader.
    """

    bounds: tuple[tuple[float, float], ...] = ((0.3, 3.0), (0.5, 5.0), (0.3, 4.0), (0.5, 5.0), (1.0, 2.0))
    delta: float = 4.0
    popsize: int = 15
    maxiter: int = 300
    tol: float = 1e-5
    seed: int = 0
    at_bound_frac: float = 0.01
    max_rmse_gap: float = 3.0
    prior_weight: float = 0.5

    def validate(self) -> None:
        """Raise ValueError naming the first bad setting."""
        if len(self.bounds) != len(FIT_NAMES):
            raise ValueError(f"bounds: need {len(FIT_NAMES)} (lo, hi) pairs, got {len(self.bounds)}")
        for name, (lo, hi) in zip(FIT_NAMES, self.bounds):
            if not (0 < lo < hi and np.isfinite(hi)):
                raise ValueError(f"bounds[{name}]: need 0 < lo < hi, got ({lo}, {hi})")
        if not (np.isfinite(self.prior_weight) and self.prior_weight >= 0):
            raise ValueError(f"prior_weight must be finite and >= 0, got {self.prior_weight!r}")
        for name in ("delta", "tol", "at_bound_frac", "max_rmse_gap"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        if self.popsize < 2 or self.maxiter < 1:
            raise ValueError("popsize must be >= 2 and maxiter >= 1")


@dataclass
class DriverFit:
    """One calibrated follower: ``params`` [5] (FIT_NAMES), errors of its calibrated simulation
    over all its records, and its status (``ok``, ``bad_fit``, ``collision``)."""

    driver: str
    source: str
    split: str
    pairs: list[str]
    params: list[float]
    rmse_gap: float
    rmse_speed: float
    n: int
    collided: bool
    at_bound: list[str] = field(default_factory=list)
    status: str = "ok"


def driver_key(p: Pair) -> str:
    """A follower's identity: ``source:scene:follower``."""
    return f"{p.source}:{p.scene}:{p.follower}"


def group_by_driver(pairs: list[Pair]) -> dict[str, list[Pair]]:
    """Pairs per follower, in first-seen order."""
    out: dict[str, list[Pair]] = {}
    for p in pairs:
        out.setdefault(driver_key(p), []).append(p)
    return out


def _objective(batches: list[PairBatch], delta: float, prior: np.ndarray | None, weight: float,
               span: np.ndarray):
    n = sum(float(b.valid.sum()) for b in batches)

    def f(x: np.ndarray) -> np.ndarray:
        x2 = np.atleast_2d(x.T) if x.ndim == 2 else x[None, :]
        sse = sum(batch_errors(b, x2[:, :4], x2[:, 4], delta).sse_gap.sum(axis=1) for b in batches)
        out = np.sqrt(sse / n)
        if prior is not None and weight > 0:
            out = out + weight * np.sqrt(np.mean(((x2 - prior[None, :]) / span[None, :]) ** 2, axis=1))
        return out
    return f


def calibrate(batch: PairBatch | list[PairBatch], cfg: FitConfig, seed: int | list[int],
              prior: np.ndarray | None = None) -> np.ndarray:
    """Parameters [5] minimising the gap RMSE over every sample of every record in ``batch``
    (one batch, or several batches of different lengths, e.g. one per source), plus
    ``cfg.prior_weight`` times the normalised distance to ``prior`` [5] when given."""
    batches = batch if isinstance(batch, list) else [batch]
    span = np.asarray([hi - lo for lo, hi in cfg.bounds])
    res = differential_evolution(_objective(batches, cfg.delta, prior, cfg.prior_weight, span), list(cfg.bounds), vectorized=True,
                                 updating="deferred", seed=np.random.default_rng(seed), popsize=cfg.popsize,
                                 maxiter=cfg.maxiter, tol=cfg.tol, polish=False, init="latinhypercube")
    return np.asarray(res.x, dtype=np.float64)


def at_bounds(params: np.ndarray, cfg: FitConfig) -> list[str]:
    """Names of the parameters within ``at_bound_frac`` of their range from a bound."""
    out = []
    for name, v, (lo, hi) in zip(FIT_NAMES, params, cfg.bounds):
        tol = cfg.at_bound_frac * (hi - lo)
        if v <= lo + tol:
            out.append(f"{name}=lo")
        elif v >= hi - tol:
            out.append(f"{name}=hi")
    return out


def fit_driver(key: str, records: list[Pair], cfg: FitConfig, prior: np.ndarray | None = None) -> DriverFit:
    """Calibrate one follower on all its records (seed: cfg.seed and a CRC of the key); the
    reported errors and status are those of the plain gap RMSE (without the prior term)."""
    batch = PairBatch.of(records)
    x = calibrate(batch, cfg, [cfg.seed, zlib.crc32(key.encode())], prior)
    e = batch_errors(batch, x[None, :4], x[None, 4:5], cfg.delta)
    n = float(e.n.sum())
    rg = float(np.sqrt(e.sse_gap.sum() / n))
    rv = float(np.sqrt(e.sse_speed.sum() / n))
    collided = bool(e.collided.any())
    status = "collision" if collided else ("bad_fit" if rg > cfg.max_rmse_gap else "ok")
    return DriverFit(driver=key, source=records[0].source, split=records[0].split, pairs=[r.key for r in records],
                     params=[float(v) for v in x], rmse_gap=rg, rmse_speed=rv, n=int(n), collided=collided,
                     at_bound=at_bounds(x, cfg), status=status)


def fit_drivers(pairs: list[Pair], cfg: FitConfig, cache: Path | None = None, progress: bool = True,
                priors: dict[str, np.ndarray] | None = None) -> list[DriverFit]:
    """Calibrate every follower (``priors``: source -> prior parameter set [5]); with ``cache``
    (a JSON-lines file) finished fits are kept and a rerun resumes where it stopped. The result
    is in driver order, independent of resuming."""
    cfg.validate()
    groups = group_by_driver(pairs)
    done: dict[str, DriverFit] = {}
    if cache is not None and cache.exists():
        for line in cache.read_text().splitlines():
            if line.strip():
                d = DriverFit(**loads_json(line, cache))
                if d.driver in groups:
                    done[d.driver] = d
    todo = [k for k in groups if k not in done]
    fh = None
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        fh = open(cache, "a")
    try:
        for k in tqdm(todo, desc="fit drivers", disable=not progress):
            prior = None if priors is None else priors.get(groups[k][0].source)
            d = fit_driver(k, groups[k], cfg, prior)
            done[k] = d
            if fh is not None:
                fh.write(json.dumps(asdict(d)) + "\n")
                fh.flush()
    finally:
        if fh is not None:
            fh.close()
    return [done[k] for k in groups]


def fit_pooled(pairs: list[Pair], cfg: FitConfig, delta: float | None = None) -> np.ndarray:
    """One parameter set [5] for all ``pairs`` (minimising the gap RMSE over all their samples;
    records of each source are batched separately so short ones are not padded to long ones)."""
    c = FitConfig(**{**asdict(cfg), "delta": cfg.delta if delta is None else delta, "prior_weight": 0.0})
    by_source: dict[str, list[Pair]] = {}
    for p in pairs:
        by_source.setdefault(p.source, []).append(p)
    return calibrate([PairBatch.of(v) for _, v in sorted(by_source.items())], c, [cfg.seed, 7])


@dataclass
class HeldOut:
    """Errors on held-out records per method: method -> {"rmse_gap": [B], "rmse_speed": [B]} (per
    record, m and m/s) plus the records' keys."""

    keys: list[str]
    methods: dict[str, dict[str, np.ndarray]]


def evaluate(pairs: list[Pair], population: np.ndarray, pooled: np.ndarray, own: dict[str, np.ndarray] | None,
             delta: float) -> HeldOut:
    """Gap/speed RMSE of each held-out record under: ``pooled`` (one set [5]); ``population``
    [N, 5] (each train driver in turn: ``population_mean`` is the expected error of a randomly
    drawn driver, ``population_median_driver`` the error of the element-wise median driver);
    ``constant_speed``; and ``own`` (the record's own calibration: the fit's floor)."""
    batch = PairBatch.of(pairs)
    out: dict[str, dict[str, np.ndarray]] = {}

    def put(name: str, e) -> None:
        out[name] = {"rmse_gap": e.rmse_gap()[0], "rmse_speed": e.rmse_speed()[0]}

    put("pooled", batch_errors(batch, pooled[None, :4], pooled[None, 4:5], delta))
    med = np.median(population, axis=0)
    put("population_median_driver", batch_errors(batch, med[None, :4], med[None, 4:5], delta))
    e = batch_errors(batch, population[:, :4], population[:, 4], delta)
    out["population_mean"] = {"rmse_gap": e.rmse_gap().mean(axis=0), "rmse_speed": e.rmse_speed().mean(axis=0)}
    put("constant_speed", constant_speed_errors(batch))
    if own is not None:
        per = np.stack([own[driver_key(p)] for p in pairs])  # [B, 5]
        e = batch_errors(batch, per[None, :, :4], per[None, :, 4], delta)
        put("own_calibration", e)
    return HeldOut(keys=[p.key for p in pairs], methods=out)
