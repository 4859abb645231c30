"""``nudge-train paper`` (nudge_train.experiments.paper*): scene cuts against a distance sort of the
source file, the cache's integrity checks, the figures' numbers on hand-made step columns, the
Table I extract, and the ``--quick`` pipeline end to end: it writes every table and figure, a
rerun takes everything from the verified caches (no simulation, no training), and a tampered
cache entry is detected and recomputed to the same outcomes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from safetensors import safe_open
from safetensors.numpy import load_file

import nudge

from nudge_train import paths
from nudge_train.cli import main
from nudge_train.experiments.paper import table1_markdown
from nudge_train.experiments.paper_report import arm_stats, z_table
from nudge_train.experiments.paper_runs import PER_AGENT, cut_scene, load_cached, write_cached

SHIPPED = sorted(Path(nudge.assets_dir(), "scenes").glob("*.safetensors"))
TEST_SCENES = paths.scenes("test")
HAVE_DATA = TEST_SCENES.is_dir() and any(TEST_SCENES.glob("*.safetensors")) and \
    (paths.processed() / "manifest.json").is_file()


# ---- scene cuts ---------------------------------------------------------------------------------
@pytest.mark.skipif(not SHIPPED, reason="no shipped scenes")
@pytest.mark.parametrize("n", [2, 5])
def test_cut_keeps_the_ego_and_its_nearest_rows(tmp_path: Path, n: int) -> None:
    src = max(SHIPPED, key=lambda p: nudge.Scenario.load(p).n_agents)
    raw = load_file(str(src))
    last = raw["history"][:, -1]
    dist = np.hypot(*(last[1:] - last[0]).T)
    rows = [0, *(1 + np.argsort(dist, kind="stable"))[: n - 1].tolist()]
    out = cut_scene(src, n, tmp_path / "cut.safetensors")
    cut = load_file(str(out))
    assert set(cut) == set(raw)
    for key, value in raw.items():
        want = value[rows] if key in PER_AGENT else value
        np.testing.assert_array_equal(cut[key], want, err_msg=key)
    with safe_open(str(src), "np") as f_src, safe_open(str(out), "np") as f_cut:
        src_meta, cut_meta = f_src.metadata(), f_cut.metadata()
    assert {k: cut_meta[k] for k in src_meta} == src_meta
    assert nudge.Scenario.load(out).n_agents == n


@pytest.mark.skipif(not SHIPPED, reason="no shipped scenes")
def test_cut_refuses_more_vehicles_than_the_scene_has(tmp_path: Path) -> None:
    src = SHIPPED[0]
    have = nudge.Scenario.load(src).n_agents
    with pytest.raises(ValueError, match=f"{have} vehicles, cannot cut to N = {have + 1}"):
        cut_scene(src, have + 1, tmp_path / "cut.safetensors")


# ---- cache --------------------------------------------------------------------------------------
def test_cache_returns_only_what_checks_out(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    payload = {"steps": {"mpc_s": [0.01, 0.02]}, "wall_s": 1.5}
    write_cached(path, "k1", payload)
    logs: list[str] = []
    assert load_cached(path, "k1", logs.append) == payload
    assert load_cached(path, "k2", logs.append) is None
    assert "inputs changed" in logs[-1]
    doc = json.loads(path.read_text())
    doc["payload"]["steps"]["mpc_s"][1] = 0.03
    path.write_text(json.dumps(doc))
    assert load_cached(path, "k1", logs.append) is None
    assert "content hash mismatch" in logs[-1]
    path.write_text("{not json")
    assert load_cached(path, "k1", logs.append) is None
    assert "unreadable" in logs[-1]
    assert load_cached(tmp_path / "absent.json", "k1", logs.append) is None


# ---- numbers ------------------------------------------------------------------------------------
def _payload(z_s: list[float], z_updates: list[int], mpc_s: list[float], cost: list[float]) -> dict:
    return {
        "runs": {"error": [None, None, "no adjacent lane"], "success": [True, False, False],
                 "steps_to_target": [5, -1, -1], "collision": [False, True, False],
                 "collisions_at_fault": [0, 2, 0], "collisions_not_at_fault": [0, 0, 0]},
        "steps": {"z_s": z_s, "z_updates": z_updates, "mpc_s": mpc_s, "cost": cost},
        "wall_s": 2.0, "cpu_s": 1.9, "load": None,
    }


def test_arm_stats_from_step_columns() -> None:
    a = arm_stats(_payload([0.006, 0.0, 0.002], [3, 0, 1], [0.010, 0.020, 0.030], [1.0, float("nan"), 3.0]))
    assert a["runs"] == 2 and a["errors"] == 1
    assert a["success"] == 0.5
    assert a["collision_runs"] == 1 and a["at_fault"] == 2
    assert a["reached"] == 1 and math.isclose(a["ttt_mean"], 1.5)
    np.testing.assert_allclose(a["z_ms"], [2.0, 2.0])  # per-step means; the step without updates left out
    assert math.isclose(a["z_mean_ms"], 8.0 / 4)  # Σ z_s / Σ z_updates
    assert a["z_updates"] == 4 and a["steps"] == 3
    assert math.isclose(a["step_q"][1], 20.0)
    assert math.isclose(a["cost_mean"], 2.0) and math.isclose(a["cost_std"], 1.0)


def test_z_table_ratio_is_teacher_over_student() -> None:
    teacher = arm_stats(_payload([0.012, 0.024], [2, 2], [0.1, 0.2], [1.0, 1.0]))
    student = arm_stats(_payload([0.002, 0.004], [2, 2], [0.01, 0.02], [1.0, 1.0]))
    table = z_table({4: {"teacher": teacher, "student": student}}, {4: 17})
    row = table.splitlines()[2].split("|")
    assert row[1].strip() == "4" and row[2].strip() == "17"
    assert row[-4].strip() == "6.0×" and row[-3].strip() == "6.0×"


def test_table1_extract(tmp_path: Path) -> None:
    report = tmp_path / "teacher.md"
    report.write_text("# T\n\nWindows: test 3.\n\n### all\n\n| a |\n\n### Beside the paper's Table I (x)\n\n"
                      "| config | k |\n|---|---|\n| t | 1 |\n\nData note.\n\n### Training runs\n\n| z |\n")
    text = table1_markdown(report)
    assert "| t | 1 |" in text and "Data note." in text and "Windows: test 3." in text
    assert "Training runs" not in text and "| a |" not in text
    report.write_text("# T\n\nno table\n")
    with pytest.raises(ValueError, match="no section"):
        table1_markdown(report)


# ---- the command, end to end ---------------------------------------------------------------------
@pytest.mark.skipif(not HAVE_DATA, reason="no processed data (make data)")
def test_paper_quick_end_to_end_and_resume(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("RAYON_NUM_THREADS", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    out, cache = tmp_path / "out", tmp_path / "cache"
    student_before = paths.model_weights("student").read_bytes()
    argv = ["paper", "--quick", "--out", str(out), "--cache", str(cache), "--no-progress"]
    assert main(argv) == 0
    names = ["README.md", "table1.md", "table2.md", "paper.json"] + \
        [f"{f}.{ext}" for f in ("fig7_inference", "fig8_z_update", "fig9_planning_step", "fig10_cost", "outcomes")
         for ext in ("png", "md")]
    for name in names:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
        if name.endswith(".png"):
            assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    readme = (out / "README.md").read_text()
    for heading in ("## Table I", "## Table II", "## Fig. 7", "## Fig. 8", "## Fig. 9", "## Fig. 10",
                    "## Where and why we differ"):
        assert heading in readme, heading
    outcomes = (out / "outcomes.md").read_text()
    rows = [ln for ln in outcomes.splitlines() if ln.startswith("| 2 |") or ln.startswith("| 4 |")]
    assert len(rows) == 6  # 2 vehicle counts x 3 predictors
    assert all(ln.split("|")[3].strip() == "4" for ln in rows)  # 4 runs each
    table2 = (out / "table2.md").read_text()
    assert sum(ln.startswith(("| 1 ", "| 64 ", "| 128 ")) for ln in table2.splitlines()) == 5
    doc = json.loads((out / "paper.json").read_text())
    assert doc["quick"] is True and sorted(doc["figures"]["pools"]) == ["2", "4"]
    assert paths.model_weights("student").read_bytes() == student_before  # Table II exports nothing

    # A rerun takes everything from the verified caches: no simulation, no training, no evaluation,
    # no inference timing.
    def boom(*args: object, **kwargs: object) -> None:
        raise AssertionError("recomputed although cached")

    with monkeypatch.context() as m:
        m.setattr(nudge, "simulate", boom)
        m.setattr("nudge_train.training.loop.train", boom)
        m.setattr("nudge_train.training.evaluate.evaluate_generator", boom)
        m.setattr("nudge_train.models.interactive.teacher_interactive", boom)
        assert main(argv) == 0
    assert (out / "outcomes.md").read_text() == outcomes

    # A tampered (N, predictor) entry is named, recomputed, and gives the same runs.
    entry = cache / "closed_loop" / "n02-student.json"
    doc = json.loads(entry.read_text())
    doc["payload"]["runs"]["success"][0] = not doc["payload"]["runs"]["success"][0]
    entry.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(argv) == 0
    assert f"{entry}: content hash mismatch" in capsys.readouterr().out
    assert (out / "outcomes.md").read_text() == outcomes


def test_table2_choice_is_the_lowest_validation_ade() -> None:
    from nudge_train.experiments.paper_table2 import CONFIGS, PAPER_TABLE_II, table_markdown

    val = {(1, 1): 0.30, (1, 0): 0.12, (64, 1): 0.20, (64, 0): 0.11, (128, 0): 0.13}
    tcfg = {"epochs": 2, "samples_per_epoch": 100, "batch_size": 8, "lr": 1e-3, "lr_schedule": "cosine",
            "max_val_windows": 50}
    trained = {k: {"best_val_ade": v, "epochs_run": 2, "train_s": 1.0, "tcfg": tcfg} for k, v in val.items()}
    metric = {"ade1": 0.05, "ade6": 0.2, "fde6": 0.4, "scenes": 3, "agents": 9}
    tested = {k: {"fidelity_all": metric, "fidelity_interactive": None, "real_all": metric,
                  "real_interactive": metric} for k in CONFIGS}
    manifest = {"teacher": {"sha256": "ab" * 32}, "splits": {s: {"examples": 10} for s in ("train", "val", "test")}}
    text = table_markdown(trained, tested, manifest)
    assert "Chosen on validation: **k_var = 64, I_adv = 0**" in text
    rows = [ln.split("|") for ln in text.splitlines() if ln.startswith(("| 1", "| 64", "| 128"))]
    assert [r[1].strip() for r in rows] == ["1", "1", "64", "64 (chosen)", "128"]
    for (kv, adv), r in zip(CONFIGS, rows, strict=True):
        assert r[2].strip() == str(adv)
        assert r[12].strip().startswith(str(PAPER_TABLE_II[(kv, adv)][0])) and r[13].strip() == str(
            PAPER_TABLE_II[(kv, adv)][1])
        assert r[6].strip() == "–"  # no lane-change scenes in the held-out candidates


def test_a_training_run_of_other_inputs_starts_afresh(tmp_path: Path) -> None:
    from nudge_train.experiments.paper_table2 import INPUTS_FILE, _check_run_inputs

    run = tmp_path / "student_k1_adv0"
    logs: list[str] = []
    _check_run_inputs(run, {"data": ["a"], "train": {"epochs": 2}}, logs.append)
    (run / "last.pt").write_bytes(b"checkpoint")
    _check_run_inputs(run, {"data": ["a"], "train": {"epochs": 2}}, logs.append)
    assert (run / "last.pt").is_file() and not logs  # same inputs: kept, resumable
    _check_run_inputs(run, {"data": ["b"], "train": {"epochs": 2}}, logs.append)
    assert not (run / "last.pt").exists() and (run / INPUTS_FILE).is_file()
    assert "trained on other data or settings" in logs[-1]
    (run / "summary.json").write_text("{}")
    (run / INPUTS_FILE).unlink()  # a folder without its record is not trusted either
    _check_run_inputs(run, {"data": ["b"], "train": {"epochs": 2}}, logs.append)
    assert not (run / "summary.json").exists() and len(logs) == 2


def test_students_must_name_configurations_and_come_with_table2_alone() -> None:
    from nudge_train.experiments.paper import PaperConfig

    with pytest.raises(ValueError, match="'student_k2_adv0' is not one of"):
        PaperConfig(stages=("table2",), students=("student_k2_adv0",)).validate()
    with pytest.raises(ValueError, match="--stages table2 only"):
        PaperConfig(stages=("table1", "table2"), students=("student_k1_adv0",)).validate()
    PaperConfig(stages=("table2",), students=("student_k1_adv0", "student_k128_adv0")).validate()


@pytest.mark.skipif(not HAVE_DATA, reason="no processed data (make data)")
def test_a_share_of_the_students_trains_only_those_and_writes_no_table(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RAYON_NUM_THREADS", "1")
    out, cache = tmp_path / "out", tmp_path / "cache"
    argv = ["paper", "--quick", "--out", str(out), "--cache", str(cache), "--no-progress", "--stages", "table2",
            "--students", "student_k64_adv0"]
    assert main(argv) == 0
    trained = sorted(p.parent.name for p in (cache / "table2").glob("*/summary.json"))
    assert trained == ["student_k64_adv0"]
    assert not out.exists()  # nothing written into the output folder

    # The full stage then trains the other four only and writes the table.
    seen: list[str] = []
    from nudge_train.training import loop

    real_train = loop.train

    def counting(mcfg: object, tcfg: object, **kw: object) -> object:
        seen.append(Path(tcfg.out_dir).name)  # type: ignore[attr-defined]
        return real_train(mcfg, tcfg, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr("nudge_train.training.loop.train", counting)
    assert main(argv[:-2]) == 0
    assert sorted(seen) == ["student_k128_adv0", "student_k1_adv0", "student_k1_adv1", "student_k64_adv1"]
    table2 = (out / "table2.md").read_text()
    assert sum(ln.startswith(("| 1 ", "| 64 ", "| 128 ")) for ln in table2.splitlines()) == 5
    assert "is not the chosen student_k" in table2  # the stage never ships

    # Every configuration's best checkpoint is exported with its provenance, loadable by the planner.
    from nudge_train.experiments.paper_runs import file_sha
    from nudge_train.training.export import read_weights

    runs = sorted(p for p in (cache / "table2").glob("student_k*") if p.is_dir())
    assert len(runs) == 5
    for run in runs:
        w = read_weights(run / "student.safetensors")
        assert w.trained and w.provenance["best_pt_sha256"] == file_sha(run / "best.pt"), run.name
        assert nudge.Predictor.load(str(run / "student.safetensors")) is not None
