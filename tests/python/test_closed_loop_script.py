"""`nudge-train closed-loop`: planners x worlds x seeds, paired by (scene, seed), cached and
resumable; the report's numbers agree with the raw run columns."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

import nudge
from nudge_train.cli import main
from nudge_train.experiments.closed_loop import Arm, Chunk, EvalConfig, collect, explain, paired, summarise


def _cfg(repo: Path, tmp_path: Path, **kw: object) -> EvalConfig:
    base = dict(scenes=repo / "assets" / "scenes", n=3, seeds=2, planners=("constant_velocity",),
                worlds=("idm", "log_replay"), teacher_n=1, threads=2, batch=2, cache=tmp_path / "cache",
                bootstrap=200, progress=False)
    base.update(kw)
    return EvalConfig(**base)


def test_chunks_hold_every_pair_and_agree_with_a_direct_simulation(repo: Path, tmp_path: Path) -> None:
    cfg = _cfg(repo, tmp_path)
    chunks, meta = collect(cfg, log=lambda s: None)
    assert [(c.arm.planner, c.arm.world) for c in chunks] == [("constant_velocity", "idm"),
                                                              ("constant_velocity", "log_replay")]
    scenes, seeds = meta["scenes"], meta["scene_seeds"]
    assert len(scenes) == 3
    direct = nudge.simulate(scenes, "constant_velocity", world="idm", scene_seeds=seeds, runs=2, threads=1)
    c = chunks[0]
    assert c.runs["scenario"] == direct["runs"]["scenario"]
    assert c.runs["seed"] == direct["runs"]["seed"].tolist()
    np.testing.assert_array_equal(c.runs["score"], direct["runs"]["score"])
    # Both worlds ran the same (scene, seed) pairs, so every run pairs up.
    assert set(zip(chunks[0].runs["scenario"], chunks[0].runs["seed"], strict=True)) == \
        set(zip(chunks[1].runs["scenario"], chunks[1].runs["seed"], strict=True))
    s = summarise(c, 30, n_boot=200)
    assert s["runs"] == 6 and s["success"][0] == np.mean(direct["runs"]["success"])
    assert s["at_fault"][0] == int(direct["runs"]["collisions_at_fault"].sum())
    assert s["at_fault_nuplan"][0] == int(direct["runs"]["collisions_at_fault_nuplan"].sum())
    # The run column counts the collision rows nuPlan's rule blames on the ego.
    blamed = np.bincount(np.asarray(direct["collisions"]["run"], dtype=np.int64)[
        np.asarray(direct["collisions"]["nuplan_at_fault"], dtype=bool)], minlength=6)
    np.testing.assert_array_equal(direct["runs"]["collisions_at_fault_nuplan"], blamed)
    assert s["straddle_s"] == direct["runs"]["straddle_steps"].mean() * nudge.DT
    ttt = np.where(direct["runs"]["steps_to_target"] >= 0, direct["runs"]["steps_to_target"], 30) * nudge.DT
    assert abs(s["time_to_target"] - ttt.mean()) < 1e-12
    cost = direct["steps"]["cost"][np.isfinite(direct["steps"]["cost"])]
    assert cost.size > 0 and s["cost"] == (float(np.median(cost)), float(cost.mean()))
    p = paired(chunks[0], chunks[1], 30, n_boot=200)
    assert p["pairs"] == 6 and p["both"] + p["only_a"] + p["only_b"] + p["neither"] == 6


def test_resume_reads_the_cache_and_recomputes_a_part_whose_inputs_changed(repo: Path, tmp_path: Path) -> None:
    cfg = _cfg(repo, tmp_path, worlds=("log_replay",))
    first, _ = collect(cfg, log=lambda s: None)
    again, _ = collect(cfg, log=lambda s: None)
    assert first[0].computed_s > 0 and again[0].computed_s == 0
    assert again[0].runs == first[0].runs
    # A part whose recorded inputs no longer match is recomputed, not trusted.
    part = next(iter(sorted(cfg.cache.rglob("part-0000.json"))))
    data = json.loads(part.read_text())
    data["key"] = "0" * 64
    data["runs"]["success"] = [not v for v in data["runs"]["success"]]
    part.write_text(json.dumps(data))
    messages: list[str] = []
    third, _ = collect(cfg, log=messages.append)
    assert third[0].computed_s > 0 and any("recomputing" in m for m in messages)
    assert third[0].runs["success"] == first[0].runs["success"]
    # A part written without a step column the summaries need is recomputed too.
    data = json.loads(part.read_text())
    del data["steps"]["cost"]
    part.write_text(json.dumps(data))
    messages.clear()
    fourth, _ = collect(cfg, log=messages.append)
    assert fourth[0].computed_s > 0 and any("without the step columns" in m for m in messages)
    np.testing.assert_array_equal(fourth[0].steps["cost"], first[0].steps["cost"])
    # Other settings are another chunk.
    s = tmp_path / "s.json"
    s.write_text(json.dumps({"admm": {"max_iter": 3}}))
    other, _ = collect(_cfg(repo, tmp_path, worlds=("log_replay",), settings=s), log=lambda m: None)
    assert other[0].computed_s > 0 and other[0].arm.settings == "s"


def test_collisions_are_explained_by_the_rule() -> None:
    row = {"at_fault": False, "other_behind": True, "rear_hit": True, "ego_in_lane": True, "ego_accel": -1.0,
           "dx": -4.0, "dy": 0.1, "ego_v": 10.0, "other_v": 14.5}
    assert "hit from behind inside its lane by a vehicle closing at 4.5 m/s" in explain(row, 3.0)
    row.update(at_fault=True, ego_in_lane=False, ego_accel=-4.0)
    why = explain(row, 3.0)
    assert "not inside one lane" in why and "brakes" in why
    row.update(other_behind=False, rear_hit=False, dx=5.0, ego_in_lane=True, ego_accel=0.0)
    assert "ran into it" in explain(row, 3.0)


def test_paired_counts_by_hand() -> None:
    def chunk(success: list[bool], steps: list[int], planner: str) -> Chunk:
        n = len(success)
        runs = {"scenario": ["a", "a", "b", "b"][:n], "seed": [1, 2, 3, 4][:n], "error": [None] * n,
                "success": success, "steps_to_target": steps}
        return Chunk(Arm(planner, "idm", "default"), runs, {}, {}, 0.0, 0.0)

    a = chunk([True, True, False, False], [10, 12, -1, -1], "a")
    b = chunk([True, False, True, False], [8, -1, 20, -1], "b")
    p = paired(a, b, 30, n_boot=200)
    assert (p["pairs"], p["both"], p["only_a"], p["only_b"], p["neither"]) == (4, 1, 1, 1, 1)
    assert p["p"] == 1.0
    # Time to target, failures at the budget (30 steps): B − A = (−2, 18, −10, 0) · 0.3 s.
    assert abs(p["ttt"][0] - np.mean([-2, 18, -10, 0]) * nudge.DT) < 1e-12
    # Success B − A per pair: (0, −1, +1, 0); scene a: (0, −1), scene b: (+1, 0).
    assert p["success"][0] == 0.0 and p["success"][1] <= -0.5 + 1e-12 and p["success"][2] >= 0.5 - 1e-12
    # C − B = (0, +1, 0, +1): +0.5 in both scenes, so every resample gives +0.5.
    c = chunk([True, True, True, True], [10, 12, 9, 9], "c")
    np.testing.assert_allclose(paired(b, c, 30, n_boot=200)["success"], (0.5, 0.5, 0.5), atol=1e-12)


def test_command_writes_the_report(repo: Path, tmp_path: Path) -> None:
    out = tmp_path / "cl.md"
    js = tmp_path / "cl.json"
    rc = main(["closed-loop", "--scenes", str(repo / "assets" / "scenes"), "--n", "2", "--seeds", "2",
               "--planners", "constant_velocity", "--worlds", "idm", "log_replay", "--threads", "1",
               "--cache", str(tmp_path / "cache"), "--bootstrap", "100", "--out", str(out), "--json", str(js),
               "--no-progress"])
    assert rc == 0
    text = out.read_text()
    for heading in ("## How runs are judged", "## Results per world and planner", "## Per density stratum",
                    "## Paired differences", "## Every collision"):
        assert heading in text
    rows = [line for line in text.splitlines() if line.startswith("| idm | constant_velocity |")]
    assert len(rows) >= 2  # the results row and at least one stratum
    data = json.loads(js.read_text())
    assert set(data) == {"idm/constant_velocity/default", "log_replay/constant_velocity/default"}
    assert data["idm/constant_velocity/default"]["runs"] == 4
    assert main(["closed-loop", "--scenes", str(tmp_path), "--n", "2", "--out", str(out)]) == 2
    assert main(["closed-loop", "--seeds", "0"]) == 2


def test_teacher_n_zero_is_accepted_without_the_teacher_only(repo: Path, tmp_path: Path) -> None:
    EvalConfig(scenes=tmp_path, planners=("student",), teacher_n=0).validate()
    with pytest.raises(ValueError, match="--teacher-n must be >= 1 when the teacher plans"):
        EvalConfig(scenes=tmp_path, planners=("student", "teacher"), teacher_n=0).validate()
    with pytest.raises(ValueError, match="--teacher-n must be >= 0"):
        EvalConfig(scenes=tmp_path, planners=("student",), teacher_n=-1).validate()
    out = tmp_path / "cl.md"
    rc = main(["closed-loop", "--scenes", str(repo / "assets" / "scenes"), "--n", "1", "--seeds", "1",
               "--planners", "constant_velocity", "--worlds", "log_replay", "--teacher-n", "0", "--threads", "1",
               "--cache", str(tmp_path / "cache"), "--bootstrap", "50", "--out", str(out), "--no-progress"])
    assert rc == 0 and out.is_file()


def test_the_report_is_only_printed_unless_out_is_named(repo: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture) -> None:
    """No tracked doc is overwritten by default: without --out nothing is written under docs/."""
    monkeypatch.setenv("NUDGE_REPO", str(tmp_path))
    rc = main(["closed-loop", "--scenes", str(repo / "assets" / "scenes"), "--n", "1", "--seeds", "1",
               "--planners", "constant_velocity", "--worlds", "log_replay", "--threads", "1",
               "--cache", str(tmp_path / "cache"), "--bootstrap", "50", "--no-progress"])
    assert rc == 0
    assert "## Results per world and planner" in capsys.readouterr().out
    assert not (tmp_path / "docs").exists()


def test_every_arm_folder_carries_its_provenance(repo: Path, tmp_path: Path) -> None:
    cfg = _cfg(repo, tmp_path, worlds=("idm",))
    chunks, meta = collect(cfg, log=lambda s: None, command="nudge-train closed-loop --n 3")
    folders = [p for p in (tmp_path / "cache").iterdir() if p.is_dir()]
    assert len(folders) == 1
    prov = json.loads((folders[0] / "provenance.json").read_text())
    assert prov["schema"] == "nudge.provenance/1" and prov["git_sha"] == nudge.GIT_SHA
    assert prov["nudge_version"] == nudge.__version__ and prov["command"] == "nudge-train closed-loop --n 3"
    assert (prov["predictor"], prov["world"], prov["threads"]) == ("constant_velocity", "idm", 2)
    assert prov["sim_config"]["world"] == "idm"
    idm = nudge.assets_dir() / "worlds" / "idm.json"
    assert list(prov["models"].values()) == [hashlib.sha256(idm.read_bytes()).hexdigest()]
    files = [(p.name, hashlib.sha256(p.read_bytes()).hexdigest()) for p in meta["scenes"]]
    assert [(Path(f["path"]).name, f["sha256"]) for f in prov["scenes"]["files"]] == files
    lines = "".join(f"{n} {h}\n" for n, h in files)
    assert prov["scenes"]["list_sha256"] == hashlib.sha256(lines.encode()).hexdigest()
    assert prov["seeds"]["scene_seeds"] == meta["scene_seeds"] and prov["seeds"]["runs_per_scene"] == 2
    assert prov["machine"]["cores"] >= 1 and prov["machine"]["hostname"]


def test_compare_runs_two_settings_on_the_same_pairs(repo: Path, tmp_path: Path) -> None:
    a, b = tmp_path / "base.json", tmp_path / "fewer_iterations.json"
    a.write_text("{}")
    b.write_text(json.dumps({"admm": {"max_iter": 2}}))
    out = tmp_path / "cmp.md"
    rc = main(["closed-loop", "--scenes", str(repo / "assets" / "scenes"), "--n", "2", "--seeds", "1",
               "--planners", "constant_velocity", "--worlds", "log_replay", "--compare", str(a), str(b),
               "--threads", "1", "--cache", str(tmp_path / "cache"), "--bootstrap", "50", "--out", str(out),
               "--no-progress"])
    assert rc == 0
    text = out.read_text()
    assert "Reference: settings base" in text
    rows = [line for line in text.splitlines()
            if line.startswith("| log_replay | constant_velocity [base] | constant_velocity [fewer_iterations] |")]
    assert len(rows) == 1 and rows[0].split("|")[4].strip() == "2"  # two (scene, seed) pairs
