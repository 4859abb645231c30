"""Settings chosen across scene groups: the group of a scenario from the real manifest, paired
differences per group against hand-computed values, the worst-group rule and leave-one-group-out
on constructed arms whose right answer is known, and the resume check on record folders."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from nudge_train import paths
from nudge_train.experiments import group_cv as cv


def _groups() -> cv.SceneGroups:
    return cv.SceneGroups({"us101-2_1": "g2", "us101-12_1": "g11", "us101-3_1": "g3"})


def _arm(success: dict[str, list[int]], at_fault: dict[str, list[int]] | None = None) -> cv.ArmWorld:
    """Runs of scenes ``<prefix>-tX-egoN`` (seed 0..): per group prefix the successes in order."""
    keys, s, f, g = [], [], [], []
    groups = _groups()
    for prefix, xs in success.items():
        for i, x in enumerate(xs):
            name = f"{prefix}-t0{i}.0-ego{i}"
            keys.append((name, 0))
            s.append(bool(x))
            f.append(bool((at_fault or {}).get(prefix, [0] * len(xs))[i]))
            g.append(groups.group(name))
    return cv.ArmWorld(keys, np.array(s), np.array(f), g)


def test_real_scene_names_map_to_their_overlap_groups() -> None:
    manifest = paths.processed() / "manifest.json"
    if not manifest.is_file():
        pytest.skip("no processed manifest")
    groups = cv.SceneGroups.from_manifest(manifest)
    assert groups.group("us101-2_1-t04.5-ego513") == "us101-group-02"
    assert groups.group("us101-12_1-t02.1-ego290") == "us101-group-11"
    # Scenes 4, 18 and 27 share vehicles: one group.
    assert {groups.group(f"us101-{n}_1-t01.0-ego1") for n in (4, 18, 27)} == {"us101-group-04"}
    with pytest.raises(cv.GroupCvError, match="us101-99_1"):
        groups.group("us101-99_1-t01.0-ego1")


def test_paired_differences_per_group_match_hand_computation() -> None:
    base = _arm({"us101-2_1": [1, 1, 0, 0], "us101-12_1": [1, 0]})
    arm = _arm({"us101-2_1": [1, 0, 1, 1], "us101-12_1": [0, 0]})
    d = cv.group_deltas(base, arm)
    # g2: differences 0, -1, +1, +1 -> mean 0.25, sd (ddof 1) = sqrt(((-.25)^2+(-1.25)^2+2*(.75)^2)/3)
    sd = np.sqrt((0.25**2 + 1.25**2 + 2 * 0.75**2) / 3)
    m, lo, hi, n = d["g2"]
    assert n == 4 and m == pytest.approx(0.25)
    assert hi - m == pytest.approx(1.96 * sd / 2)
    assert d["g11"][:1] == (-0.5,) and d["g11"][3] == 2
    assert d["all"][0] == pytest.approx((0 - 1 + 1 + 1 - 1 + 0) / 6)
    with pytest.raises(cv.GroupCvError, match="share no"):
        cv.group_deltas(base, _arm({"us101-3_1": [1]}))


def _results(arm_b: dict[str, list[int]], arm_c: dict[str, list[int]], c_faults: dict | None = None) -> cv.Results:
    base = {"us101-2_1": [0, 0, 1, 1], "us101-12_1": [0, 0, 1, 1], "us101-3_1": [0, 0, 1, 1]}
    return {
        "base": {w: _arm(base) for w in cv.WORLDS},
        "b": {w: _arm(arm_b) for w in cv.WORLDS},
        "c": {w: _arm(arm_c, c_faults) for w in cv.WORLDS},
    }


def test_the_rule_decides_on_the_worst_group_not_the_mean() -> None:
    # b: a large gain in two groups, a loss of 25 pp in one (mean +33 pp); c: +25 pp everywhere.
    b = {"us101-2_1": [1, 1, 1, 1], "us101-12_1": [1, 1, 1, 1], "us101-3_1": [0, 0, 0, 1]}
    c = {"us101-2_1": [1, 0, 1, 1], "us101-12_1": [1, 0, 1, 1], "us101-3_1": [1, 0, 1, 1]}
    choice, scores = cv.select(_results(b, c), "base")
    assert scores["b"] == pytest.approx(-0.25) and scores["c"] == pytest.approx(0.25)
    assert choice == "c"
    # Leaving g3 out, b's worst group is +50 pp and it wins; on g3 it then loses 25 pp.
    rows = {g: (arm, x) for g, arm, x in cv.leave_one_group_out(_results(b, c), "base")}
    assert rows["g3"] == ("b", pytest.approx(-0.25))
    assert rows["g2"][0] == "c"


def test_an_arm_that_adds_an_at_fault_run_is_never_chosen_and_the_base_wins_ties() -> None:
    c = {"us101-2_1": [1, 1, 1, 1], "us101-12_1": [1, 1, 1, 1], "us101-3_1": [1, 1, 1, 1]}
    faults = {"us101-3_1": [0, 0, 0, 1]}
    same = {"us101-2_1": [0, 0, 1, 1], "us101-12_1": [0, 0, 1, 1], "us101-3_1": [0, 0, 1, 1]}
    choice, scores = cv.select(_results(same, c, faults), "base")
    assert scores["c"] == -np.inf
    assert scores["b"] == 0.0 and choice == "base"
    # Without the group of the at-fault run, c is eligible again.
    assert cv.select(_results(same, c, faults), "base", exclude="g3")[0] == "c"
    text = cv.report(_results(same, c, faults), "base", "nudge-train group-cv --arm c=c.json")
    assert "**Chosen: base.**" in text and "c ineligible" in text


def _write_records(folder: Path, args: list[str], settings: dict) -> None:
    folder.mkdir(parents=True)
    (folder / "runs.csv").write_text("scenario,seed,success,collisions_at_fault\nus101-2_1-t01.0-ego1,0,true,0\n")
    (folder / "provenance.json").write_text(json.dumps({"command": ["/bin/nudge", *args], "settings": settings}))
    lines = [f"{hashlib.sha256((folder / n).read_bytes()).hexdigest()}  {n}" for n in ("runs.csv", "provenance.json")]
    (folder / "outputs.sha256").write_text("\n".join(lines) + "\n")


def test_records_are_reused_only_when_they_verify(tmp_path: Path) -> None:
    args = ["simulate", "--scenes", "/s", "--runs", "3"]
    full = {"admm": {"relinearisations": 2, "rho": 1000.0}, "cost": {"w_y": 15.0}}
    folder = tmp_path / "arm" / "student-idm"
    _write_records(folder, args, full)
    assert cv.verified(folder, args, {"admm": {"relinearisations": 2}})
    assert cv.verified(folder, args, {})
    assert not cv.verified(folder, args, {"admm": {"relinearisations": 1}})
    assert not cv.verified(folder, [*args[:-1], "1"], {})
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "us101-2_1-t01.0-ego1.safetensors").write_bytes(b"x")
    assert cv.verified(folder, args, {}, scenes)
    (scenes / "us101-2_1-t02.0-ego2.safetensors").write_bytes(b"x")
    assert not cv.verified(folder, args, {}, scenes), "a scene the records never ran"
    (folder / "runs.csv").write_text("tampered\n")
    assert not cv.verified(folder, args, {})
    assert not cv.verified(tmp_path / "missing", args, {})
    with pytest.raises(cv.GroupCvError, match="missing"):
        cv.load_arm_world(tmp_path / "missing", _groups())


def test_the_sample_takes_at_most_n_scenes_per_group_deterministically(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    for i in range(5):
        (src / f"us101-2_1-t0{i}.0-ego{i}.safetensors").write_bytes(b"x")
    (src / "us101-12_1-t01.0-ego9.safetensors").write_bytes(b"y")
    a = cv.sample_scenes([src], _groups(), 3, 7, tmp_path / "a")
    b = cv.sample_scenes([src], _groups(), 3, 7, tmp_path / "b")
    assert a == {"g11": 1, "g2": 3}
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == sorted(p.name for p in (tmp_path / "b").iterdir())
    # A smaller sample into the same folder leaves no file of the larger one behind.
    assert cv.sample_scenes([src], _groups(), 1, 7, tmp_path / "a") == {"g11": 1, "g2": 1}
    assert len(list((tmp_path / "a").iterdir())) == 2
