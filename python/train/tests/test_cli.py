"""The `nudge-train` command: every subcommand parses with the defaults of the entry point it
replaces, `--help` works everywhere, and the fast subcommands run end to end on tiny inputs."""

from __future__ import annotations

import argparse
import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nudge_train import paths
from nudge_train.cli import build_parser, main
from nudge_train.constants import BENCH_NS

# Every subcommand with the smallest valid arguments, and the handler it dispatches to.
COMMANDS: list[tuple[list[str], str]] = [
    (["data", "build"], "_run_data_build"),
    (["data", "report"], "_run_data_report"),
    (["data", "scenes"], "_run_data_scenes"),
    (["train", "--config", "c.toml"], "_run_train"),
    (["teacher"], "_run_teacher"),
    (["student"], "_run_student"),
    (["distill"], "_run_distill"),
    (["student-react"], "_run_student_react"),
    (["student-report"], "_run_student_report"),
    (["reaction"], "_run_reaction"),
    (["closed-loop"], "_run_closed_loop"),
    (["bench", "inference"], "_run_bench_inference"),
    (["bench", "planner"], "_run_bench_planner"),
    (["bench", "python"], "_run_bench_python"),
    (["bench", "latency"], "_run_bench_latency"),
    (["goldens"], "_run_goldens"),
    (["figures", "runs", "out/demo"], "_run_figures_runs"),
    (["figures", "curves", "teacher=runs/teacher", "--png", "c.png"], "_run_figures_curves"),
    (["human-lane-changes"], "_run_human_lane_changes"),
]


def _png_size(path: Path) -> tuple[int, int]:
    """Width and height (pixels) from a PNG's IHDR chunk."""
    raw = path.read_bytes()
    assert raw[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    return struct.unpack(">II", raw[16:24])


@pytest.mark.parametrize(("argv", "handler"), COMMANDS, ids=[" ".join(c[:2]) for c, _ in COMMANDS])
def test_every_subcommand_parses(argv: list[str], handler: str) -> None:
    args = build_parser().parse_args(argv)
    assert args.run.__name__ == handler


def test_defaults_are_those_of_the_replaced_entry_points() -> None:
    p = build_parser()
    cl = p.parse_args(["closed-loop"])
    assert (cl.split, cl.scenes, cl.n, cl.seeds, cl.teacher_n, cl.seed, cl.threads) == ("val", None, None, 3, 60, 0, 2)
    assert cl.planners == ["student", "teacher"] and cl.worlds == ["teacher", "idm", "log_replay"]
    assert (cl.settings, cl.config, cl.compare) == (None, None, None)
    # The report is printed; a tracked doc is written only when named (--out).
    assert cl.out is None
    t = p.parse_args(["teacher"])
    assert (t.data, t.runs, t.threads, t.no_export) == (
        str(paths.repo() / "data" / "processed"), str(paths.repo() / "runs"), 2, False)
    assert t.export == str(paths.repo() / "assets" / "models" / "teacher.safetensors")
    assert t.report == str(paths.repo() / "docs" / "results" / "teacher.md")
    s = p.parse_args(["student"])
    assert s.config == paths.repo() / "python" / "train" / "configs" / "student.toml"
    assert (s.distill, s.out_dir) == (str(paths.repo() / "data" / "distill"), str(paths.repo() / "runs" / "student"))
    sr = p.parse_args(["student-react"])
    assert sr.config == paths.repo() / "python" / "train" / "configs" / "student_react.toml"
    rep = p.parse_args(["student-report"])
    assert (rep.weights, rep.distill) == (paths.repo() / "assets" / "models" / "student.safetensors", paths.distill())
    assert rep.report == paths.repo() / "docs" / "results" / "student.md"
    r = p.parse_args(["reaction"])
    assert (r.distill, r.split, r.candidate, r.bootstrap) == (paths.repo() / "data" / "distill", "test", [], 2000)
    assert r.report == paths.repo() / "docs" / "results" / "reaction.md"
    assert r.cutins == paths.repo() / "assets" / "worlds" / "cutins.json"
    d = p.parse_args(["distill"])
    assert d.size == {"train": 340, "val": 64, "test": 88}  # the "paper" preset
    assert (d.world, d.runs, d.seed, d.max_steps, d.scenes_per_shard, d.threads) == ("teacher", 1, 0, 30, 8, None)
    assert d.out == paths.repo() / "data" / "distill"
    b = p.parse_args(["bench", "inference"])
    assert (b.ns, b.warmup, b.repeats, b.min_seconds, b.batch32) == (list(BENCH_NS), 10, 50, 1.0, False)
    assert p.parse_args(["bench", "python"]).ns == [2, 4, 8, 16]
    assert p.parse_args(["bench", "planner"]).criterion == paths.repo() / "target" / "criterion" / "planner"
    g = p.parse_args(["goldens"])
    assert (g.repo_root, g.trained, g.ship_random, g.check) == (paths.repo(), False, False, False)
    f = p.parse_args(["figures", "runs", "out/demo"])
    assert (f.scenes, f.png, f.max_runs) == (paths.repo() / "assets" / "scenes", None, 6)
    db = p.parse_args(["data", "build"])
    assert (db.out, db.phases, db.seed, db.no_i80) == (paths.repo() / "data" / "processed", "0,1,2", 0, False)


@pytest.mark.parametrize("argv", [[]] + [c[:1] for c, _ in COMMANDS if c[0] in ("data", "bench", "figures")]
                         + [c[:2] if c[0] in ("data", "bench", "figures") else c[:1] for c, _ in COMMANDS])
def test_help_works(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: nudge-train" + "".join(f" {a}" for a in argv))


def _registered(argv: list[str]) -> list[str]:
    """The subcommands registered under ``nudge-train ARGV`` (in registration order), read from
    the parser itself."""
    parser = build_parser()
    for name in [*argv, None]:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        if name is None:
            return list(sub.choices)
        parser = sub.choices[name]
    raise AssertionError("unreachable")


@pytest.mark.parametrize("argv", [[], ["data"], ["bench"], ["figures"]], ids=lambda a: " ".join(a) or "top")
def test_help_lists_every_registered_subcommand(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    names = _registered(argv)
    assert len(names) >= (19 if not argv else 2)
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    # One entry per registered subcommand, in registration order, and no other.
    listed = re.findall(r"^ {4}(\S+)", out, flags=re.M)
    assert listed == names, f"`nudge-train {' '.join(argv)} --help` lists {listed}, registered: {names}"
    # No hand-written list of them anywhere in the help: every {a,b,...} naming one names them all.
    for group in re.findall(r"\{([^{}]*)\}", out):
        choices = set(group.split(","))
        if choices & set(names):
            assert choices == set(names), f"the help names {sorted(choices)}, registered: {names}"


@pytest.mark.parametrize("argv", [[], ["nope"], ["bench"], ["train"], ["distill", "--size", "bogus=3"],
                                  ["closed-loop", "--n", "many"]])
def test_bad_command_lines_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "usage: nudge-train" in capsys.readouterr().err


def test_installed_console_script_runs() -> None:
    script = Path(sys.executable).parent / "nudge-train"
    if not script.exists():
        pytest.skip("nudge-train is not installed in this environment")
    done = subprocess.run([str(script), "--help"], capture_output=True, text=True, check=False)
    assert done.returncode == 0 and done.stdout.startswith("usage: nudge-train")


# ---- end to end ---------------------------------------------------------------------------------
def _processed(out: Path, windows: dict[str, int]) -> Path:
    """A processed-data folder (manifest + one shard per split) of synthetic highway windows:
    3-6 agents each, 14 steps of 0.3 s."""
    from nudge_train.constants import DATASET_SCHEMA, OBS_LEN, PRED_LEN
    from nudge_train.data.st_io import write_safetensors
    from nudge_train.provenance import sha256_file
    from nudge_train.testing.synthetic import highway_history

    out.mkdir(parents=True)
    rng = np.random.default_rng(7)
    splits = {}
    for split, count in windows.items():
        pos = [highway_history(rng, int(rng.integers(3, 7)), obs_len=OBS_LEN + PRED_LEN) for _ in range(count)]
        offsets = np.concatenate([[0], np.cumsum([len(p) for p in pos])]).astype(np.int64)
        shard = out / f"{split}-000.safetensors"
        write_safetensors(shard, {
            "positions": np.concatenate(pos), "offsets": offsets, "interactive": np.zeros(count, np.uint8)}, {})
        splits[split] = {"shards": [{"file": shard.name, "sha256": sha256_file(shard)}]}
    (out / "manifest.json").write_text(json.dumps({"schema": DATASET_SCHEMA, "splits": splits}))
    return out


def test_train_then_curves(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    processed = _processed(tmp_path / "processed", {"train": 16, "val": 6})
    config = tmp_path / "tiny.toml"
    config.write_text('[model]\nkind = "teacher"\npool_hidden_dim = 16\n\n[train]\nepochs = 2\nbatch_size = 8\n'
                      'k_samples = 2\nmax_train_windows = 16\nmax_val_windows = 8\nthreads = 1\ndevice = "cpu"\n')
    out = tmp_path / "run"
    capsys.readouterr()
    assert main(["train", "--config", str(config), "--data", str(processed), "--out-dir", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary == json.loads((out / "summary.json").read_text())
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1]
    assert summary["best_val_ade"] == min(r["val_ade"] for r in rows)
    assert (out / "best.pt").is_file() and (out / "last.pt").is_file()
    # An impossible override is refused with status 2 before anything is trained.
    assert main(["train", "--config", str(config), "--data", str(processed), "--out-dir", str(tmp_path / "x"),
                 "--epochs", "0"]) == 2
    assert "train.epochs" in capsys.readouterr().err and not (tmp_path / "x").exists()

    png = tmp_path / "curves.png"
    assert main(["figures", "curves", f"tiny={out}", "--png", str(png), "--title", "t"]) == 0
    assert _png_size(png) == (1210, 440)  # figsize 11 x 4 in at 110 dpi
    assert main(["figures", "curves", "no-label", "--png", str(png)]) == 2


def _records(scene_dir: Path, names: list[str]) -> list[dict]:
    """Two closed-loop runs in the layout of `nudge simulate --out` (records.json): the ego drives
    straight on at 15 m/s from its last observed position; the second run reports a collision."""
    import nudge

    runs = []
    for k, name in enumerate(names):
        sc = nudge.Scenario.load(scene_dir / f"{name}.safetensors")
        x0, y0 = sc.history[0, -1]
        steps = [{"step": i, "ego": [float(x0 + 4.5 * (i + 1)), float(y0), 0.0, 15.0], "collision": k == 1 and i == 3}
                 for i in range(5)]
        runs.append({"scenario": name, "predictor": "student", "target_lane": int(sc.ego_lane),
                     "y_target": float(y0), "success": k == 0, "steps": steps})
    return runs


def test_figures_runs_draws_and_needs_no_torch(tmp_path: Path) -> None:
    pytest.importorskip("nudge", reason="the nudge extension is not built (run `make develop`)")
    scenes = paths.shipped_scenes()
    names = [p.stem for p in sorted(scenes.glob("*.safetensors"))[:2]]
    records = tmp_path / "sim"
    records.mkdir()
    (records / "records.json").write_text(json.dumps(_records(scenes, names)))
    png = tmp_path / "runs.png"
    assert main(["figures", "runs", str(records), "--scenes", str(scenes), "--png", str(png)]) == 0
    assert _png_size(png) == (1650, 286)  # two panels side by side: figsize 15 x 2.6 in at 110 dpi
    # The same command with torch, safetensors and tqdm made unimportable: the demo's light
    # environment (numpy + matplotlib + the extension) is enough.
    png2 = tmp_path / "runs2.png"
    code = ("import sys\n"
            "for m in ('torch', 'safetensors', 'tqdm', 'ray'):\n    sys.modules[m] = None\n"
            "from nudge_train.cli import main\n"
            f"rc = main(['figures', 'runs', {str(records)!r}, '--scenes', {str(scenes)!r}, '--png', {str(png2)!r}])\n"
            "assert 'torch' not in [k for k, v in sys.modules.items() if v is not None]\n"
            "raise SystemExit(rc)\n")
    env = {**os.environ, "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=False)
    assert done.returncode == 0, done.stderr
    assert png2.read_bytes() == png.read_bytes()
    assert main(["figures", "runs", str(tmp_path / "empty"), "--scenes", str(scenes)]) == 2


def test_bench_planner_table_from_criterion_estimates(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    crit = tmp_path / "criterion" / "planner"
    for bench_id, ns in {"step_student": 1.5e6, "step_teacher": 60e6, "z_update_student": 2e4,
                         "z_update_teacher": 3e6}.items():
        d = crit / bench_id / "8" / "new"
        d.mkdir(parents=True)
        (d / "estimates.json").write_text(json.dumps({"median": {"point_estimate": ns}}))
    md = tmp_path / "planner.md"
    assert main(["bench", "planner", "--criterion", str(crit), "--markdown", str(md)]) == 0
    row = next(line for line in md.read_text().splitlines() if line.startswith("| 8 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    # N, step teacher / student / CV (ms), Z-update teacher / student / CV, Z ratio, step ratio
    assert cells == ["8", "60.00", "1.50", "nan", "3.000", "0.0200", "nan", "150.0", "40.0"]
    assert md.read_text() == capsys.readouterr().out
    assert main(["bench", "planner", "--criterion", str(tmp_path / "none")]) == 2


def test_bench_inference_refuses_agent_counts_without_a_scene(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "inference", "--ns", "3"]) == 2
    assert "not in the bench scenes" in capsys.readouterr().err


def test_ctrl_c_ends_any_command_with_status_130_and_no_traceback(monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 49 class 12: `nudge-train distill` answered Ctrl-C with a traceback. Every command
    ends on KeyboardInterrupt with one line on stderr and status 130 (128 + SIGINT), saying that
    a resumable command resumes from where it stopped."""
    import nudge_train.cli as cli

    def interrupted(_: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_run_distill", interrupted)
    assert main(["distill", "--out", "x"]) == 130
    err = capsys.readouterr().err
    assert err.startswith("interrupted") and "Traceback" not in err and err.count("\n") == 1, err
