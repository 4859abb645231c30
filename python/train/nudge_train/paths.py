"""Where things are: the one resolver of the repository, data, runs, docs and asset paths.

Every default path of ``nudge-train`` and of the library comes from here. Two environment
variables override the defaults (read on every call, so a test or a shell can set them late):

* ``NUDGE_REPO``: the repository root. Default: the checkout that holds this package
  (``python/train/nudge_train`` three levels below the root), else the current directory (an
  installed, non-editable package).
* ``NUDGE_ASSETS``: the shipped assets (``models/``, ``scenes/``). Default ``<repo>/assets``. The
  rule is the one of every front end (``nudge_predictor::assets_dir``: the variable when set and
  not empty, else the shipped folder), and in a checkout the folder is the same as
  ``nudge.assets_dir()``'s (the package's ``python/nudge/assets`` links to ``<repo>/assets``).
* ``NUDGE_NGSIM``: the raw NGSIM material (see its PROVENANCE.md). Default
  ``../shared/data/ngsim`` beside the repository.

Derived from the repository root: ``data/processed`` (the processed NGSIM build and its planner
scenes), ``data/distill`` (the distillation set), ``runs/`` (training runs), ``docs/``,
``python/train/configs`` and ``target/criterion`` (Rust bench estimates).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = [
    "BENCH_SCENES",
    "ENV_ASSETS",
    "ENV_NGSIM",
    "ENV_REPO",
    "GOLDEN_DIR",
    "assets",
    "configs",
    "criterion",
    "data",
    "distill",
    "docs",
    "figures",
    "model_weights",
    "ngsim",
    "processed",
    "repo",
    "repo_relative",
    "results",
    "runs",
    "scenes",
    "shipped_scenes",
]

ENV_REPO = "NUDGE_REPO"
"""Environment variable overriding the repository root."""
ENV_ASSETS = "NUDGE_ASSETS"
"""Environment variable overriding the shipped-assets folder."""
ENV_NGSIM = "NUDGE_NGSIM"
"""Environment variable overriding the raw NGSIM folder."""

GOLDEN_DIR = Path("crates/predictor/tests/golden")
"""Repository-relative folder of the predictor's golden files (``nudge-train goldens``)."""
BENCH_SCENES = Path("crates/predictor/benches/data/scenes.safetensors")
"""Repository-relative file of the predictor benchmark's input scenes (``nudge-train goldens``)."""

_CHECKOUT = Path(__file__).resolve().parents[3]


def repo() -> Path:
    """The repository root: ``$NUDGE_REPO``, else this package's checkout, else the current
    directory."""
    env = os.environ.get(ENV_REPO)
    if env:
        return Path(env)
    if (_CHECKOUT / "python" / "train" / "nudge_train").is_dir():
        return _CHECKOUT
    return Path.cwd()


def assets() -> Path:
    """The shipped assets: ``$NUDGE_ASSETS`` (when not empty), else ``<repo>/assets``."""
    env = os.environ.get(ENV_ASSETS)
    return Path(env) if env else repo() / "assets"


def model_weights(name: str) -> Path:
    """The shipped weights file of ``name`` (``"teacher"`` or ``"student"``)."""
    return assets() / "models" / f"{name}.safetensors"


def shipped_scenes() -> Path:
    """The shipped real scenes (``nudge.scenario/1`` files)."""
    return assets() / "scenes"


def data() -> Path:
    """``<repo>/data``: processed data and the distillation set (generated, not committed)."""
    return repo() / "data"


def processed() -> Path:
    """``<repo>/data/processed``: the processed NGSIM build (``manifest.json`` and shards)."""
    return data() / "processed"


def scenes(split: str) -> Path:
    """``<repo>/data/processed/scenes/<split>``: every planner scenario of one split."""
    return processed() / "scenes" / split


def distill() -> Path:
    """``<repo>/data/distill``: the distillation set."""
    return data() / "distill"


def runs() -> Path:
    """``<repo>/runs``: training runs (checkpoints, metrics)."""
    return repo() / "runs"


def docs() -> Path:
    """``<repo>/docs``."""
    return repo() / "docs"


def results() -> Path:
    """``<repo>/docs/results``: the generated result tables."""
    return docs() / "results"


def figures() -> Path:
    """``<repo>/docs/figures``: the generated figures."""
    return docs() / "figures"


def configs() -> Path:
    """``<repo>/python/train/configs``: the training configurations (TOML)."""
    return repo() / "python" / "train" / "configs"


def criterion() -> Path:
    """``<repo>/target/criterion``: the Rust benches' saved estimates."""
    return repo() / "target" / "criterion"


def ngsim() -> Path:
    """The raw NGSIM material: ``$NUDGE_NGSIM``, else ``<repo>/../shared/data/ngsim``."""
    env = os.environ.get(ENV_NGSIM)
    return Path(env) if env else repo().parent / "shared" / "data" / "ngsim"


def repo_relative(path: Path) -> str:
    """``path`` relative to the repository when it lies inside it (as given or with symbolic links
    resolved), else as given: recorded provenance must not name a machine."""
    roots = (repo().absolute(), repo().resolve())
    for full in (Path(path).absolute(), Path(path).resolve()):
        for root in roots:
            if full.is_relative_to(root):
                return str(full.relative_to(root))
    return str(path)
