"""`nudge-train data report`: docs/data.md and docs/figures/data_*.png from a processed build."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from nudge_train.artefacts import atomic_write_text
from nudge_train.constants import DT, OBS_LEN, SPLITS
from nudge_train.jsonio import load_json

from .errors import DataError
from .st_io import load_verified_shard

KIND_NAMES = {"commonroad": "US-101 (CommonRoad)", "coifman_block": "I-80 (Coifman & Li)", "raw_block": "raw NGSIM"}


def load_split(processed: Path, manifest: dict, split: str) -> dict[str, np.ndarray]:
    """Concatenate the shards of one split (offsets re-based), each checked against the sha256
    the manifest records for it."""
    mpath = processed / "manifest.json"
    parts = [load_verified_shard(mpath, s)[1] for s in manifest["splits"][split]["shards"]]
    if not parts:
        return {}
    out: dict[str, np.ndarray] = {}
    for k in parts[0]:
        if k == "offsets":
            base = 0
            offs = [np.asarray([0])]
            for p in parts:
                offs.append(p["offsets"][1:] + base)
                base += int(p["offsets"][-1])
            out[k] = np.concatenate(offs)
        else:
            out[k] = np.concatenate([p[k] for p in parts])
    return out


def window_stats(d: dict[str, np.ndarray], kinds: np.ndarray) -> dict[str, dict[str, np.ndarray]]:
    """Per source kind: agents per window, speeds (m/s, last observed step, all agents), space
    gaps (m, bumper to bumper, to the nearest agent ahead within 1.8 m laterally) and time
    headways (s)."""
    offs = d["offsets"]
    pos = d["positions"]
    size = d["size"]
    res: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for w in range(offs.shape[0] - 1):
        a, b = int(offs[w]), int(offs[w + 1])
        k = str(kinds[int(d["source"][w])])
        r = res[k]
        r["n_agents"].append(b - a)
        p = pos[a:b]
        v = np.linalg.norm(p[:, OBS_LEN - 1] - p[:, OBS_LEN - 2], axis=1) / DT
        r["speed"].append(v)
        x, y = p[:, OBS_LEN - 1, 0], p[:, OBS_LEN - 1, 1]
        dx = x[None, :] - x[:, None]
        dy = np.abs(y[None, :] - y[:, None])
        ahead = (dx > 0) & (dy < 1.8)
        dxm = np.where(ahead, dx, np.inf)
        j = np.argmin(dxm, axis=1)
        has = np.isfinite(dxm[np.arange(b - a), j])
        gap = dxm[np.arange(b - a), j] - 0.5 * (size[a:b, 0] + size[a:b, 0][j])
        gap = gap[has]
        r["gap"].append(gap)
        vv = v[has]
        r["thw"].append(np.where(vv > 1.0, gap / np.maximum(vv, 1e-6), np.nan))
    out: dict[str, dict[str, np.ndarray]] = {}
    for k, r in res.items():
        out[k] = {"n_agents": np.asarray(r["n_agents"])}
        for key in ("speed", "gap", "thw"):
            arr = np.concatenate(r[key]) if r[key] else np.zeros(0)
            out[k][key] = arr[np.isfinite(arr)]
    return out


def _legacy_rule(reason: str) -> str:
    """The rule of an exclusion recorded by a build that wrote only the reason text."""
    if reason.startswith("criticality-modified"):
        return "criticality_modified"
    if reason.startswith("variant of scene"):
        return "duplicate_variant"
    return reason


def drop_table(manifest: dict) -> list[str]:
    """Markdown lines: everything the build dropped or decided, by reason, with counts: source
    files excluded (per rule), split decisions, rows dropped by the readers, windows and agents
    dropped by the window filters (all splits)."""
    counts: dict[tuple[str, str], int] = defaultdict(int)
    tables_seen: set[tuple[str, str]] = set()
    for src in manifest["sources"]:
        rule = src.get("rule") or _legacy_rule(src.get("reason", ""))
        if src["split"] == "excluded":
            counts[("source excluded", rule)] += 1
        elif src.get("rule"):
            counts[("split decision", rule)] += 1
        table = (src["name"].split("#")[0], src.get("scene", ""))  # time blocks share their table's notes
        if table in tables_seen:
            continue
        tables_seen.add(table)
        for k, v in (src.get("reader_notes") or {}).items():
            if k.endswith("_dropped") and v:
                counts[("rows dropped by a reader", k)] += int(v)
    for sp in manifest["splits"].values():
        for k, v in sp["windows_dropped"].items():
            counts[("window dropped", k)] += int(v)
        for k, v in sp["agents_dropped"].items():
            counts[("agent dropped", k)] += int(v)
    lines = ["", "## Everything dropped, by reason", "",
             "Source files excluded (US-101: criticality-modified or duplicate variants, scenes without an "
             "overlap-group row, files that are no benchmark scene), split decisions (fewer than 3 independent "
             "groups: every unit to test), rows the readers dropped, windows and agents the filters dropped:", "",
             "| stage | reason | count |", "|---|---|---|"]
    lines += [f"| {stage} | {reason} | {n} |" for (stage, reason), n in sorted(counts.items())]
    if not counts:
        lines.append("| - | nothing dropped | 0 |")
    return lines


def _shown(path: Path) -> str:
    """``path`` relative to the working directory when inside it (stable across machines)."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return path.name


def _q(a: np.ndarray) -> str:
    if a.size == 0:
        return "-"
    q = np.percentile(a, [5, 25, 50, 75, 95])
    return " / ".join(f"{v:.1f}" for v in q)


def scenes_table(scenes_root: Path) -> list[str]:
    """Markdown lines: planner scenarios per split as ``nudge-train data scenes`` recorded them
    (``<scenes_root>/<split>/summary.json``): scenarios, merge scenarios (ego in a lane that ends
    ahead), candidates dropped per reason. Empty when no split's scenarios were written."""
    rows = []
    for s in SPLITS:
        path = scenes_root / s / "summary.json"
        if not path.exists():
            continue
        sm = load_json(path)
        dropped = ", ".join(f"{k}: {v}" for k, v in sm.get("candidates_dropped", {}).items()) or "none"
        rows.append(f"| {s} | {sm.get('road_frame', 'straightened')} | {sm['scenarios']} | {sm['merge_scenarios']} | "
                    f"{sm.get('ramp_scenarios', 0)} | {dropped} |")
    if not rows:
        return []
    return ["", "## Planner scenarios per split", "",
            "Written by `nudge-train data scenes --split <split>` (one scenario per ego and last observed step "
            "on the 0.3 s grid, neighbours within 60 m). A *merge scenario* has its ego, at the last observed "
            "step, in a lane that ends ahead inside the scene (an on-ramp's acceleration lane or an auxiliary "
            "lane; only the curvilinear frame knows lane ends); an *on-ramp scenario* has it in a lane that "
            "begins inside the scene (joined from an on-ramp; on US-101 it runs on as the auxiliary lane). "
            "Candidates dropped: `ego_history_incomplete` / "
            "`ego_future_short` (the ego lacks 8 observed or 6 future steps), `lanes_not_straight` (lanes off "
            "d = const by more than 0.6 m within 100 m of the ego), `agent_off_road` (an agent observed more "
            "than 2 m outside the road edges at the ego's position: still on an on-ramp that joins ahead, or "
            "already on an exit ramp; the planner's scenario loader refuses such a file), `lanes_unmatched` (a lane at the ego "
            "matches no lane extent).", "",
            "| split | road frame | scenarios | merge scenarios | on-ramp scenarios | candidates dropped (reason: n) |",
            "|---|---|---|---|---|---|", *rows]


def write_report(processed: Path, doc: Path, figures: Path, scenes_root: Path | None = None) -> None:
    """Write the dataset report for the build in ``processed`` (planner scenario counts from
    ``scenes_root``, default ``processed/scenes``, where written)."""
    mpath = processed / "manifest.json"
    if not mpath.exists():
        raise DataError(mpath, "no manifest.json: run `nudge-train data build` first")
    manifest = load_json(mpath)
    sources = manifest["sources"]
    kinds = np.asarray([s["kind"] for s in sources])
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures.mkdir(parents=True, exist_ok=True)
    doc.parent.mkdir(parents=True, exist_ok=True)
    stats: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for s in SPLITS:
        d = load_split(processed, manifest, s)
        stats[s] = window_stats(d, kinds) if d else {}
    L: list[str] = []
    cfg = manifest["config"]
    w = cfg["window"]
    L += ["# nudge dataset report", "",
          "Generated by `nudge-train data report` from `" + _shown(processed) + "/manifest.json` "
          f"(schema `{manifest['schema']}`; shards `{manifest['windows_schema']}`, see "
          "[data_schema.md](data_schema.md)). Do not edit by hand.", "",
          f"Build: seed {cfg['seed']}, phases {cfg['phases']} (window starts every 0.1 s when all three), "
          f"{w['n_obs']} observed + {w['n_fut']} future steps of {w['step_s']} s, "
          f"at most {w['max_agents']} agents per window; {manifest['counts']['windows']} windows, "
          f"{manifest['counts']['agents']} agent tracks.", "",
          f"Road frame of the US-101 scenes: `{cfg.get('road_frame', 'straightened')}`.", "",
          "Reproduce (from the repository root; about a minute on 2 cores, byte-identical on rerun, "
          "sha256 of every shard in the manifest):", "", "```sh",
          "nudge-train data build                 # ../shared/data/ngsim -> data/processed/",
          "nudge-train data scenes --split train  # all scenarios of a split -> data/processed/scenes/<split>/",
          "nudge-train data scenes --split val",
          "nudge-train data scenes --split test",
          "nudge-train data report                # -> docs/data.md, docs/figures/data_*.png",
          "```", ""]
    # Windows per split and source kind.
    agg: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0, 0, 0, 0, 0])
    for src in sources:
        if "windows" not in src:
            continue
        a = agg[(src["split"], src["kind"])]
        a[0] += src["windows"]
        a[1] += src["agents"]
        a[2] += src["interactive"]
        a[3] += src["lane_changing_agents"]
        a[4] += 1
        a[5] += src.get("merge_windows", 0)
    L += ["## Windows per split and source", "",
          "| split | source | units | windows | agents | interactive windows | interactive share | lane-changing agents "
          "| merge windows |",
          "|---|---|---|---|---|---|---|---|---|"]
    for s in SPLITS:
        tot = [0, 0, 0, 0, 0, 0]
        for k in KIND_NAMES:
            if (s, k) not in agg:
                continue
            a = agg[(s, k)]
            tot = [x + y for x, y in zip(tot, a)]
            L.append(f"| {s} | {KIND_NAMES[k]} | {a[4]} | {a[0]} | {a[1]} | {a[2]} | {a[2] / max(a[0], 1):.1%} | {a[3]} "
                     f"| {a[5]} |")
        L.append(f"| **{s}** | all | {tot[4]} | **{tot[0]}** | {tot[1]} | {tot[2]} | **{tot[2] / max(tot[0], 1):.1%}** "
                 f"| {tot[3]} | **{tot[5]}** |")
    total_w = sum(a[0] for a in agg.values())
    i80_w = sum(a[0] for (s, k), a in agg.items() if k == "coifman_block")
    us_w = sum(a[0] for (s, k), a in agg.items() if k == "commonroad")
    L += ["", f"US-101 contributes {us_w} windows, I-80 {i80_w} ({i80_w / max(total_w, 1):.1%} of all). "
          "Units are US-101 scenes (one CommonRoad file each) and 60 s I-80 time blocks. A window is "
          "*interactive* when at least one of its agents changes lane (lane index differs between the "
          "first and last of the 14 steps and the agent moved at least "
          f"{w['lane_change_min_dy']} m laterally), which includes on-ramp merges. I-80 lateral motion is "
          "derived from lane numbers (lane changes interpolated over 4 s), so its lane changes are real "
          "but their lateral shape is not. A *merge window* has an agent that, at the last observed step, is "
          "in a lane that ends ahead inside the scene (an on-ramp's acceleration lane or an auxiliary lane; "
          "only the curvilinear frame knows lane ends, so 0 in a straightened build and on I-80).", ""]
    # Splits.
    L += ["## Splits", "", "US-101 by `overlap_group` (scenes sharing vehicles stay together), I-80 by "
          "contiguous 60 s time blocks; seeded (seed in the build config), target 20 % test, then 10 % "
          "of the rest for validation, measured in window starts. Every source file's fate, with the "
          "*residual* of the road frame's mapping (US-101: worst deviation of a lane boundary from a line of "
          "constant lateral position, m, within each lane's extent in the curvilinear frame):", "",
          "| source | group | split | windows | interactive | merge windows | residual (m) | note |",
          "|---|---|---|---|---|---|---|---|"]
    for src in sources:
        cm = (src.get("reader_notes") or {}).get("lane_straightness_cm")
        res = "-" if cm is None else f"{cm / 100:.2f}"
        L.append(f"| {src['name']} | {src['group'] or '-'} | {src['split']} | {src.get('windows', '-')} | "
                 f"{src.get('interactive', '-')} | {src.get('merge_windows', '-')} | {res} | {src.get('reason', '')} |")
    # Filters.
    L += ["", "## What the filters dropped", "",
          f"Agents present in all 14 steps are kept unless a rule fires: speed > {w['max_speed']} m/s or "
          f"moving backwards faster than {-w['min_forward_speed']} m/s; |acceleration| > {w['max_accel']} m/s^2; "
          f"|jerk| > {w['max_jerk']} m/s^3 (finite differences at 0.3 s); boxes overlapping "
          f"(road-frame boxes shrunk to {w['overlap_shrink']:.0%}; the agent farther from the ego is dropped); "
          f"beyond the {w['max_agents']} agents nearest to the ego. A window with fewer than 2 agents left is dropped.", "",
          "| split | candidate windows | kept | windows dropped (rule: n) | agents dropped (rule: n) |",
          "|---|---|---|---|---|"]
    for s in SPLITS:
        sp = manifest["splits"][s]
        wd = ", ".join(f"{k}: {v}" for k, v in sp["windows_dropped"].items()) or "none"
        ad = ", ".join(f"{k}: {v}" for k, v in sp["agents_dropped"].items()) or "none"
        L.append(f"| {s} | {sp['candidates']} | {sp['windows']} | {wd} | {ad} |")
    L += drop_table(manifest)
    L += scenes_table(scenes_root if scenes_root is not None else processed / "scenes")
    # Distributions.
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    all_by_kind: dict[str, dict[str, list[np.ndarray]]] = defaultdict(lambda: defaultdict(list))
    for s in SPLITS:
        for k, r in stats[s].items():
            for key, arr in r.items():
                all_by_kind[k][key].append(arr)
    merged = {k: {key: np.concatenate(v) for key, v in r.items()} for k, r in all_by_kind.items()}
    for k in sorted(merged):
        r = merged[k]
        axes[0].hist(r["n_agents"], bins=np.arange(0.5, 48.5, 1), alpha=0.6, label=KIND_NAMES.get(k, k))
        axes[1].hist(r["speed"], bins=np.linspace(0, 35, 71), alpha=0.6, density=True, label=KIND_NAMES.get(k, k))
        axes[2].hist(np.clip(r["thw"], 0, 6), bins=np.linspace(0, 6, 61), alpha=0.6, density=True,
                     label=KIND_NAMES.get(k, k))
    axes[0].set_xlabel("agents per window")
    axes[0].set_ylabel("windows")
    axes[1].set_xlabel("speed at last observed step (m/s)")
    axes[2].set_xlabel("time headway to leader (s, clipped at 6)")
    if merged:  # an empty build (every source excluded) has nothing to label
        for ax in axes:
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(figures / "data_distributions.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 3.4))
    for i, s in enumerate(SPLITS):
        sp = manifest["splits"][s]
        ax.bar(i - 0.2, sp["windows"], width=0.4, color="tab:blue", label="windows" if i == 0 else None)
        ax.bar(i + 0.2, sp["interactive"], width=0.4, color="tab:orange", label="interactive" if i == 0 else None)
    ax.set_xticks(range(3), SPLITS)
    ax.legend()
    fig.tight_layout()
    fig.savefig(figures / "data_splits.png", dpi=110)
    plt.close(fig)
    L += ["", "## Distributions", "", "![windows per split](figures/data_splits.png)", "",
          "![agents per window, speed, headway](figures/data_distributions.png)", "",
          "Quantiles 5 / 25 / 50 / 75 / 95 %, all splits:", "",
          "| source | agents per window | speed (m/s) | gap to leader (m) | time headway (s) |", "|---|---|---|---|---|"]
    for k in sorted(merged):
        r = merged[k]
        L.append(f"| {KIND_NAMES.get(k, k)} | {_q(r['n_agents'])} | {_q(r['speed'])} | {_q(r['gap'])} | {_q(r['thw'])} |")
    L += ["", "Agents-per-window histogram (windows with n agents, all splits):", "",
          "| source | " + " | ".join(["2-4", "5-8", "9-16", "17-32", "33-47"]) + " |", "|---|---|---|---|---|---|"]
    for k in sorted(merged):
        n = merged[k]["n_agents"]
        bins = [(2, 4), (5, 8), (9, 16), (17, 32), (33, 47)]
        L.append(f"| {KIND_NAMES.get(k, k)} | " + " | ".join(str(int(((n >= a) & (n <= b)).sum())) for a, b in bins) + " |")
    # Reader notes.
    L += ["", "## Reader notes (per source, from the readers)", ""]
    seen = set()
    for src in sources:
        notes = src.get("reader_notes")
        if not notes or src["kind"] == "commonroad":
            continue
        key = (src["kind"], json.dumps(notes, sort_keys=True))
        if key in seen:
            continue
        seen.add(key)
        L.append(f"- {src['name'].split('#')[0]}: " + ", ".join(f"{k} = {v}" for k, v in notes.items()))
    if cfg.get("road_frame", "straightened") == "frenet":
        L.append("- US-101 CommonRoad: curvilinear road frame per scene (arclength and offset along a spline "
                 "fitted to the lanelets, rotation in reader_notes of manifest.json as rotation_mrad, lanes that "
                 "begin and end inside the scene as lanes_beginning / lanes_ending; see "
                 "[results/road_frame.md](results/road_frame.md)).")
    else:
        L.append("- US-101 CommonRoad: frame rotated and straightened per scene (rotation in reader_notes of "
                 "manifest.json as rotation_mrad).")
    L.append("")
    atomic_write_text(doc, "\n".join(L))
