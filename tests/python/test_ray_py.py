"""Closed-loop runs on Ray (`nudge.simulate(..., ray=...)`, `nudge-train closed-loop --ray`) on
a local Ray of 2 CPUs: the records equal those of one process, run by run and in the same order
(every column but the wall-time ones), whatever the chunking; a failed task raises a typed error
naming its scenes and seeds and returns nothing."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import nudge
from nudge import distributed

ray = pytest.importorskip("ray", reason="ray is not installed in this environment")

TIMING = {"mpc_s", "z_s", "z_median_s"}


@pytest.fixture(scope="module")
def local_ray() -> Iterator[str]:
    """A local Ray of 2 CPUs, started by `distributed.connect` as `--ray` without an address does."""
    if ray.is_initialized():
        ray.shutdown()
    used = distributed.connect(None, num_cpus=2)
    try:
        yield used
    finally:
        ray.shutdown()


def assert_same_records(a: dict, b: dict, tables: tuple[str, ...] = ("runs", "steps", "collisions")) -> None:
    """Every column of every table equal (same names, order, dtype, values; NaN equals NaN)
    except the wall-time columns."""
    for t in tables:
        assert list(a[t]) == list(b[t]), t
        for k in a[t]:
            if k in TIMING:
                continue
            x, y = a[t][k], b[t][k]
            if isinstance(x, np.ndarray):
                assert isinstance(y, np.ndarray) and x.dtype == y.dtype and x.shape == y.shape, (t, k)
                np.testing.assert_array_equal(x, y, err_msg=f"{t}.{k}")
            else:
                assert list(x) == list(y), f"{t}.{k}"


def test_the_chunks_cover_the_runs_in_order() -> None:
    assert distributed.split(7, 3) == [range(0, 3), range(3, 6), range(6, 7)]
    assert distributed.split(2, 8) == [range(0, 2)]
    with pytest.raises(nudge.InputError, match="at least 1 run per task"):
        distributed.split(4, 0)
    s = distributed.Sweep(("a", "b"), (10, 3), 2)
    assert s.specs() == [(0, 10), (0, 11), (1, 3), (1, 4)]


@pytest.mark.parametrize("chunk", [1, 3])
def test_simulate_on_ray_equals_one_process(local_ray: str, scenes: list[Path], chunk: int) -> None:
    """Chunks of 1 and 3 runs (3 cuts a scene's runs apart) give the single-process tables."""
    assert local_ray.startswith("local")
    kw = dict(world="idm", max_steps=8, runs=2, scene_seeds=[5, 9, 2])
    one = nudge.simulate(scenes[:3], "student", threads=2, **kw)
    done: list[tuple[int, int]] = []
    on_ray = nudge.simulate(scenes[:3], "student", ray=True, ray_chunk=chunk, progress=lambda d, n: done.append((d, n)),
                            **kw)
    assert_same_records(one, on_ray)
    np.testing.assert_array_equal(on_ray["runs"]["scene_index"], [0, 0, 1, 1, 2, 2])
    assert len(on_ray["steps"]["run"]) > 6 and set(on_ray["steps"]["run"]) == set(range(6))
    n_tasks = -(-6 // chunk)
    assert done == [(i, n_tasks) for i in range(1, n_tasks + 1)]


def test_collision_rows_keep_their_runs(local_ray: str, scenes: list[Path]) -> None:
    """Settings loose enough to collide (margins 0, the reaction ablated): the collision rows of
    runs in different tasks come back under their runs."""
    loose = nudge.PlannerSettings.default().replace(
        safety={"ablate_reaction": True, "margin_x": 0.0, "margin_y": 0.0, "ellipse_scale": 1.0})
    kw = dict(world="idm", max_steps=20, runs=2, seed=0, settings=loose)
    one = nudge.simulate(scenes, "constant_velocity", **kw)
    on_ray = nudge.simulate(scenes, "constant_velocity", ray=True, ray_chunk=3, **kw)
    assert_same_records(one, on_ray)
    runs = sorted(set(on_ray["collisions"]["run"].tolist()))
    assert len(runs) >= 3 and len({r // 3 for r in runs}) >= 3, runs  # rows from three tasks or more


def test_the_base_seed_rule_and_traces_survive_the_fan_out(local_ray: str, scenes: list[Path]) -> None:
    kw = dict(world="log_replay", max_steps=4, runs=2, seed=40, trace=True)
    one = nudge.simulate(scenes[:2], "constant_velocity", **kw)
    on_ray = nudge.simulate(scenes[:2], "constant_velocity", ray=True, ray_chunk=3, **kw)
    assert_same_records(one, on_ray)
    assert on_ray["runs"]["seed"].tolist() == [40, 41, 42, 43]
    assert len(on_ray["traces"]) == 4
    for a, b in zip(one["traces"], on_ray["traces"], strict=True):
        np.testing.assert_array_equal(a["plan"], b["plan"])
        np.testing.assert_array_equal(a["agents"], b["agents"])


def test_a_failed_task_names_its_runs_and_returns_nothing(local_ray: str, scenes: list[Path], tmp_path: Path) -> None:
    bad = tmp_path / "broken.safetensors"
    bad.write_bytes(b"not a scenario")
    paths = [scenes[0], bad, scenes[1]]
    with pytest.raises(distributed.RayRunError) as e:
        nudge.simulate(paths, "constant_velocity", world="log_replay", max_steps=2, runs=2, seed=7, ray=True,
                       ray_chunk=2)
    assert e.value.runs == [("broken.safetensors", 9), ("broken.safetensors", 10)]
    assert "broken.safetensors seed 9" in str(e.value) and "ScenarioError" in e.value.cause
    assert isinstance(e.value, nudge.NudgeError)


def test_what_ray_cannot_carry_is_refused(scenes: list[Path], tmp_path: Path) -> None:
    """Refused before Ray is touched (no Ray needed)."""
    for kw, what in ((dict(record=True), "record"), (dict(out=tmp_path / "o"), "out"),
                     (dict(planner=object()), "planner")):
        with pytest.raises(nudge.InputError, match=what):
            nudge.simulate(scenes[:1], "constant_velocity", ray=True, **kw)
    with pytest.raises(nudge.InputError, match="ray_chunk"):
        nudge.simulate(scenes[:1], "constant_velocity", ray_chunk=2, max_steps=1)
    for kw, what in ((dict(on_error="ignore"), "on_error"), (dict(progress="yes"), "progress"),
                     (dict(threads=0), "task threads"), (dict(ray_chunk=0), "at least 1 run per task"),
                     (dict(ray=1), "ray: expected")):
        with pytest.raises(nudge.InputError, match=what):
            nudge.simulate(scenes[:1], "constant_velocity", **{"ray": True, **kw})


def test_closed_loop_on_ray_equals_one_process(local_ray: str, repo: Path, tmp_path: Path) -> None:
    """`nudge-train closed-loop` with and without `--ray`: the same arms, runs, steps and
    collisions in the same order, the same cache parts; provenance names the Ray."""
    from nudge_train.cli import main
    from nudge_train.experiments.closed_loop import EvalConfig, collect

    config = tmp_path / "sim.json"
    config.write_text(json.dumps({"max_steps": 10}))
    base = dict(scenes=repo / "assets" / "scenes", n=3, seeds=2, planners=("student",),
                worlds=("idm", "log_replay"), threads=2, batch=2, config=config, bootstrap=50, progress=False)
    one, _ = collect(EvalConfig(cache=tmp_path / "one", **base), log=lambda s: None)
    on_ray, _ = collect(EvalConfig(cache=tmp_path / "ray", ray="", ray_chunk=3, **base), log=lambda s: None)
    assert [c.arm for c in one] == [c.arm for c in on_ray]
    for a, b in zip(one, on_ray, strict=True):
        assert a.runs.keys() == b.runs.keys() and len(a.runs["seed"]) == 6
        for t in ("runs", "collisions", "steps"):
            ta, tb = getattr(a, t), getattr(b, t)
            assert list(ta) == list(tb)
            for k in ta:
                if k not in TIMING:
                    assert ta[k] == tb[k] or np.array_equal(ta[k], tb[k], equal_nan=True), (a.arm, t, k)
    parts = sorted(p.relative_to(tmp_path / "one") for p in (tmp_path / "one").rglob("part-*.json"))
    assert parts == sorted(p.relative_to(tmp_path / "ray") for p in (tmp_path / "ray").rglob("part-*.json"))
    assert len(parts) == 4
    for rel in parts:
        x, y = (json.loads((tmp_path / d / rel).read_text()) for d in ("one", "ray"))
        assert (x["key"], x["runs"]["scenario"], x["runs"]["seed"]) == (y["key"], y["runs"]["scenario"],
                                                                        y["runs"]["seed"])
    for d, want in (("one", None), ("ray", {"address": local_ray, "runs_per_task": 3, "task_threads": 1})):
        for prov in (tmp_path / d).rglob("provenance.json"):
            assert json.loads(prov.read_text())["ray"] == want
    # The command: --ray with the Ray this process holds; the cache of the single-process run
    # is read back as is (the parts' keys do not depend on Ray), a fresh cache computed on Ray.
    rc = main(["closed-loop", "--scenes", str(repo / "assets" / "scenes"), "--n", "2", "--seeds", "1",
               "--planners", "constant_velocity", "--worlds", "log_replay", "--cache", str(tmp_path / "cli"),
               "--bootstrap", "20", "--no-progress", "--ray", "--ray-chunk", "1"])
    assert rc == 0
    (prov,) = (tmp_path / "cli").rglob("provenance.json")
    assert json.loads(prov.read_text())["ray"]["runs_per_task"] == 1


def test_a_ray_that_cannot_be_reached_is_a_typed_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """What Ray raises when it cannot connect (here a stand-in for a cluster that refuses this
    process's token) becomes RayConnectError naming the address and the causes."""
    def refuse(**kw: object) -> None:
        try:
            raise RuntimeError("Failed to connect to GCS.\nAuthenticationError: token is missing")
        except RuntimeError as e:
            raise ConnectionError(f"Failed to connect to Ray cluster at {kw['address']}") from e

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", refuse)
    with pytest.raises(distributed.RayConnectError) as e:
        distributed.connect("head:6379")
    assert e.value.address == "head:6379" and isinstance(e.value, nudge.NudgeError)
    assert str(e.value) == ("cannot start or reach the Ray cluster at head:6379: ConnectionError: Failed to connect "
                            "to Ray cluster at head:6379; caused by RuntimeError: AuthenticationError: token is missing")
    # The command says so in one line and exits 2, before any run.
    from nudge_train.cli import main

    rc = main(["closed-loop", "--scenes", str(Path(nudge.scene_paths()[0]).parent), "--n", "1", "--seeds", "1",
               "--planners", "constant_velocity", "--worlds", "log_replay", "--cache", "/nonexistent/never-written",
               "--no-progress", "--ray", "head:6379"])
    assert rc == 2
