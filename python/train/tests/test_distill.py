"""Distillation-data generator: shard contents, determinism, resumability, atomic writes,
split handling, bad input and the Ray fan-out."""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

nudge = pytest.importorskip("nudge", reason="the nudge extension is not built (run `make develop`)")

from nudge_train.cli import main as cli_main  # noqa: E402
from nudge_train.distill import pipeline as gen_mod  # noqa: E402
from nudge_train.distill.config import DistillConfig, parse_size  # noqa: E402
from nudge_train.distill.pipeline import generate, load_shard, plan_shards  # noqa: E402
from nudge_train.distill.scenes import scene_interactive  # noqa: E402
from nudge_train.distill.stats import describe  # noqa: E402


@pytest.fixture(scope="module")
def scenes_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three small shipped scenes (split "test") as a scenes folder."""
    root = tmp_path_factory.mktemp("scenes")
    (root / "test").mkdir()
    small = [p for p in nudge.scene_paths() if nudge.Scenario.load(p).n_agents <= 5][:3]
    assert len(small) == 3
    for p in small:
        shutil.copy(p, root / "test" / p.name)
    return root


def _cfg(out: Path, scenes_root: Path, **kw: object) -> DistillConfig:
    base = DistillConfig(out=out, splits=("test",), scenes_root=scenes_root, max_scenes={"test": None},
                         max_steps=2, scenes_per_shard=2, threads=1, progress=False)
    return replace(base, **kw)  # type: ignore[arg-type]


def _files(out: Path) -> dict[str, tuple[dict[str, str], dict[str, bytes]]]:
    """Every shard's metadata and tensors (as dtype + shape + raw bytes). The header's key order is
    not fixed by safetensors, so shards are compared by content, not file bytes."""
    from safetensors import safe_open

    res = {}
    for p in sorted(out.glob("*.safetensors")):
        with safe_open(str(p), "numpy") as f:
            meta = dict(f.metadata() or {})
            arrays = {k: f"{f.get_tensor(k).dtype}{f.get_tensor(k).shape}".encode() + f.get_tensor(k).tobytes()
                      for k in f.keys()}
        res[p.name] = (meta, arrays)
    return res


def test_generate_writes_consistent_shards(tmp_path: Path, scenes_root: Path) -> None:
    cfg = _cfg(tmp_path / "d", scenes_root)
    m = generate(cfg, log=lambda _: None)
    assert m["schema"] == "nudge.distill/1"
    assert m["teacher"]["sha256"] == gen_mod.sha256_file(cfg.teacher)
    s = m["splits"]["test"]
    assert s["complete"] and s["shards_planned"] == 2 and len(s["shards"]) == 2
    assert sorted(s["scenes"]) == sorted(p.stem for p in (scenes_root / "test").glob("*.safetensors"))
    assert s["examples"] > 0
    teacher = nudge.Predictor.load(cfg.teacher)
    total = 0
    for e in s["shards"]:
        t = load_shard(cfg.out / e["file"])
        E = len(t["example_context"])
        total += E
        assert E == e["examples"] and t["candidate"].shape == (E, 6, 2)
        co, po = t["context_offsets"], t["prediction_offsets"]
        assert co[-1] == len(t["history"]) and po[-1] == len(t["prediction"])
        agents = np.diff(co)[t["example_context"]]
        np.testing.assert_array_equal(np.diff(po), agents - 1)
        assert t["run_scene"].max() < len(t["scene_agents"])
        np.testing.assert_array_equal(np.diff(co)[:1], t["scene_agents"][t["run_scene"][t["context_run"][:1]]])
        # The stored prediction is the teacher's prediction for the stored history + candidate.
        for i in np.linspace(0, E - 1, 5).astype(int):
            c = t["example_context"][i]
            want = teacher.predict(t["history"][co[c]:co[c + 1]].astype(np.float64),
                                   t["candidate"][i:i + 1].astype(np.float64))[0]
            np.testing.assert_allclose(t["prediction"][po[i]:po[i + 1]], want, atol=5e-3)
    assert total == s["examples"]
    st = describe(cfg.out)
    assert st["splits"]["test"]["examples"] == total and st["disk_bytes"] > 0
    assert not list(cfg.out.glob(".*tmp*"))


def test_cli_writes_what_generate_writes_and_prints_statistics(tmp_path: Path, scenes_root: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cli"
    assert cli_main(["distill", "--out", str(out), "--splits", "test", "--size", "test=all", "--scenes-root",
                     str(scenes_root), "--max-steps", "2", "--scenes-per-shard", "2", "--threads", "1",
                     "--no-progress"]) == 0
    ref = _cfg(tmp_path / "ref", scenes_root)
    generate(ref, log=lambda _: None)
    assert _files(out) == _files(ref.out)
    capsys.readouterr()
    assert cli_main(["distill", "--stats", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    stats, end = json.JSONDecoder().raw_decode(text)
    assert stats == json.loads(json.dumps(describe(out)))
    assert stats["splits"]["test"]["examples"] == json.loads((out / "manifest.json").read_text())["splits"]["test"]["examples"] > 0
    assert "| split | scenes done |" in text[end:]


def _count_shards(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Records the file of every shard computed from now on (in the returned list)."""
    calls: list[str] = []
    real = gen_mod.compute_shard

    def counting(spec, *a, **k):  # type: ignore[no-untyped-def]
        calls.append(spec.file)
        return real(spec, *a, **k)

    monkeypatch.setattr(gen_mod, "compute_shard", counting)
    return calls


def test_rerun_skips_complete_shards_and_regenerates_missing(tmp_path: Path, scenes_root: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = _cfg(tmp_path / "d", scenes_root)
    generate(cfg, log=lambda _: None)
    first = _files(cfg.out)
    calls = _count_shards(monkeypatch)
    generate(cfg, log=lambda _: None)
    assert calls == []
    victim = sorted(first)[0]
    (cfg.out / victim).unlink()
    generate(cfg, log=lambda _: None)
    assert calls == [victim]
    assert _files(cfg.out) == first  # deterministic: identical tensors and metadata
    # A different seed changes the content key: every shard is redone.
    calls.clear()
    generate(replace(cfg, seed=1), log=lambda _: None)
    assert sorted(calls) == sorted(first)


def test_closed_loop_defaults_are_part_of_the_content_key(tmp_path: Path, scenes_root: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Shards made under other closed-loop defaults (here without the crawl reference) are not
    resumed from: the SimConfig defaults are in the content key and the manifest."""
    cfg = _cfg(tmp_path / "d", scenes_root)
    generate(cfg, log=lambda _: None)
    first = _files(cfg.out)
    manifest = json.loads((cfg.out / "manifest.json").read_text())
    assert manifest["sim_config"] == nudge.SimConfig.default().to_dict()
    calls = _count_shards(monkeypatch)
    other = nudge.SimConfig.default().replace(crawl_fraction=0.0)
    monkeypatch.setattr(gen_mod.nudge.SimConfig, "default", staticmethod(lambda: other))
    generate(cfg, log=lambda _: None)
    assert sorted(calls) == sorted(first)
    assert json.loads((cfg.out / "manifest.json").read_text())["content_key"] != manifest["content_key"]


def test_failed_shard_leaves_no_file(tmp_path: Path, scenes_root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = _cfg(tmp_path / "d", scenes_root)

    def failing_replace(src: object, dst: object) -> None:
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="simulated"):
        generate(cfg, log=lambda _: None)
    monkeypatch.undo()
    assert not list(cfg.out.glob("test-*.safetensors")), "no shard may exist after a failed write"
    assert not list(cfg.out.glob(".test-*"))
    # A truncated shard under the final name (e.g. copied by hand) is not taken as complete.
    generate(cfg, log=lambda _: None)
    good = _files(cfg.out)
    name = sorted(good)[0]
    (cfg.out / name).write_bytes((cfg.out / name).read_bytes()[:100])
    generate(cfg, log=lambda _: None)
    assert _files(cfg.out) == good


def test_split_assignment_is_checked(tmp_path: Path, scenes_root: Path) -> None:
    root = tmp_path / "scenes"
    shutil.copytree(scenes_root, root)
    (root / "val").mkdir()
    shutil.copy(next((root / "test").glob("*.safetensors")), root / "val" / "x.safetensors")
    with pytest.raises(ValueError, match="split 'test' found in the 'val' folder"):
        plan_shards(_cfg(tmp_path / "d", root, splits=("val",), max_scenes={"val": None}))


def test_subset_and_seeds_are_stable(tmp_path: Path, scenes_root: Path) -> None:
    a = plan_shards(_cfg(tmp_path / "d", scenes_root, max_scenes={"test": 2}))["test"]
    b = plan_shards(_cfg(tmp_path / "d", scenes_root, max_scenes={"test": 2}, scenes_per_shard=1))["test"]
    assert [s for sp in a for s in sp.scenes] == [s for sp in b for s in sp.scenes]
    assert [x for sp in a for x in sp.seeds] == [x for sp in b for x in sp.seeds]
    # Sizes are nested: the 2-scene set is a prefix of the full one.
    full = plan_shards(_cfg(tmp_path / "d", scenes_root, scenes_per_shard=1))["test"]
    assert [sp.scenes for sp in full[:2]] == [sp.scenes for sp in b]
    c = plan_shards(_cfg(tmp_path / "d", scenes_root, seed=5))["test"]
    assert [x for sp in c for x in sp.seeds] != [x for sp in a for x in sp.seeds][:1] + [0]


def test_bad_input(tmp_path: Path, scenes_root: Path) -> None:
    with pytest.raises(FileNotFoundError, match="teacher weights not found"):
        generate(_cfg(tmp_path / "d", scenes_root, teacher=tmp_path / "none.safetensors"), log=lambda _: None)
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"nonsense")
    with pytest.raises(nudge.WeightsError):
        generate(_cfg(tmp_path / "d", scenes_root, teacher=bad), log=lambda _: None)
    with pytest.raises(ValueError, match="runs"):
        _cfg(tmp_path / "d", scenes_root, runs=0)
    with pytest.raises(ValueError, match="split"):
        _cfg(tmp_path / "d", scenes_root, splits=("dev",))
    assert parse_size("train=3,val=all")["val"] is None
    with pytest.raises(SystemExit):
        cli_main(["distill", "--size", "bogus=3"])


def test_interactive_flag_follows_the_window_rule(scenes_root: Path, tmp_path: Path) -> None:
    from safetensors import safe_open
    from safetensors.numpy import load_file, save_file

    src = next((scenes_root / "test").glob("*.safetensors"))
    t = load_file(str(src))
    with safe_open(str(src), "numpy") as f:
        meta = f.metadata()
    b = t["lane_bounds"]
    # Agent 1 keeps its lane in the history and moves 1.5 lanes over in the logged future.
    lane = int(np.searchsorted(b, t["history"][1, 0, 1], side="right") - 1)
    target = lane + 1 if lane + 1 < len(b) - 1 else lane - 1
    y_new = 0.5 * (b[target] + b[target + 1])
    t2 = dict(t)
    fut = t["future"].copy()
    fut[1, :, 1] = y_new
    t2["future"] = fut
    t2["future_valid"] = np.ones_like(t["future_valid"])
    t3 = dict(t)
    fut3 = t["future"].copy()
    fut3[:, :, 1] = t["history"][:, :1, 1]
    t3["future"] = fut3
    t3["history"] = np.repeat(t["history"][:, :1], 8, axis=1) * [1, 1] + 0.0
    t3["future_valid"] = np.ones_like(t["future_valid"])
    p2, p3 = tmp_path / "a.safetensors", tmp_path / "b.safetensors"
    save_file(t2, str(p2), metadata=meta)
    save_file(t3, str(p3), metadata=meta)
    assert scene_interactive(p2)
    assert not scene_interactive(p3)


def test_ray_shards_equal_single_process(tmp_path: Path, scenes_root: Path) -> None:
    ray = pytest.importorskip("ray", reason="ray is not installed in this environment")
    single = _cfg(tmp_path / "single", scenes_root)
    generate(single, log=lambda _: None)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        m = generate(_cfg(tmp_path / "ray", scenes_root), use_ray=True, log=lambda _: None)
    finally:
        ray.shutdown()
    assert m["last_run"]["ray"] is True
    assert _files(tmp_path / "ray") == _files(tmp_path / "single")
    a = json.loads((tmp_path / "ray" / "manifest.json").read_text())["splits"]
    b = json.loads((tmp_path / "single" / "manifest.json").read_text())["splits"]
    assert a == b


def test_distill_set_loads_as_student_windows(tmp_path: Path, scenes_root: Path) -> None:
    """``load_split`` on a distillation manifest: every window is (context history, candidate,
    teacher prediction), checked against a fresh teacher call on the window itself."""
    from nudge_train.data.loader import load_split

    cfg = _cfg(tmp_path / "d", scenes_root)
    m = generate(cfg, log=lambda _: None)
    ws = load_split(cfg.out, "test")
    assert len(ws) == m["splits"]["test"]["examples"] > 0
    teacher = nudge.Predictor.load(str(cfg.teacher))
    rng = np.random.default_rng(0)
    for w in rng.choice(len(ws), size=min(25, len(ws)), replace=False):
        win = ws.positions[ws.offsets[w] : ws.offsets[w + 1]]
        obs, fut = win[:, :8].astype(np.float64), win[:, 8:]
        pred = teacher.predict(obs, fut[:1].astype(np.float64))[0]  # [n-1, 6, 2]
        np.testing.assert_allclose(pred, fut[1:], atol=2e-4)
    # Interactive flags come from the scenes; a missing split is a clear error.
    assert set(np.unique(ws.interactive)) <= {0, 1}
    with pytest.raises(ValueError, match="no split 'train'"):
        load_split(cfg.out, "train")
