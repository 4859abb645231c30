"""Where does a logged vehicle go once its log ends? The log-replay world's extrapolation,
fitted to real tracks.

The log-replay world (``World::LogReplay``) moves every other vehicle along its logged future;
where a log ends before the run does, the vehicle is extrapolated step by step
(``nudge_sim::world::logged_position``): its last displacement along the road is
repeated, and a fraction ρ (``SimConfig::replay_lateral_decay``) of its last displacement across
it, so that k steps past the log's end it has moved

    Δy · (ρ + ρ² + … + ρᵏ)        (k · Δy at ρ = 1, 0 at ρ = 0)

sideways, Δy being its last observed sideways displacement per 0.3 s step. ρ = 1 is constant
velocity; ρ = 0 holds the lateral position.

This experiment measures that rule on real NGSIM tracks. Every other vehicle of every scene of
a split gives one anchor: its last two observed positions (the end of the scene's history) play
the log's end, and its real logged positions 1…``horizon`` steps later are the truth. ρ is
chosen on the training split by least squares over a grid; the validation and test splits
report the lateral error of that choice against constant velocity and a held lateral position.
The shipped default must be the fitted value; the report says so or says that it is not.

Command: ``nudge-train replay-extrapolation`` (writes ``docs/results/replay_extrapolation.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from safetensors.numpy import load_file
from tqdm import tqdm

from nudge_train.data.errors import DataError

HORIZON = 24
"""Steps past the anchor that are scored (24 × 0.3 s = 7.2 s: a whole 30-step run can outlast a
log by this much, the shortest logs being 6 steps)."""

GRID = tuple(round(0.05 * i, 2) for i in range(21))
"""The candidate values of ρ: 0, 0.05, …, 1."""

DT = 0.3
"""Step length (s)."""


@dataclass(frozen=True)
class Pairs:
    """(anchor, horizon) pairs of one split, flat arrays of equal length.

    ``dy``: the anchor's last sideways displacement (m per step); ``k``: steps past the anchor
    (1…horizon); ``truth``: the real sideways displacement from the anchor's last position to
    its logged position k steps later (m)."""

    dy: np.ndarray
    k: np.ndarray
    truth: np.ndarray
    scenes: int
    anchors: int
    log_steps: np.ndarray
    """Logged future steps of each scene (``future``'s second dimension)."""


def pairs(scene_dir: Path, horizon: int = HORIZON, progress: bool = True) -> Pairs:
    """Every other vehicle (agent ≥ 1) of every ``*.safetensors`` scene in ``scene_dir``,
    scored at each future step up to ``horizon`` until its first invalid one.

    Raises :class:`DataError` naming the file when a scene lacks ``history``, ``future`` or
    ``future_valid``, or their shapes disagree, or a position that is scored is not finite."""
    files = sorted(Path(scene_dir).glob("*.safetensors"))
    if not files:
        raise DataError(scene_dir, "no scene files (*.safetensors)")
    dy_all, k_all, truth_all = [], [], []
    anchors = 0
    log_steps = []
    for f in tqdm(files, desc=f"tracks {Path(scene_dir).name}", disable=not progress, unit="scene"):
        d = load_file(str(f))
        for key in ("history", "future", "future_valid"):
            if key not in d:
                raise DataError(f, f"no tensor {key!r}", field=key)
        h, fu, fv = d["history"], d["future"], d["future_valid"].astype(bool)
        if h.ndim != 3 or h.shape[2] != 2 or h.shape[1] < 2 or fu.shape[:1] != h.shape[:1] \
                or fu.ndim != 3 or fu.shape[2] != 2 or fv.shape != fu.shape[:2]:
            raise DataError(f, f"history {h.shape}, future {fu.shape}, future_valid {fv.shape} disagree",
                            field="future")
        steps = min(horizon, fu.shape[1])
        log_steps.append(fu.shape[1])
        for i in range(1, h.shape[0]):
            # Scored steps: the valid prefix of the logged future.
            n = int(np.argmin(fv[i, :steps])) if not fv[i, :steps].all() else steps
            if n == 0:
                continue
            a, b = h[i, -2], h[i, -1]
            ys = fu[i, :n, 1]
            if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(ys).all()):
                raise DataError(f, f"agent {i}: a non-finite position in its last history or scored future",
                                field="future")
            anchors += 1
            dy_all.append(np.full(n, b[1] - a[1]))
            k_all.append(np.arange(1, n + 1))
            truth_all.append(ys - b[1])
    if not dy_all:
        raise DataError(scene_dir, "no vehicle with a logged future")
    return Pairs(np.concatenate(dy_all), np.concatenate(k_all), np.concatenate(truth_all), len(files), anchors,
                 np.array(log_steps))


def lateral_offset(dy: np.ndarray, k: np.ndarray, rho: float) -> np.ndarray:
    """Δy·(ρ + … + ρᵏ): the sideways displacement k steps past a log's end under decay ρ (m)."""
    if not 0.0 <= rho <= 1.0:
        raise ValueError(f"rho: must be in [0, 1], got {rho}")
    k = np.asarray(k, dtype=float)
    if rho == 1.0:
        return dy * k
    return dy * rho * (1.0 - rho ** k) / (1.0 - rho)


def rmse(p: Pairs, rho: float, k: int | None = None) -> float:
    """Root-mean-square lateral error (m) of decay ρ over all pairs, or over those at step k."""
    e = p.truth - lateral_offset(p.dy, p.k, rho)
    if k is not None:
        e = e[p.k == k]
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


def fit(p: Pairs, grid: tuple[float, ...] = GRID) -> float:
    """The ρ of ``grid`` with the least RMSE over ``p`` (the smallest such ρ on a tie)."""
    errors = [rmse(p, r) for r in grid]
    return grid[int(np.argmin(errors))]


def _cell(x: float) -> str:
    return "–" if not np.isfinite(x) else f"{x:.3f}"


def report(train: Pairs, held_out: dict[str, Pairs], default: float, run_steps: int = 30) -> tuple[float, str]:
    """The fitted ρ and the markdown page (``run_steps``: the closed loop's step budget)."""
    rho = fit(train)
    splits = [("train (fit)", train), *held_out.items()]
    best = all(
        rmse(p, rho, k) <= min(rmse(p, 0.0, k), rmse(p, 1.0, k))
        for _, p in splits for k in range(1, HORIZON + 1) if np.isfinite(rmse(p, rho, k))
    )
    ks = [k for k in (1, 2, 3, 6, 10, 16, 24) if k <= HORIZON]
    lines = [
        "# Log replay past the end of a log: where real vehicles went",
        "",
        "Generated by `nudge-train replay-extrapolation`.",
        "",
        "In the log-replay world a vehicle whose log ends before the run does is extrapolated",
        "step by step (`nudge_sim::world::logged_position`): its last displacement along",
        "the road is repeated, and a fraction ρ (`SimConfig::replay_lateral_decay`) of its last",
        "displacement across it, so that k steps past the log's end it has moved Δy·(ρ + … + ρᵏ)",
        "sideways. ρ = 1 is constant velocity; ρ = 0 holds its lateral position.",
        "",
        "**Data.** Every other vehicle of every scene of a split is one anchor: its last two",
        "observed positions play the end of a log, and its real logged positions 1 to "
        f"{HORIZON} steps ({HORIZON * DT:.1f} s) later, up to its first missing one, are the truth.",
        "All scenes are US-101, whose lateral positions are measured.",
        "",
        f"**Fit.** ρ is the value of the grid 0, 0.05, …, 1 with the least lateral RMSE over the "
        f"training split's pairs: **ρ = {rho:.2f}** (a time constant of "
        f"{-DT / np.log(rho) if 0 < rho < 1 else float('nan'):.2f} s). "
        + (f"The shipped default `replay_lateral_decay` = {default:.2f} is this value."
           if abs(rho - default) < 1e-12 else
           f"**The shipped default `replay_lateral_decay` = {default:.2f} is not this value.**"),
        "",
        "Lateral RMSE (m) by steps past the anchor, and over all pairs:",
        "",
        "| split | scenes | anchors | pairs | ρ | " + " | ".join(f"k = {k} ({k * DT:.1f} s)" for k in ks)
        + " | all |",
        "|" + "---|" * (6 + len(ks)),
    ]
    for name, p in [("train (fit)", train), *held_out.items()]:
        for r, label in ((0.0, "0 (held)"), (rho, f"{rho:.2f} (fitted)"), (1.0, "1 (constant velocity)")):
            cells = " | ".join(_cell(rmse(p, r, k)) for k in ks)
            lines.append(f"| {name} | {p.scenes} | {p.anchors} | {p.k.size} | {label} | {cells} | {rmse(p, r):.3f} |")
    lines += [
        "",
        "(– : no scene of the split logs that far.)",
        "",
        "**Reading it.** "
        + ("The fitted ρ has the least error of the three at every horizon from 1 to "
           f"{HORIZON} steps on every split. " if best else
           "The fitted ρ does **not** have the least error of the three at every horizon on every split. ")
        + "Constant velocity's error grows about linearly with the horizon, because a vehicle's "
        "sideways displacement over one step is mostly a wobble within its lane, not a lane change "
        "that goes on: a driver wobbling towards the ego when its log ended would keep crossing the "
        "road for the rest of the run.",
        "",
        f"**How much of a run is past a log.** A run lasts up to {run_steps} steps; scenes whose "
        "logged future is shorter:",
        "",
        "| split | scenes | log shorter than a run | logged steps, min / median |",
        "|---|---|---|---|",
    ]
    for name, p in splits:
        short = int((p.log_steps < run_steps).sum())
        lines.append(f"| {name} | {p.scenes} | {short} ({100 * short / p.scenes:.0f} %) | "
                     f"{int(p.log_steps.min())} / {int(np.median(p.log_steps))} |")
    lines.append("")
    return rho, "\n".join(lines)


def run(scenes_root: Path, out: Path | None, progress: bool = True) -> int:
    """Fits ρ on ``scenes_root/train``, reports on ``val`` and ``test``; writes ``out`` (when
    given) and prints the page. Returns 0 when the shipped default is the fitted value, 1 when
    it is not."""
    import nudge

    train = pairs(scenes_root / "train", progress=progress)
    held = {split: pairs(scenes_root / split, progress=progress) for split in ("val", "test")
            if (scenes_root / split).is_dir()}
    default = float(nudge.SimConfig.default().replay_lateral_decay)
    rho, page = report(train, held, default, int(nudge.SimConfig.default().max_steps))
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(page)
    print(page)
    return 0 if abs(rho - default) < 1e-12 else 1
