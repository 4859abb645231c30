"""The committed golden files, bench scenes and shipped weights are exactly what
``nudge-train goldens`` (:mod:`nudge_train.testing.goldens`) produces (its --check mode, run
in-process)."""

from __future__ import annotations

from collections.abc import Iterator
import shutil
from pathlib import Path

import pytest
import torch
from safetensors import safe_open

from nudge_train import paths
from nudge_train.cli import main
from nudge_train.models.config import teacher_config
from nudge_train.models.interactive import student_interactive, teacher_interactive
from nudge_train.models.networks import build_model
from nudge_train.testing import goldens as make_goldens
from nudge_train.training.export import export_generator, load_generator, read_weights


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """Single-threaded torch: these small ops only slow down with threads on a shared machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)

REPO_ROOT = paths.repo()
GOLDEN = paths.GOLDEN_DIR.as_posix()  # repository-relative, as the check reports it
BENCH = paths.BENCH_SCENES.as_posix()


def _asset_is_trained(kind: str) -> bool:
    path = REPO_ROOT / "assets" / "models" / f"{kind}.safetensors"
    return path.is_file() and read_weights(path).trained


def test_committed_files_are_reproduced_bit_exactly() -> None:
    trained = any(_asset_is_trained(k) for k in ("teacher", "student"))
    options = make_goldens.Options(trained=trained, ship_random=not trained)
    problems = make_goldens.check(REPO_ROOT, options, log=lambda _msg: None)
    assert problems == []


def test_check_reports_a_modified_file(tmp_path: Path) -> None:
    for rel in (GOLDEN, paths.BENCH_SCENES.parent.as_posix()):
        shutil.copytree(REPO_ROOT / rel, tmp_path / rel)
    target = tmp_path / GOLDEN / "cases_student_random.safetensors"
    raw = bytearray(target.read_bytes())
    raw[-1] ^= 0x01  # flip one bit of the last expected value
    target.write_bytes(bytes(raw))
    (tmp_path / paths.BENCH_SCENES).unlink()
    problems = make_goldens.check(tmp_path, make_goldens.Options(), log=lambda _msg: None)
    assert len(problems) == 2
    assert any(p.startswith(f"{GOLDEN}/cases_student_random.safetensors: n") and "values differ" in p for p in problems)
    assert any(p.startswith(f"{BENCH}: missing") for p in problems)
    assert main(["goldens", "--repo-root", str(tmp_path), "--check"]) == 1


@pytest.mark.parametrize("kind", ["teacher", "student"])
def test_cases_format_and_pytorch_f32_agreement(kind: str) -> None:
    fn = teacher_interactive if kind == "teacher" else student_interactive
    gen = load_generator(REPO_ROOT / GOLDEN / f"weights_{kind}_random.safetensors")
    assert gen.cfg.kind == kind
    with safe_open(str(REPO_ROOT / GOLDEN / f"cases_{kind}_random.safetensors"), "pt") as f:
        meta = f.metadata()
        assert meta["weights"] == f"weights_{kind}_random.safetensors"
        assert meta["generator"] == "python/train/scripts/make_goldens.py"
        for n in (1, 2, 5, 17, 47):
            history = f.get_tensor(f"n{n}.history")
            cands = f.get_tensor(f"n{n}.candidates")
            expected = f.get_tensor(f"n{n}.expected")
            assert history.shape == (n, 8, 2) and cands.shape == (4, 6, 2) and expected.shape == (4, n - 1, 6, 2)
            assert history.dtype == cands.dtype == expected.dtype == torch.float32
            # scene style of the spec: ego ends near the origin, everything within ±60 m × ±8 m
            assert history[0, -1].abs().max() < 1.0
            assert history[..., 0].abs().max() <= 60.0 and history[..., 1].abs().max() <= 8.0
            # float32 PyTorch vs the float64 reference: the tolerance the Rust side works to
            torch.testing.assert_close(fn(gen, history, cands), expected, atol=1e-5, rtol=1e-6)


def test_bench_scenes_format() -> None:
    with safe_open(str(REPO_ROOT / paths.BENCH_SCENES), "pt") as f:
        for n in (2, 4, 8, 16, 32):
            assert f.get_tensor(f"n{n}.history").shape == (n, 8, 2)
            assert f.get_tensor(f"n{n}.candidates").shape == (32, 6, 2)


def test_shipped_weights_load() -> None:
    for kind in ("teacher", "student"):
        weights = read_weights(REPO_ROOT / "assets" / "models" / f"{kind}.safetensors")
        assert weights.config.kind == kind
        load_generator(REPO_ROOT / "assets" / "models" / f"{kind}.safetensors")


def test_trained_cases_and_ship_random_guard(tmp_path: Path) -> None:
    src, out = tmp_path / "src", tmp_path / "out"
    cfg = teacher_config()
    gen, _ = build_model(cfg.replace(seed=77))  # stands in for trained weights
    export_generator(gen, gen.cfg, src / "assets" / "models" / "teacher.safetensors", trained=True, provenance={"run": "t"})
    messages: list[str] = []
    written = make_goldens.generate(out, src, make_goldens.Options(trained=True), log=messages.append)
    rel = Path(GOLDEN) / "cases_teacher_trained.safetensors"
    assert rel in written
    assert not (out / GOLDEN / "cases_student_trained.safetensors").exists()
    assert any("student" in m and "not found" in m for m in messages)
    with safe_open(str(out / rel), "pt") as f:
        assert f.metadata()["weights"] == "assets/models/teacher.safetensors"
        history, cands = f.get_tensor("n5.history"), f.get_tensor("n5.candidates")
        torch.testing.assert_close(teacher_interactive(gen, history, cands), f.get_tensor("n5.expected"), atol=1e-5, rtol=1e-6)
    with pytest.raises(ValueError, match="refusing"):
        make_goldens.generate(out, src, make_goldens.Options(ship_random=True), log=messages.append)
