"""The three stages behind ``nudge-train idm``: fit, cut-ins, report (see docs/results/idm_fit.md).

Intermediate results go to ``runs/idm/`` (resumable driver fits, JSON results for the report);
the products are ``assets/worlds/idm.json`` (``nudge.idm/1``), ``assets/worlds/cutins.json``
(``nudge.cutins/1``) and the report.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nudge_train import paths
from nudge_train.jsonio import load_json
from nudge_train.paths import repo_relative
from nudge_train.provenance import git_commit, sha256_file

from . import cutins as ci
from .fit import FIT_NAMES, DriverFit, FitConfig, evaluate, fit_drivers, fit_pooled
from .model import GAP_FLOOR, MAX_DECEL
from .pairs import PairStats, read_i80_pairs, us101_pairs
from .sources import COIFMAN, I80_PAIRS, OVERLAP_CSV, US101_FLAT, Sources, load_sources
from .yielding import YieldConfig, fit_rule, mixed, mixed_pos_err, sample_drivers, simulate_event

IDM_SCHEMA = "nudge.idm/1"
DELTAS = (2.0, 4.0, 8.0)
"""Acceleration exponents compared on validation with pooled fits."""


@dataclass(frozen=True)
class Settings:
    """Everything the results depend on (recorded in the outputs)."""

    data_root: Path = field(default_factory=paths.ngsim)
    runs: Path = field(default_factory=lambda: paths.runs() / "idm")
    assets: Path = field(default_factory=lambda: paths.assets() / "worlds")
    doc: Path = field(default_factory=lambda: paths.results() / "idm_fit.md")
    figures: Path = field(default_factory=paths.figures)
    i80_min_s: float = 5.0
    us101_min_s: float = 5.0
    bootstrap: int = 2000
    seed: int = 0
    fit: FitConfig = field(default_factory=FitConfig)
    cutin: ci.CutInConfig = field(default_factory=ci.CutInConfig)
    rule: YieldConfig = field(default_factory=YieldConfig)
    progress: bool = True


def _digest(obj: object) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:12]


def provenance(s: Settings) -> dict:
    """Data files with sha256 prefixes, the split rule, the commit."""
    files = {}
    for rel in (I80_PAIRS, COIFMAN, US101_FLAT, OVERLAP_CSV):
        p = s.data_root / rel
        files[rel] = sha256_file(p)[:16] if p.exists() else "missing"
    return {"data": files, "us101_scenes": "us101/commonroad_us101_T-1/*.xml.gz + us101/commonroad_us101_2018b_extra/"
                                           "*.xml.gz (one variant per scene, USA_US101-3_5_T-1 excluded)",
            "split": "the data pipeline's rule (nudge-train data build, seed 0): US-101 by overlap group, "
                     "I-80 by 60 s time block (a follower takes the block of its record's middle frame)",
            "commit": git_commit()}


def median_ci(values: np.ndarray, rng: np.random.Generator, n_boot: int) -> tuple[float, float, float, int]:
    """(median, 2.5 %, 97.5 % percentile-bootstrap bounds, n) of the finite values."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.shape[0] == 0:
        return float("nan"), float("nan"), float("nan"), 0
    idx = rng.integers(0, v.shape[0], size=(n_boot, v.shape[0]))
    meds = np.median(v[idx], axis=1)
    return float(np.median(v)), float(np.percentile(meds, 2.5)), float(np.percentile(meds, 97.5)), int(v.shape[0])


def _r(x: float, k: int = 4) -> float:
    return float(round(float(x), k))


# ---------------------------------------------------------------------------------------------- fit


def _summary(per_record: dict[str, np.ndarray]) -> dict:
    g, v = per_record["rmse_gap"], per_record["rmse_speed"]
    return {"n": int(g.shape[0]), "gap_rmse_median": _r(np.median(g), 3), "gap_rmse_mean": _r(np.mean(g), 3),
            "speed_rmse_median": _r(np.median(v), 3), "speed_rmse_mean": _r(np.mean(v), 3)}


def run_fit(s: Settings, sources: Sources | None = None) -> dict:
    """Pairs -> per-driver fits (resumable) -> pooled fits -> held-out errors; writes
    ``runs/idm/fit.json`` and ``assets/worlds/idm.json`` (keeping an existing intrusion rule)."""
    s.fit.validate()
    sources = sources if sources is not None else load_sources(s.data_root, s.progress)
    st_i80, st_us = PairStats(), PairStats()
    i80 = read_i80_pairs(s.data_root / I80_PAIRS, sources, st_i80, min_s=s.i80_min_s)
    us = us101_pairs(sources, s.us101_min_s, st_us)
    pairs = i80 + us
    by_src = {"i80": [p for p in pairs if p.source == "i80"], "us101": [p for p in pairs if p.source == "us101"]}
    # Pooled sets on the train records (also the per-driver fits' prior), and the delta study.
    pooled: dict[str, list[float]] = {}
    delta_fits: dict[tuple[str, float], np.ndarray] = {}
    steps = [(src, d) for src in ("i80", "us101") for d in DELTAS] + [("all", s.fit.delta)]
    for src, d in tqdm(steps, desc="pooled fits", disable=not s.progress):
        train = [p for p in (pairs if src == "all" else by_src[src]) if p.split == "train"]
        x = fit_pooled(train, s.fit, delta=d)
        delta_fits[(src, d)] = x
        if d == s.fit.delta:
            pooled[src] = [float(v) for v in x]
    priors = {src: np.asarray(pooled[src]) for src in ("i80", "us101")}
    digest = _digest([asdict(s.fit), s.i80_min_s, s.us101_min_s, pooled if s.fit.prior_weight > 0 else None])
    fits = fit_drivers(pairs, s.fit, cache=s.runs / f"driver_fits-{digest}.jsonl", progress=s.progress, priors=priors)
    plain_cfg = replace(s.fit, prior_weight=0.0)
    plain = fit_drivers(pairs, plain_cfg, progress=s.progress,
                        cache=s.runs / f"driver_fits-{_digest([asdict(plain_cfg), s.i80_min_s, s.us101_min_s, None])}.jsonl")
    own = {f.driver: np.asarray(f.params) for f in fits}
    train_ok = [f for f in fits if f.split == "train" and f.status == "ok"]
    population = np.asarray([f.params for f in train_ok])
    plain_pop = np.asarray([f.params for f in plain if f.split == "train" and f.status == "ok"])
    plain_own = {f.driver: np.asarray(f.params) for f in plain}
    delta_study: dict[str, dict] = {}
    for (src, d), x in delta_fits.items():
        if src != "all":
            val = [p for p in by_src[src] if p.split == "val"]
            h = evaluate(val, population, x, None, d)
            delta_study.setdefault(src, {})[f"{d:g}"] = {"params": [_r(v) for v in x],
                                                         "val": _summary(h.methods["pooled"])}
    heldout: dict[str, dict] = {}
    per_record: dict[str, dict] = {}
    for src in ("i80", "us101"):
        for split in ("val", "test"):
            recs = [p for p in by_src[src] if p.split == split]
            if not recs:
                continue
            h = evaluate(recs, population, np.asarray(pooled[src]), own, s.fit.delta)
            h_all = evaluate(recs, population, np.asarray(pooled["all"]), None, s.fit.delta)
            m = {k: _summary(v) for k, v in h.methods.items()}
            m["pooled_all_sources"] = _summary(h_all.methods["pooled"])
            h_plain = evaluate(recs, plain_pop, np.asarray(pooled[src]), plain_own, s.fit.delta)
            m["plain_population_mean"] = _summary(h_plain.methods["population_mean"])
            m["plain_own_calibration"] = _summary(h_plain.methods["own_calibration"])
            heldout[f"{src}/{split}"] = m
            per_record[f"{src}/{split}"] = {k: {kk: [_r(x, 3) for x in vv] for kk, vv in v.items()}
                                            for k, v in h.methods.items()}
    counts = {}
    for src in ("i80", "us101"):
        fs = [f for f in fits if f.source == src]
        ps = [f for f in plain if f.source == src]
        counts[src] = {
            "plain": {"status": {k: sum(f.status == k for f in ps) for k in ("ok", "bad_fit", "collision")},
                      "any_at_bound": sum(bool(f.at_bound) for f in ps),
                      "iqr": [[_r(q, 3) for q in np.percentile([f.params[k] for f in ps if f.split == "train"
                                                                and f.status == "ok"], [25, 50, 75])]
                              for k in range(len(FIT_NAMES))]},
            "pairs": len(by_src[src]), "pairs_dropped": (st_i80 if src == "i80" else st_us).dropped,
            "drivers": {sp: sum(f.split == sp for f in fs) for sp in ("train", "val", "test")},
            "status": {k: sum(f.status == k for f in fs) for k in ("ok", "bad_fit", "collision")},
            "train_ok": sum(f.status == "ok" and f.split == "train" for f in fs),
            "at_bound": {name: {side: sum(f"{name}={side}" in f.at_bound for f in fs) for side in ("lo", "hi")}
                         for name in FIT_NAMES},
            "any_at_bound": sum(bool(f.at_bound) for f in fs),
            "record_s": {"median": _r(np.median([p.duration for p in by_src[src]]), 1),
                         "min": _r(min(p.duration for p in by_src[src]), 1),
                         "max": _r(max(p.duration for p in by_src[src]), 1)},
        }
    result = {"settings": {"fit": asdict(s.fit), "i80_min_s": s.i80_min_s, "us101_min_s": s.us101_min_s},
              "counts": counts, "pooled": pooled, "delta_study": delta_study, "heldout": heldout,
              "per_record": per_record, "drivers": [asdict(f) for f in fits]}
    s.runs.mkdir(parents=True, exist_ok=True)
    (s.runs / "fit.json").write_text(json.dumps(result, indent=1) + "\n")
    write_idm_json(s, result, train_ok)
    return result


def write_idm_json(s: Settings, fit: dict, train_ok: list[DriverFit]) -> dict:
    """``assets/worlds/idm.json``: the train population, pooled sets, model constants, metrics."""
    path = s.assets / "idm.json"
    old = load_json(path) if path.exists() else {}
    doc = {
        "schema": IDM_SCHEMA,
        "units": {"T": "s", "s0": "m", "a_max": "m/s^2", "b": "m/s^2", "v0_ratio": "1", "gap": "m",
                  "speed": "m/s", "threshold_m": "m"},
        "model": {
            "acceleration": "a = a_max * (1 - (v/v0)^delta - (s_star/s)^2), "
                            "s_star = s0 + v*T + v*(v - v_leader) / (2*sqrt(a_max*b)); free road: no s_star term",
            "delta": s.fit.delta,
            "v0": "v0 = v0_ratio * v_ref, v_ref = the vehicle's highest logged speed",
            "gap": "bumper to bumper (leader rear minus follower front), m",
            "max_decel_mps2": MAX_DECEL,
            "gap_floor_m": GAP_FLOOR,
            "integration": "ballistic, dt = 0.1 s: v' = max(v + a dt, 0), x' = x + (v + v')/2 dt",
        },
        "parameter_names": list(FIT_NAMES),
        "bounds": {n: list(b) for n, b in zip(FIT_NAMES, s.fit.bounds)},
        "drivers": [[_r(v) for v in f.params] for f in train_ok],
        "driver_sources": [f.source for f in train_ok],
        "sampling": "each vehicle draws one row of drivers (with replacement, seeded); rows carry their source",
        "pooled": {k: [_r(v) for v in x] for k, x in fit["pooled"].items()},
        "intrusion": old.get("intrusion"),
        "metrics": {"heldout": fit["heldout"], "counts": {k: {kk: vv for kk, vv in v.items() if kk != "pairs_dropped"}
                                                          for k, v in fit["counts"].items()}},
        "provenance": provenance(s),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return doc


# ---------------------------------------------------------------------------------------- cut-ins


def run_cutins(s: Settings, sources: Sources | None = None) -> dict:
    """Find the real cut-ins, measure the reactions, fit the intrusion rule; writes
    ``assets/worlds/cutins.json``, ``runs/idm/cutins.json`` and the ``intrusion`` of idm.json."""
    idm_path = s.assets / "idm.json"
    if not idm_path.exists():
        raise FileNotFoundError(f"{idm_path}: run the fit stage first")
    idm = load_json(idm_path)
    population = np.asarray(idm["drivers"], dtype=np.float64)
    pooled = {k: np.asarray(v) for k, v in idm["pooled"].items()}
    delta = float(idm["model"]["delta"])
    sources = sources if sources is not None else load_sources(s.data_root, s.progress)
    cs = ci.find_cutins(sources, s.cutin, progress=s.progress)
    rng = np.random.default_rng([s.seed, 13])
    # Per-event measurements.
    rows = []
    for e in tqdm(cs.events, desc="reactions", disable=not s.progress):
        tr = cs.tracks[e.scene]
        valid = ci.TAUS <= e.follower_after_s + 1e-9
        fb_c = np.where(valid, ci.fall_back(tr, e.follower, e.t_centre), np.nan)
        fb_e = None
        if e.t_edge is not None:
            valid_e = ci.TAUS <= e.follower_after_s + (e.t_centre - e.t_edge) + 1e-9
            fb_e = np.where(valid_e, ci.fall_back(tr, e.follower, e.t_edge), np.nan)
        fb_i = np.where(valid, ci.idm_fall_back(tr, e, pooled[e.source], delta=delta), np.nan)
        t_on, ov_on, peak = ci.onset(tr, e, s.cutin)
        rows.append({"key": e.key, "source": e.source, "split": e.split, "fb_centre": fb_c, "fb_edge": fb_e,
                     "fb_idm_old_leader": fb_i, "onset_s": None if t_on is None else t_on - e.t_centre,
                     "onset_overlap_m": ov_on, "peak_decel": peak})
    # Controls: followers without a cut-in (US-101 per scene; I-80 whole table).
    controls: dict[str, np.ndarray] = {}
    for name, tr in cs.tracks.items():
        controls[name] = ci.control_fall_backs(tr, cs.events, s.cutin, name != "i80-coifman")
    for r, e in zip(rows, cs.events):
        c = controls[e.scene]
        base = np.nanmedian(c, axis=0) if c.shape[0] else np.full(ci.TAUS.shape, np.nan)
        r["fb_centre_net"] = r["fb_centre"] - base
    summary: dict[str, dict] = {}
    for src in ("us101", "i80", "all"):
        sel = [r for r in rows if src == "all" or r["source"] == src]
        if not sel:
            continue
        out: dict[str, object] = {"n_events": len(sel),
                                  "splits": {sp: sum(r["split"] == sp for r in sel) for sp in ("train", "val", "test")}}
        for meas in ("fb_centre", "fb_edge", "fb_idm_old_leader", "fb_centre_net"):
            arr = np.stack([r[meas] if r[meas] is not None else np.full(ci.TAUS.shape, np.nan) for r in sel])
            if not np.isfinite(arr).any():
                continue
            out[meas] = [median_ci(arr[:, k], rng, s.bootstrap) for k in range(ci.TAUS.shape[0])]
            full = arr[np.isfinite(arr[:, -1])]
            out[meas + "_full_horizon"] = [median_ci(full[:, k], rng, s.bootstrap) for k in range(ci.TAUS.shape[0])]
        evs = [e for e in cs.events if src == "all" or e.source == src]
        for name, vals in (("gap_m", [e.gap for e in evs]), ("time_headway_s", [e.time_headway for e in evs]),
                           ("follower_speed_mps", [e.follower_speed for e in evs]),
                           ("peak_decel_mps2", [r["peak_decel"] for r in sel]),
                           ("edge_lead_s", [e.t_centre - e.t_edge for e in evs if e.t_edge is not None]),
                           ("onset_s", [r["onset_s"] for r in sel if r["onset_s"] is not None]),
                           ("onset_overlap_m", [r["onset_overlap_m"] for r in sel if r["onset_overlap_m"] is not None])):
            v = np.asarray(vals, dtype=np.float64)
            out[name] = {"median_ci": median_ci(v, rng, s.bootstrap),
                         "quartiles": [_r(q, 3) for q in np.percentile(v, [25, 50, 75])] if v.shape[0] else []}
        out["decelerating"] = sum(r["onset_s"] is not None for r in sel)
        if src != "all":
            c = np.concatenate([v for k, v in controls.items() if (k == "i80-coifman") == (src == "i80")])
            out["control"] = {"n": int(c.shape[0]),
                              "median_ci": [median_ci(c[:, k], rng, s.bootstrap) for k in range(ci.TAUS.shape[0])]}
        summary[src] = out
    # Intrusion rule: US-101 train events fit, val+test report; I-80 at the lane-ID jump.
    drivers = sample_drivers(population, s.rule)
    th = np.asarray(s.rule.thresholds)
    sims = {e.key: simulate_event(cs.tracks[e.scene], e, drivers, th, s.rule, delta)
            for e in tqdm(cs.events, desc="rule sims", disable=not s.progress)}
    us_train = [sims[e.key] for e in cs.events if e.source == "us101" and e.split == "train"]
    us_held = [sims[e.key] for e in cs.events if e.source == "us101" and e.split != "train"]
    rule = fit_rule(us_train, s.rule)
    i_th = int(np.flatnonzero(np.isclose(th, rule.threshold))[0])

    def report_set(ss: list, i: int, p: float) -> dict:
        if not ss:
            return {"n": 0}
        sim = mixed(ss, i, p)
        real = np.stack([x.real for x in ss])
        err = mixed_pos_err(ss, i, p)
        return {"n": len(ss), "loss_m2": _r(np.nansum((np.nanmedian(sim, 0) - np.nanmedian(real, 0))[1:] ** 2), 4),
                "position_rmse_m": _r(np.sqrt(np.nanmean(err[:, 1:] ** 2)), 3),
                "sim_median": [_r(v, 3) for v in np.nanmedian(sim, axis=0)],
                "real_median": [_r(v, 3) for v in np.nanmedian(real, axis=0)]}

    i_zero = int(np.argmin(np.abs(th - 0.0)))
    rule_out = {
        "threshold_m": rule.threshold, "p_yield": rule.p,
        "grid": {"thresholds": th.tolist(), "p_yield": list(s.rule.p_yield),
                 "loss_m2": [[_r(v, 4) for v in row] for row in rule.loss]},
        "train": report_set(us_train, i_th, rule.p), "heldout": report_set(us_held, i_th, rule.p),
        "heldout_edge_at_line": report_set(us_held, i_zero, 1.0),
        "heldout_full_entry_only": report_set(us_held, i_zero, 0.0),
        "i80_at_lane_id_jump": report_set([sims[e.key] for e in cs.events if e.source == "i80"], 0, 1.0),
        "switch_s_median": _r(np.nanmedian([x.switch_s[i_th] for x in us_train + us_held]), 3),
        "draws": s.rule.draws,
    }
    prov = provenance(s)
    ci.write_events(s.assets / "cutins.json", cs, s.cutin, prov)
    idm["intrusion"] = {
        "rule": "a follower treats an intruder as its leader once the intruder's nearest edge is more than "
                "threshold_m inside the follower's lane (negative: before reaching the line); with probability "
                "1 - p_yield it reacts only once the intruder is entirely inside the lane",
        "threshold_m": rule.threshold, "p_yield": rule.p,
        "fit": {k: rule_out[k] for k in ("train", "heldout") if k in rule_out} | {
            "events": "assets/worlds/cutins.json (US-101, train split fits, val+test held out)",
            "objective": "squared distance of median fall-back curves, tau = 0.3..4.2 s"},
    }
    (s.assets / "idm.json").write_text(json.dumps(idm, indent=1) + "\n")
    res = {"settings": {"cutin": asdict(s.cutin), "rule": asdict(s.rule), "bootstrap": s.bootstrap},
           "taus": ci.TAUS.tolist(), "dropped": cs.dropped, "summary": summary, "rule": rule_out,
           "events": [{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in r.items()} for r in rows]}
    s.runs.mkdir(parents=True, exist_ok=True)
    (s.runs / "cutins.json").write_text(json.dumps(res, indent=1, default=float) + "\n")
    return res


def run_stage(stage: str, *, data_root: Path, runs: Path, assets: Path, doc: Path, figures: Path, seed: int,
              progress: bool) -> int:
    """Runs ``stage`` (``fit``, ``cutins``, ``report`` or ``all``) of ``nudge-train idm``; returns the
    exit status (2 with a message for missing or bad data)."""
    import sys
    import time

    from nudge_train.data.errors import DataError

    from .report import main_report
    from .sources import load_sources

    d = Settings()
    s = replace(d, data_root=data_root, runs=runs, assets=assets, doc=doc, figures=figures, seed=seed,
                fit=replace(d.fit, seed=seed), rule=replace(d.rule, seed=seed), progress=progress)
    t0 = time.perf_counter()
    try:
        sources = load_sources(s.data_root, s.progress) if stage in ("fit", "cutins", "all") else None
        if stage in ("fit", "all"):
            run_fit(s, sources)
        if stage in ("cutins", "all"):
            run_cutins(s, sources)
        if stage in ("report", "all"):
            main_report(s.runs, s.doc, s.figures)
    except (DataError, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{stage}: {time.perf_counter() - t0:.0f} s")
    return 0
