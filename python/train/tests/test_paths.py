"""nudge_train.paths: the one path resolver, its environment overrides, and that the package
resolves paths through it only."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import nudge_train
from nudge_train import paths
from nudge_train.cli import build_parser
from nudge_train.distill.config import DistillConfig

PACKAGE = Path(nudge_train.__file__).parent


@pytest.fixture(autouse=True)
def _no_overrides(monkeypatch: pytest.MonkeyPatch) -> None:
    for var in (paths.ENV_REPO, paths.ENV_ASSETS, paths.ENV_NGSIM):
        monkeypatch.delenv(var, raising=False)


def test_default_repo_is_this_checkout() -> None:
    root = paths.repo()
    assert (root / "Cargo.toml").is_file() and (root / "Makefile").is_file()
    assert (root / "python" / "train" / "nudge_train" / "paths.py").samefile(Path(paths.__file__))
    assert paths.assets() == root / "assets"
    assert (paths.model_weights("teacher")).is_file() and any(paths.shipped_scenes().glob("*.safetensors"))
    assert (paths.configs() / "student.toml").is_file()
    assert paths.ngsim() == root.parent / "shared" / "data" / "ngsim"


def test_nudge_repo_moves_every_repository_path(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("NUDGE_REPO", str(tmp_path))
    assert paths.repo() == tmp_path
    assert paths.processed() == tmp_path / "data" / "processed"
    assert paths.scenes("val") == tmp_path / "data" / "processed" / "scenes" / "val"
    assert paths.distill() == tmp_path / "data" / "distill"
    assert paths.runs() == tmp_path / "runs"
    assert paths.results() == tmp_path / "docs" / "results"
    assert paths.figures() == tmp_path / "docs" / "figures"
    assert paths.configs() == tmp_path / "python" / "train" / "configs"
    assert paths.criterion() == tmp_path / "target" / "criterion"
    assert paths.assets() == tmp_path / "assets"
    assert paths.ngsim() == tmp_path.parent / "shared" / "data" / "ngsim"
    # Defaults are resolved when used, so the command line and the configs follow the variable.
    cl = build_parser().parse_args(["closed-loop"])
    assert (cl.cache, cl.out) == (tmp_path / "runs" / "closed_loop", None)
    assert build_parser().parse_args(["teacher"]).export == str(tmp_path / "assets" / "models" / "teacher.safetensors")
    cfg = DistillConfig()
    assert cfg.out == tmp_path / "data" / "distill"
    assert cfg.teacher == tmp_path / "assets" / "models" / "teacher.safetensors"


def test_nudge_assets_and_nudge_ngsim_move_only_their_folder(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    root = paths.repo()
    monkeypatch.setenv("NUDGE_ASSETS", str(tmp_path / "a"))
    monkeypatch.setenv("NUDGE_NGSIM", str(tmp_path / "n"))
    assert paths.assets() == tmp_path / "a"
    assert paths.model_weights("student") == tmp_path / "a" / "models" / "student.safetensors"
    assert paths.shipped_scenes() == tmp_path / "a" / "scenes"
    assert paths.ngsim() == tmp_path / "n"
    assert paths.repo() == root and paths.processed() == root / "data" / "processed"
    args = build_parser().parse_args(["data", "build"])
    assert (args.data_root, args.out) == (tmp_path / "n", root / "data" / "processed")
    assert build_parser().parse_args(["figures", "runs", "x"]).scenes == tmp_path / "a" / "scenes"


def test_assets_agree_with_the_bindings(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    nudge = pytest.importorskip("nudge", reason="the nudge extension is not built (run `make develop`)")
    assert nudge.assets_dir().resolve() == paths.assets().resolve()
    monkeypatch.setenv("NUDGE_ASSETS", "")  # empty counts as unset for both
    assert nudge.assets_dir().resolve() == paths.assets().resolve() == (paths.repo() / "assets").resolve()
    (tmp_path / "models").mkdir()
    monkeypatch.setenv("NUDGE_ASSETS", str(tmp_path))
    assert nudge.assets_dir() == paths.assets() == tmp_path
    assert nudge.model_path("teacher") == paths.model_weights("teacher")


def test_repo_relative(tmp_path: Path) -> None:
    root = paths.repo()
    assert paths.repo_relative(root / "docs" / "results") == "docs/results"
    assert paths.repo_relative(tmp_path / "x") == str(tmp_path / "x")
    # A path reaching into the repository through a symbolic link from outside is still shown
    # relative to the repository.
    link = tmp_path / "link"
    link.symlink_to(root / "docs")
    assert paths.repo_relative(link / "results") == "docs/results"


def test_no_other_module_guesses_paths_or_patches_imports() -> None:
    """Only paths.py looks at where the package lives; no module edits sys.path or loads files as
    modules."""
    pattern = re.compile(r"Path\(__file__\)|sys\.path\.insert|spec_from_file_location")
    offenders = [
        f"{p.relative_to(PACKAGE)}:{i}: {line.strip()}"
        for p in sorted(PACKAGE.rglob("*.py")) if p.name != "paths.py"
        for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)
    ]
    assert offenders == []
