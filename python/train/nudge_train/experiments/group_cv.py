"""Planner settings chosen across scene groups: ``nudge-train group-cv``.

The closed-loop scenes of one overlap group share vehicles, so scenes are not independent and a
setting tuned on a few of them does not carry over. This command runs planner-settings arms on a
sample of the training and validation scenes, every world, paired with a base arm (same scene,
seed and target lane), and decides by groups:

* per arm, world and group: the paired difference of success (arm − base) with a normal 95 %
  interval over the runs (the seeds of one scene are treated as independent, which they are not
  quite, so the interval is somewhat narrow; :mod:`.stats` has the scene-clustered bootstrap),
  at-fault runs, the share of steps whose plan the ADMM decided, step time;
* **the rule**: an arm is eligible when it adds no at-fault run in any world; its score is its
  WORST group's paired success difference (the mean over worlds); the eligible arm with the best
  score is chosen, the base (score 0) when none scores above 0;
* **leave one group out**: for each group, the arm the rule picks from the other groups and its
  difference on the held-out one — how the choice carries to a group it never saw.

Arm records are ``nudge simulate`` folders (``OUT/<arm>/<predictor>-<world>``); a folder is
reused only when its ``outputs.sha256`` verifies and its ``provenance.json`` shows the same
scenes, runs, world, predictor and settings, so an interrupted job resumes where it stopped.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import random
import shutil
import subprocess
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nudge_train.errors import NudgeTrainError

__all__ = ["Arm", "ArmWorld", "GroupCvError", "SceneGroups", "group_deltas", "leave_one_group_out",
           "load_arm_world", "report", "run_arm", "sample_scenes", "select", "verified"]

WORLDS = ("teacher", "idm", "log_replay")
"""The worlds every arm runs in."""


class GroupCvError(NudgeTrainError, ValueError):
    """A scene, record folder or arm that the group cross-validation cannot use, named."""


@dataclass(frozen=True)
class SceneGroups:
    """Scene name prefix (``us101-<scene>_<variant>``) → overlap group, from the processed
    manifest's ``sources``."""

    of: dict[str, str]

    @classmethod
    def from_manifest(cls, manifest: Path) -> SceneGroups:
        data = json.loads(Path(manifest).read_text())
        of = {}
        for s in data.get("sources", []):
            scene, group = s.get("scene", ""), s.get("group", "")
            if group and scene.startswith("USA_US101-"):
                of["us101-" + scene.removeprefix("USA_US101-").removesuffix("_T-1")] = group
        if not of:
            raise GroupCvError(f"{manifest}: no US-101 source with an overlap group")
        return cls(of)

    def group(self, scenario: str) -> str:
        """The group of a closed-loop scenario name (``us101-2_1-t04.5-ego513``)."""
        prefix = "-".join(scenario.split("-")[:2])
        try:
            return self.of[prefix]
        except KeyError:
            raise GroupCvError(f"scenario {scenario!r}: its scene {prefix!r} has no overlap group") from None


def sample_scenes(folders: Sequence[Path], groups: SceneGroups, per_group: int, seed: int, out: Path) -> dict[str, int]:
    """Copies up to ``per_group`` scenario files of every group (drawn with ``seed`` from the
    sorted files of ``folders``) into ``out``; returns the count per group."""
    by_group: dict[str, list[Path]] = {}
    for folder in folders:
        for f in sorted(Path(folder).glob("*.safetensors")):
            by_group.setdefault(groups.group(f.stem), []).append(f)
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob("*.safetensors"):
        stale.unlink()
    rng = random.Random(seed)
    counts = {}
    for g in sorted(by_group):
        files = by_group[g]
        pick = sorted(rng.sample(files, min(per_group, len(files))))
        for f in pick:
            shutil.copyfile(f, out / f.name)
        counts[g] = len(pick)
    return counts


@dataclass(frozen=True)
class Arm:
    """A planner-settings arm: its name and settings (a partial settings object; {} = the
    defaults)."""

    name: str
    settings: dict


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _contains(full: dict, part: dict) -> bool:
    return all(k in full and (_contains(full[k], v) if isinstance(v, dict) else full[k] == v) for k, v in part.items())


def verified(folder: Path, args: Sequence[str], settings: dict, scenes: Path | None = None) -> bool:
    """Whether ``folder`` holds a complete record set of ``nudge simulate ARGS``: every file of
    its ``outputs.sha256`` present with that hash, its provenance's command (after the binary)
    equal to ``args``, its settings containing ``settings`` and, given ``scenes``, its runs
    covering exactly the scenario files there."""
    manifest = folder / "outputs.sha256"
    if not manifest.is_file():
        return False
    for line in manifest.read_text().splitlines():
        digest, _, name = line.partition("  ")
        f = folder / name
        if not f.is_file() or _sha256(f) != digest:
            return False
    try:
        prov = json.loads((folder / "provenance.json").read_text())
    except (OSError, json.JSONDecodeError):
        return False
    if list(prov.get("command", [])[1:]) != list(args) or not _contains(prov.get("settings", {}), settings):
        return False
    if scenes is None:
        return True
    with open(folder / "runs.csv", newline="") as f:
        ran = {r.get("scenario") for r in csv.DictReader(f)}
    return ran == {p.stem for p in Path(scenes).glob("*.safetensors")}


def _simulate_args(scenes: Path, runs: int, world: str, predictor: str, settings_file: Path | None,
                   out: Path) -> list[str]:
    args = ["simulate", "--scenes", str(scenes), "--runs", str(runs), "--world", world, "--predictor", predictor,
            "--threads", "1", "--no-progress", "--out", str(out)]
    if settings_file is not None:
        args[-2:-2] = ["--settings", str(settings_file)]
    return args


def run_arm(nudge: Path, arm: Arm, scenes: Path, runs: int, predictor: str, out: Path,
            log: Callable[[str], None] = print, worlds: Sequence[str] = WORLDS) -> None:
    """Runs ``arm`` in every world into ``out/<arm>/<predictor>-<world>`` (one thread per run,
    the worlds one after another), reusing each folder that :func:`verified` accepts."""
    root = out / arm.name
    root.mkdir(parents=True, exist_ok=True)
    settings_file = None
    if arm.settings:
        settings_file = root / "settings.json"
        settings_file.write_text(json.dumps(arm.settings, indent=1, sort_keys=True) + "\n")
    for world in worlds:
        folder = root / f"{predictor}-{world}"
        args = _simulate_args(scenes, runs, world, predictor, settings_file, folder)
        if verified(folder, args, arm.settings, scenes):
            log(f"{arm.name} {world}: verified records reused ({folder})")
            continue
        log(f"{arm.name} {world}: running {runs} seeds on {scenes}")
        done = subprocess.run([str(nudge), *args], capture_output=True, text=True, check=False)
        if done.returncode != 0:
            tail = " | ".join(done.stderr.strip().splitlines()[-3:]) or "no message"
            raise GroupCvError(f"arm {arm.name}, world {world}: nudge simulate exit status {done.returncode}: {tail}")


@dataclass
class ArmWorld:
    """One arm's runs in one world: per run (scenario, seed), success, an at-fault collision
    and the group; per step the share decided by the ADMM and the step times."""

    keys: list[tuple[str, int]]
    success: np.ndarray
    at_fault: np.ndarray
    groups: list[str]
    admm_share: float = math.nan
    step_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))


def load_arm_world(folder: Path, groups: SceneGroups) -> ArmWorld:
    """The runs (``runs.csv``) and steps (``steps.csv``) of one record folder."""
    try:
        with open(folder / "runs.csv", newline="") as f:
            runs = list(csv.DictReader(f))
    except OSError as err:
        raise GroupCvError(f"{folder}: no runs.csv ({err.strerror})") from None
    keys, success, at_fault, grp = [], [], [], []
    for i, r in enumerate(runs):
        try:
            keys.append((r["scenario"], int(r["seed"])))
            success.append(r["success"] == "true")
            at_fault.append(int(r["collisions_at_fault"] or 0) > 0)
        except (KeyError, ValueError) as err:
            raise GroupCvError(f"{folder / 'runs.csv'} row {i + 2}: {err}") from None
        grp.append(groups.group(r["scenario"]))
    aw = ArmWorld(keys, np.array(success), np.array(at_fault), grp)
    steps_file = folder / "steps.csv"
    if steps_file.is_file():
        with open(steps_file, newline="") as f:
            steps = list(csv.DictReader(f))
        if steps:
            aw.admm_share = sum(s["decided_by"] in ("admm", "admm_governed") for s in steps) / len(steps)
            aw.step_ms = np.array([1000.0 * float(s["mpc_s"]) for s in steps])
    return aw


def _interval(d: np.ndarray) -> tuple[float, float, float]:
    """Mean of ``d`` and its normal 95 % interval (NaN for no runs)."""
    n = d.size
    if n == 0:
        return (math.nan, math.nan, math.nan)
    m = float(d.mean())
    if n < 2:
        return (m, m, m)
    h = 1.96 * float(d.std(ddof=1)) / math.sqrt(n)
    return (m, m - h, m + h)


def _paired(base: ArmWorld, arm: ArmWorld) -> tuple[np.ndarray, list[str]]:
    """Success differences (arm − base) over the runs both have, and their groups."""
    where = {k: i for i, k in enumerate(base.keys)}
    d, g = [], []
    for j, k in enumerate(arm.keys):
        i = where.get(k)
        if i is not None:
            d.append(float(arm.success[j]) - float(base.success[i]))
            g.append(base.groups[i])
    if not d:
        raise GroupCvError("the arm and the base share no (scenario, seed) run")
    return np.array(d), g


def group_deltas(base: ArmWorld, arm: ArmWorld) -> dict[str, tuple[float, float, float, int]]:
    """Per group (and ``"all"``): the paired success difference (mean, 95 % interval) and the
    number of pairs."""
    d, g = _paired(base, arm)
    out = {"all": (*_interval(d), int(d.size))}
    for name in sorted(set(g)):
        sel = np.array([x == name for x in g])
        out[name] = (*_interval(d[sel]), int(sel.sum()))
    return out


Results = dict[str, dict[str, ArmWorld]]
"""arm name → world → its runs."""


def _score(base: dict[str, ArmWorld], arm: dict[str, ArmWorld], exclude: str | None = None,
           only: str | None = None) -> float:
    """The worst group's paired success difference, averaged over worlds (groups other than
    ``exclude``), or the difference on group ``only``."""
    per_group: dict[str, list[float]] = {}
    for w in arm:
        for g, (m, _, _, _) in group_deltas(base[w], arm[w]).items():
            if g != "all" and g != exclude and (only is None or g == only):
                per_group.setdefault(g, []).append(m)
    return min(float(np.mean(v)) for v in per_group.values())


def _eligible(base: dict[str, ArmWorld], arm: dict[str, ArmWorld], exclude: str | None = None) -> bool:
    """No world has more at-fault runs (outside group ``exclude``) than the base."""
    def count(aw: ArmWorld) -> int:
        return int(sum(f for f, g in zip(aw.at_fault, aw.groups) if g != exclude))
    return all(count(arm[w]) <= count(base[w]) for w in arm)


def select(results: Results, base: str, exclude: str | None = None) -> tuple[str, dict[str, float]]:
    """The rule: the eligible arm with the best worst-group score, the base when none scores
    above 0; with ``exclude``, decided without that group. Returns the choice and every arm's
    score (−∞ for an ineligible arm)."""
    scores = {base: 0.0}
    for name, arm in results.items():
        if name != base:
            ok = _eligible(results[base], arm, exclude)
            scores[name] = _score(results[base], arm, exclude) if ok else -math.inf
    best = max(scores, key=lambda n: (scores[n], n == base))
    return best, scores


def leave_one_group_out(results: Results, base: str) -> list[tuple[str, str, float]]:
    """For every group: the arm :func:`select` picks without it, and that arm's paired success
    difference on the held-out group (mean over worlds; 0 for the base)."""
    groups = sorted({g for aw in results[base].values() for g in aw.groups})
    rows = []
    for g in groups:
        choice, _ = select(results, base, exclude=g)
        held = 0.0 if choice == base else _score(results[base], results[choice], only=g)
        rows.append((g, choice, held))
    return rows


def _pct(x: float) -> str:
    return f"{100 * x:+.1f}"


def report(results: Results, base: str, command: str) -> str:
    """The markdown report: per arm and world the paired difference, at-fault runs, ADMM share and
    step time; per group the differences; the leave-one-group-out table and the choice."""
    lines = [f"Command: `{command}`", "",
             "| arm | world | pairs | success base → arm | paired Δ success (95 %) | worst group | at-fault runs "
             "base → arm | steps decided by the ADMM | step ms p50 / p99 / max |",
             "|---|---|---|---|---|---|---|---|---|"]
    b = results[base]
    for name, arm in results.items():
        if name == base:
            continue
        for w, aw in arm.items():
            d = group_deltas(b[w], aw)
            m, lo, hi, n = d["all"]
            worst = min((k for k in d if k != "all"), key=lambda k: d[k][0])
            t = aw.step_ms
            ms = f"{np.median(t):.1f} / {np.quantile(t, 0.99):.1f} / {t.max():.0f}" if t.size else "–"
            lines.append(f"| {name} | {w} | {n} | {100 * b[w].success.mean():.1f} → {100 * aw.success.mean():.1f} % | "
                         f"{_pct(m)} [{_pct(lo)}, {_pct(hi)}] pp | {worst} {_pct(d[worst][0])} | "
                         f"{int(b[w].at_fault.sum())} → {int(aw.at_fault.sum())} | "
                         f"{100 * b[w].admm_share:.1f} → {100 * aw.admm_share:.1f} % | {ms} |")
    groups = sorted({g for aw in b.values() for g in aw.groups})
    lines += ["", "Paired Δ success per group (pp, mean over the worlds; pairs per world):", "",
              "| arm | " + " | ".join(groups) + " |", "|---|" + "---|" * len(groups)]
    for name, arm in results.items():
        if name == base:
            continue
        cells = []
        for g in groups:
            ds = [group_deltas(b[w], arm[w])[g] for w in arm]
            cells.append(f"{_pct(float(np.mean([x[0] for x in ds])))} ({ds[0][3]})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    choice, scores = select(results, base)
    lines += ["", "Leave one group out (the arm the rule picks from the other groups, and its Δ on the held-out one):",
              "", "| held-out group | chosen without it | Δ success there (pp) |", "|---|---|---|"]
    lines += [f"| {g} | {c} | {_pct(x)} |" for g, c, x in leave_one_group_out(results, base)]
    shown = ", ".join(f"{n} {'ineligible' if s == -math.inf else _pct(s)}" for n, s in scores.items())
    lines += ["", f"Worst-group scores: {shown}. **Chosen: {choice}.**", ""]
    return "\n".join(lines)
