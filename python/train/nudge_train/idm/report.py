"""``nudge-train idm report``: docs/results/idm_fit.md and its two figures, from
``runs/idm/fit.json`` and ``runs/idm/cutins.json``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nudge_train.jsonio import load_json
from nudge_train.paths import repo_relative

from .fit import FIT_NAMES

METHODS = (("own_calibration", "own calibration (floor)"), ("plain_own_calibration", "own calibration, no prior"),
           ("pooled", "pooled, same source"), ("pooled_all_sources", "pooled, both sources"),
           ("population_mean", "random train driver (mean)"),
           ("plain_population_mean", "random train driver, no prior (mean)"),
           ("population_median_driver", "median train driver"), ("constant_speed", "constant speed"))
TAU_SHOW = (0.9, 1.8, 2.4, 3.0, 3.6, 4.2)
EARLIER = {1.8: -0.30, 3.0: -0.68, 4.2: -1.38}
"""An earlier measurement of the real followers' extra fall-back (m, n = 56) that this work re-measures."""


def _findings(fit: dict, cut: dict) -> list[str]:
    """Summary sentences computed from the results."""
    taus = [round(t, 1) for t in cut["taus"]]
    k = {t: taus.index(t) for t in (1.8, 3.0, 4.2)}
    out = []
    su, si = cut["summary"]["us101"], cut["summary"]["i80"]
    fb = si["fb_centre"]
    inside = all(fb[k[t]][1] <= v <= fb[k[t]][2] for t, v in EARLIER.items())
    out.append(f"- **Cut-ins**: {su['n_events']} on US-101 and {si['n_events']} on I-80 ({su['n_events'] + si['n_events']} "
               f"in all; {su['fb_centre'][-1][3] + si['fb_centre'][-1][3]} observed for the full 4.2 s).")
    out.append(f"- **I-80 followers** fall back {fb[k[1.8]][0]:+.2f} / {fb[k[3.0]][0]:+.2f} / {fb[k[4.2]][0]:+.2f} m at "
               f"1.8 / 3.0 / 4.2 s after the lane-ID jump (n = {fb[k[1.8]][3]}, {fb[k[3.0]][3]}, {fb[k[4.2]][3]}); the "
               f"earlier measurement ({EARLIER[1.8]:+.2f} / {EARLIER[3.0]:+.2f} / {EARLIER[4.2]:+.2f} m, n = 56) lies "
               f"{'inside' if inside else 'partly outside'} these 95 % intervals. Followers without a cut-in drift "
               f"{si['control']['median_ci'][k[4.2]][0]:+.2f} m by 4.2 s, so the I-80 curve is the reaction itself.")
    cu = su["control"]["median_ci"]
    out.append(f"- **US-101 followers** end up AHEAD of their constant-speed prediction ({su['fb_centre'][k[4.2]][0]:+.2f} m at "
               f"4.2 s) because the traffic of these short scenes speeds up: followers without a cut-in gain "
               f"{cu[k[4.2]][0]:+.2f} m. Net of that control the cut-in followers fall back "
               f"{su['fb_centre_net'][k[1.8]][0]:+.2f} / {su['fb_centre_net'][k[3.0]][0]:+.2f} / "
               f"{su['fb_centre_net'][k[4.2]][0]:+.2f} m (1.8 / 3.0 / 4.2 s), close to I-80.")
    ov = su["onset_overlap_m"]["median_ci"]
    out.append(f"- **When followers react** (US-101): {su['decelerating']} of {su['n_events']} brake noticeably; the "
               f"median onset comes when the intruder's nearest edge is {ov[0]:+.2f} m [{ov[1]:+.2f}, {ov[2]:+.2f}] "
               f"inside the lane, {su['onset_s']['median_ci'][0]:+.2f} s from the centre crossing.")
    r = cut["rule"]
    i80 = r["i80_at_lane_id_jump"]
    out.append(f"- **Intrusion rule**: threshold {r['threshold_m']:+.1f} m, p_yield {r['p_yield']:.1f}, fitted on "
               f"{r['train']['n']} US-101 train events; on the {r['heldout']['n']} held-out events its loss is "
               f"{r['heldout']['loss_m2']:.2f} m^2 against {r['heldout_edge_at_line']['loss_m2']:.2f} (edge at the line) "
               f"and {r['heldout_full_entry_only']['loss_m2']:.2f} (full entry only). Too few US-101 events for a "
               "precise threshold: the held-out set is small and the per-event spread is large (figure).")
    out.append(f"- **IDM over-reacts to close cut-ins**: replayed at the I-80 lane-ID jumps, the fitted drivers fall "
               f"back {i80['sim_median'][k[1.8]]:+.2f} / {i80['sim_median'][k[4.2]]:+.2f} m at 1.8 / 4.2 s where the real "
               f"followers fall back {i80['real_median'][k[1.8]]:+.2f} / {i80['real_median'][k[4.2]]:+.2f} m: real drivers "
               "accept a short gap for a while, IDM brakes to restore s* at once. A reactive world built on these "
               "drivers yields MORE than real traffic; results that depend on yielding must say so.")
    return out


def _ci(t: list) -> str:
    med, lo, hi, n = t
    if n == 0:
        return "–"
    return f"{med:+.2f} [{lo:+.2f}, {hi:+.2f}] ({n})"


def _figures(fit: dict, cut: dict, figdir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figdir.mkdir(parents=True, exist_ok=True)
    names = []
    bounds = fit["settings"]["fit"]["bounds"]
    fig, axes = plt.subplots(1, 5, figsize=(13, 2.6))
    for k, (ax, name) in enumerate(zip(axes, FIT_NAMES)):
        for src, col in (("i80", "C0"), ("us101", "C1")):
            v = [d["params"][k] for d in fit["drivers"] if d["source"] == src and d["split"] == "train"
                 and d["status"] == "ok"]
            ax.hist(v, bins=np.linspace(*bounds[k], 16), alpha=0.55, color=col, label=src)
        ax.set_title(name, fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7)
    fig.suptitle("IDM parameters of the train drivers (search box = plotted range)", fontsize=9)
    fig.tight_layout()
    p = figdir / "idm_fit_params.png"
    fig.savefig(p, dpi=80)
    plt.close(fig)
    names.append(p.name)

    taus = np.asarray(cut["taus"])
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    for ax, src in zip(axes[:2], ("us101", "i80")):
        s = cut["summary"][src]
        for meas, col, lab in (("fb_centre", "C3", "cut-in followers"), ("fb_centre_net", "C2", "minus control"),
                               ("fb_idm_old_leader", "C4", "vs IDM behind old leader")):
            if meas not in s:
                continue
            a = np.asarray([x[:3] for x in s[meas]])
            ax.plot(taus, a[:, 0], color=col, label=lab)
            ax.fill_between(taus, a[:, 1], a[:, 2], color=col, alpha=0.15)
        c = np.asarray([x[:3] for x in s["control"]["median_ci"]])
        ax.plot(taus, c[:, 0], color="grey", ls="--", label="followers without cut-in")
        ax.axhline(0, color="k", lw=0.5)
        ax.set(title=f"{src}: fall-back after the centre crossing (n={s['n_events']})", xlabel="tau (s)",
               ylabel="m")
        ax.title.set_fontsize(9)
        ax.legend(fontsize=7)
    r = cut["rule"]
    ax = axes[2]
    for key, col, lab in (("heldout", "C3", f"rule {r['threshold_m']:+.1f} m, p={r['p_yield']:.1f}"),
                          ("heldout_edge_at_line", "C0", "edge at line, p=1"),
                          ("heldout_full_entry_only", "C1", "full entry only")):
        ax.plot(taus, r[key]["sim_median"], color=col, label=f"IDM: {lab}")
    ax.plot(taus, r["heldout"]["real_median"], color="k", lw=2, label="real")
    ax.set(title=f"US-101 held-out cut-ins (n={r['heldout']['n']}): median fall-back", xlabel="tau (s)")
    ax.title.set_fontsize(9)
    ax.axhline(0, color="k", lw=0.5)
    ax.legend(fontsize=7)
    fig.tight_layout()
    p = figdir / "idm_cutins.png"
    fig.savefig(p, dpi=66)
    plt.close(fig)
    names.append(p.name)
    return names


def write_report(runs: Path, doc: Path, figdir: Path, runtime_note: str = "") -> Path:
    """Write the markdown report (and figures) from the stage results in ``runs``."""
    fit = load_json(runs / "fit.json")
    cut = load_json(runs / "cutins.json")
    figs = _figures(fit, cut, figdir)
    rel = Path("..") / "figures"
    L: list[str] = []
    a = L.append
    fs = fit["settings"]["fit"]
    a("# IDM car-following fitted to real NGSIM data, and real cut-ins\n")
    a("Generated by `nudge-train idm all` (stages `fit`, `cutins`, `report`); products: "
      "`assets/worlds/idm.json` (`nudge.idm/1`: the train driver population, pooled sets, the intrusion rule) "
      "and `assets/worlds/cutins.json` (`nudge.cutins/1`: the real cut-in events). "
      "Splits follow the data pipeline (US-101 by overlap group, I-80 by 60 s time block).\n")
    a("Reproduce from the repository root: `.venv/bin/nudge-train idm all` (data from "
      "`../shared/data/ngsim`, `--data-root` to change; seeded; per-driver fits are cached in `runs/idm/` and a "
      "rerun resumes). Measured on a 2-core machine shared with other jobs, one thread: about 16 min from "
      "scratch (two sets of about 460 per-driver fits, 9 and 5 min; pooled fits, cut-ins and rule fit 1.5 min), "
      "1.5 min with the fits cached.\n")
    if runtime_note:
        a(runtime_note + "\n")
    a("## Findings\n")
    L.extend(_findings(fit, cut))
    a("")
    a("## 1. Calibration\n")
    a(f"IDM with delta = {fs['delta']:g}; per follower, T, s0, a_max, b and v0/v_ref (v_ref = its highest "
      "logged speed) minimise the RMSE of the simulated bumper-to-bumper gap over the whole record, the follower "
      "starting in its logged state behind its logged leader (spacing-based calibration, the measure the "
      "calibration literature recommends over speed-based ones). Optimiser: scipy differential evolution "
      f"(population {fs['popsize']} x 5, at most {fs['maxiter']} generations, seeded per follower). "
      "Ballistic update at 0.1 s, deceleration floored at -9 m/s^2.\n")
    a(f"Plain least squares leaves most parameters of most drivers on a face of the box (the records, "
      "especially the 5-17 s US-101 ones, do not identify s0, b and v0 separately: the well-known "
      f"compensation between IDM parameters). The per-driver fits therefore add a weak prior: gap RMSE + "
      f"{fs['prior_weight']:g} m x sqrt(mean(z^2)), z = (parameters - the pooled set of the driver's source) / "
      "(box range), the pooled set being fitted on train records only. A parameter the record does not "
      "determine stays near the pooled value; one it does determine moves. Both versions are reported "
      "(\"no prior\").\n")
    a("Plausibility box (also the search box): " + ", ".join(
        f"{n} [{lo:g}, {hi:g}]" for n, (lo, hi) in zip(FIT_NAMES, fs["bounds"])) +
      f". A driver is a bad fit (excluded from the population) if its calibrated gap RMSE exceeds "
      f"{fs['max_rmse_gap']:g} m or its calibrated simulation collides.\n")
    a("| source | records | record length (s) median [min, max] | drivers train/val/test | ok / bad fit / collision | any parameter at a bound | same, no prior | train drivers in the population |")
    a("|---|---|---|---|---|---|---|---|")
    for src, c in fit["counts"].items():
        d, st, rs = c["drivers"], c["status"], c["record_s"]
        pl = c["plain"]
        a(f"| {src} | {c['pairs']} | {rs['median']} [{rs['min']}, {rs['max']}] | {d['train']}/{d['val']}/{d['test']} | "
          f"{st['ok']} / {st['bad_fit']} / {st['collision']} | {c['any_at_bound']} | {pl['any_at_bound']} "
          f"(bad fits {pl['status']['bad_fit']}) | {c['train_ok']} |")
    a("")
    a("Records dropped: " + "; ".join(f"{src}: " + (", ".join(f"{k} {v}" for k, v in c["pairs_dropped"].items()
                                                             if "shorter" not in k) or "none")
                                      for src, c in fit["counts"].items()) +
      ". (US-101 runs shorter than the minimum are not counted as drops: every lane-index flicker makes one.)\n")
    a("### Fitted population (train drivers with status ok): median [IQR]\n")
    a("| source | n | " + " | ".join(FIT_NAMES) + " |")
    a("|---|---|" + "---|" * len(FIT_NAMES))
    for src in ("i80", "us101", None):
        P = np.asarray([d["params"] for d in fit["drivers"] if d["split"] == "train" and d["status"] == "ok"
                        and (src is None or d["source"] == src)])
        q = np.percentile(P, [25, 50, 75], axis=0)
        a(f"| {src or 'both'} | {P.shape[0]} | " + " | ".join(f"{q[1, k]:.2f} [{q[0, k]:.2f}, {q[2, k]:.2f}]"
                                                              for k in range(len(FIT_NAMES))) + " |")
    a("")
    a("No prior (plain least squares), same drivers, median [IQR]: " + "; ".join(
        f"{src}: " + ", ".join(f"{n} {q[1]:.2f} [{q[0]:.2f}, {q[2]:.2f}]" for n, q in zip(FIT_NAMES, c["plain"]["iqr"]))
        for src, c in fit["counts"].items()) + ".\n")
    a("Parameters at a bound (all splits, lo / hi): " + "; ".join(
        f"{src}: " + ", ".join(f"{n} {v['lo']}/{v['hi']}" for n, v in c["at_bound"].items())
        for src, c in fit["counts"].items()) + ".\n")
    a(f"![parameters]({rel / figs[0]})\n")
    a("Pooled sets (one set fitted on all train records of a source): " + "; ".join(
        f"{k}: " + ", ".join(f"{n} {v:.2f}" for n, v in zip(FIT_NAMES, x)) for k, x in fit["pooled"].items()) + ".\n")
    a("### delta (pooled fits on train, gap RMSE on validation, median over records)\n")
    a("| source | " + " | ".join(f"delta = {d}" for d in next(iter(fit["delta_study"].values()))) + " |")
    a("|---|" + "---|" * len(next(iter(fit["delta_study"].values()))))
    for src, v in fit["delta_study"].items():
        a(f"| {src} | " + " | ".join(f"{x['val']['gap_rmse_median']:.2f} m" for x in v.values()) + " |")
    a("")
    a("### Error on held-out real car-following (per record; median / mean)\n")
    a("Whole-record simulation from the logged initial state behind the logged leader. \"own calibration\" is "
      "the held-out follower's own fit (what the model can do at best); the other rows use nothing of the "
      "held-out follower but its initial state and its v_ref.\n")
    a("| source/split (records) | method | gap RMSE (m) | speed RMSE (m/s) |")
    a("|---|---|---|---|")
    for key, m in fit["heldout"].items():
        n = m["pooled"]["n"]
        for mk, label in METHODS:
            if mk in m:
                x = m[mk]
                a(f"| {key} ({n}) | {label} | {x['gap_rmse_median']:.2f} / {x['gap_rmse_mean']:.2f} | "
                  f"{x['speed_rmse_median']:.2f} / {x['speed_rmse_mean']:.2f} |")
    a("")
    # Cut-ins
    a("## 2. Real cut-ins and the followers' reactions\n")
    cs = cut["settings"]["cutin"]
    a("A cut-in: a vehicle moves to the adjacent lane and, when its centre crosses the lane line, the nearest "
      f"vehicle behind it in the new lane (the follower, gap <= {cs['max_gap']:g} m) stays in that lane from "
      f"{cs['follower_before_s']:g} s before to at least {cs['follower_min_after_s']:g} s after. US-101 "
      f"(measured lateral motion; the intruder must move >= {cs['min_lateral_move']:g} m sideways within 1 s "
      "of the crossing; events repeated across scenes of one overlap group are kept once): centre and "
      "nearest-edge crossings. I-80 (Coifman & Li, longitudinal only): the frame of the Lane_ID jump. "
      "Fall-back fb(tau) = x_F(t0+tau) - x_F(t0) - v_F(t0) tau (negative = behind its constant-speed "
      "prediction). Medians with 95 % percentile-bootstrap intervals over events "
      f"({cut['settings']['bootstrap']} resamples), n in parentheses. Events dropped as repeats: "
      f"{sum(cut['dropped'].values())}.\n")
    a("| source | events | train/val/test | full 4.2 s horizon | gap at crossing (m) | time headway (s) | follower speed (m/s) | peak deceleration (m/s^2) | decelerating (onset found) |")
    a("|---|---|---|---|---|---|---|---|---|")
    for src in ("us101", "i80", "all"):
        s = cut["summary"][src]
        sp = s["splits"]
        full = s["fb_centre"][-1][3]
        a(f"| {src} | {s['n_events']} | {sp['train']}/{sp['val']}/{sp['test']} | {full} | "
          f"{_ci(s['gap_m']['median_ci'])} | {_ci(s['time_headway_s']['median_ci'])} | "
          f"{_ci(s['follower_speed_mps']['median_ci'])} | {_ci(s['peak_decel_mps2']['median_ci'])} | {s['decelerating']} |")
    a("")
    taus = [round(t, 1) for t in cut["taus"]]
    cols = [taus.index(t) for t in TAU_SHOW]
    a("### Fall-back (m) after the alignment time: median [95 % CI] (n)\n")
    a("| source | measure | " + " | ".join(f"{t} s" for t in TAU_SHOW) + " |")
    a("|---|---|" + "---|" * len(TAU_SHOW))
    rows = (("fb_centre", "vs constant speed, centre crossing"), ("fb_centre_full_horizon", "same, events with the full 4.2 s"),
            ("fb_edge", "vs constant speed, nearest-edge crossing"), ("fb_centre_net", "centre, minus the control median"),
            ("fb_idm_old_leader", "vs IDM (pooled) behind the old leader"))
    for src in ("us101", "i80", "all"):
        s = cut["summary"][src]
        for meas, label in rows:
            if meas in s:
                a(f"| {src} | {label} | " + " | ".join(_ci(s[meas][k]) for k in cols) + " |")
        if "control" in s:
            a(f"| {src} | control: followers without a cut-in ({s['control']['n']} samples) | " +
              " | ".join(_ci(s["control"]["median_ci"][k]) for k in cols) + " |")
    a("")
    us = cut["summary"]["us101"]
    a("### When does a follower start to brake? (US-101, measured lateral motion)\n")
    a(f"Deceleration onset = first time, from 2 s before the edge crossing to 2 s after the centre crossing, the "
      f"follower's acceleration (speed difference over {cs['accel_smooth_s']:g} s) stays {cs['onset_drop']:g} m/s^2 "
      f"below its mean over the second before that window for {cs['onset_hold_s']:g} s. Found for "
      f"{us['decelerating']} of {us['n_events']} US-101 followers; the intruder's nearest edge was then "
      f"{_ci(us['onset_overlap_m']['median_ci'])} m inside the lane (quartiles {us['onset_overlap_m']['quartiles']}), "
      f"at {_ci(us['onset_s']['median_ci'])} s from the centre crossing. The edge crosses the line "
      f"{_ci(us['edge_lead_s']['median_ci'])} s before the centre.\n")
    a("## 3. The intrusion rule of the IDM world\n")
    r = cut["rule"]
    a("Rule: a follower treats an intruder as its leader once the intruder's nearest edge is more than "
      "`threshold_m` inside its lane; with probability 1 - `p_yield` it reacts only when the intruder is "
      "entirely inside the lane. Fitted on the US-101 TRAIN cut-ins (each replayed with "
      f"{r['draws']} seeded drivers from the train population behind the real old leader and intruder): grid "
      "threshold x p_yield minimising the squared distance between the median simulated and median real "
      "fall-back curves (tau 0.3..4.2 s).\n")
    a(f"**Chosen: threshold_m = {r['threshold_m']:+.1f} m, p_yield = {r['p_yield']:.1f}** "
      f"(median switch {r['switch_s_median']:+.2f} s from the centre crossing).\n")
    a("Loss: the fit objective. Position RMSE: simulated minus real follower position at tau = 0.3..4.2 s, "
      "the simulation starting 2 s before the edge crossing (a check that does not use the fall-back reference).\n")
    a("| events | rule | loss (m^2) | position RMSE (m) | " + " | ".join(f"sim / real {t} s" for t in TAU_SHOW) + " |")
    a("|---|---|---|---|" + "---|" * len(TAU_SHOW))
    for key, label in (("train", "chosen"), ("heldout", "chosen"), ("heldout_edge_at_line", "edge at line, p = 1"),
                       ("heldout_full_entry_only", "full entry only"), ("i80_at_lane_id_jump", "at the Lane_ID jump")):
        x = r[key]
        if x.get("n", 0) == 0:
            continue
        name = {"train": "US-101 train", "i80_at_lane_id_jump": "I-80 (all)"}.get(key, "US-101 val+test")
        a(f"| {name} ({x['n']}) | {label} | {x['loss_m2']:.3f} | {x['position_rmse_m']:.2f} | " + " | ".join(
            f"{x['sim_median'][k]:+.2f} / {x['real_median'][k]:+.2f}" for k in cols) + " |")
    a("")
    a(f"![cut-ins]({rel / figs[1]})\n")
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text("\n".join(L) + "\n")
    return doc


def main_report(runs: Path, doc: Path, figdir: Path, runtime_note: str = "") -> None:
    p = write_report(runs, doc, figdir, runtime_note)
    print(f"wrote {repo_relative(p)}")
