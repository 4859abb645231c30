"""The library does not import the experiments: no module of ``nudge_train`` outside
``nudge_train/experiments/`` imports :mod:`nudge_train.experiments`, absolutely or relatively,
at module level or inside a function, nor names it to ``importlib.import_module``.

The one exemption is the command-line dispatcher ``nudge_train/cli.py``, whose subcommands run the
experiments (each imported inside its own subcommand). Read with :mod:`ast`, nothing imported."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "nudge_train"
FORBIDDEN = "nudge_train.experiments"
EXEMPT = {"nudge_train.cli": "the nudge-train command dispatches to the experiments"}


def module_name(path: Path, root: Path = PACKAGE) -> str:
    """Dotted name of the module at ``path`` under the package directory ``root``."""
    parts = [root.name, *path.relative_to(root).with_suffix("").parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def resolve(module: str, is_package: bool, level: int, target: str | None) -> str:
    """The absolute name a ``from`` import of ``target`` at relative ``level`` in ``module`` names
    (``level`` 0: ``target`` itself)."""
    if level == 0:
        return target or ""
    base = module.split(".")
    # In a package's __init__, "." is the package itself; in a module, its parent.
    drop = level - 1 if is_package else level
    if drop > len(base) - 1:
        raise ValueError(f"{module}: relative import beyond the top-level package")
    anchor = base[: len(base) - drop]
    return ".".join([*anchor, target] if target else anchor)


def _names(name: str) -> bool:
    return name == FORBIDDEN or name.startswith(FORBIDDEN + ".")


def experiment_imports(source: str, module: str, is_package: bool = False) -> list[tuple[int, str]]:
    """(line, imported name) of every import in ``source`` (module ``module``) that names
    :mod:`nudge_train.experiments` or a module in it."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if _names(a.name)]
        elif isinstance(node, ast.ImportFrom):
            base = resolve(module, is_package, node.level, node.module)
            if _names(base):
                found.append((node.lineno, base))
            else:
                # from nudge_train import experiments / from .. import experiments
                found += [(node.lineno, f"{base}.{a.name}") for a in node.names if _names(f"{base}.{a.name}")]
        elif isinstance(node, ast.Call) and node.args:
            f, arg = node.func, node.args[0]
            called = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            if called in ("import_module", "__import__") and isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                if _names(arg.value):
                    found.append((node.lineno, arg.value))
    return found


def library_modules() -> list[Path]:
    """Every module of the package outside ``experiments/``."""
    return sorted(p for p in PACKAGE.rglob("*.py") if "experiments" not in p.relative_to(PACKAGE).parts[:-1])


def test_no_library_module_imports_the_experiments() -> None:
    modules = library_modules()
    names = {module_name(p) for p in modules}
    # The walk covers the library (not vacuous): the training library and every other subpackage.
    for must in ("nudge_train.training.reaction", "nudge_train.training.loop", "nudge_train.distill.pipeline",
                 "nudge_train.data.build", "nudge_train.models.networks", "nudge_train.idm.fit", "nudge_train"):
        assert must in names, must
    assert not any(n.startswith(FORBIDDEN) for n in names)
    offenders = []
    for path in modules:
        name = module_name(path)
        if name in EXEMPT:
            continue
        for line, imported in experiment_imports(path.read_text(encoding="utf-8"), name, path.name == "__init__.py"):
            offenders.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {imported}")
    assert not offenders, "the library imports the experiments (move what it shares out of experiments/):\n" + "\n".join(offenders)


def test_the_exemptions_exist() -> None:
    for name in EXEMPT:
        assert (PACKAGE.parent / (name.replace(".", "/") + ".py")).is_file(), name


@pytest.mark.parametrize(
    ("source", "module", "is_package"),
    [
        ("import nudge_train.experiments.reaction", "nudge_train.training.reaction", False),
        ("import nudge_train.experiments as e", "nudge_train.training.reaction", False),
        ("from nudge_train.experiments.reaction import keep_lane", "nudge_train.training.reaction", False),
        ("from nudge_train.experiments import reaction", "nudge_train.training.reaction", False),
        ("from nudge_train import experiments", "nudge_train.training.reaction", False),
        ("from ..experiments.reaction import keep_lane", "nudge_train.training.reaction", False),
        ("from ..experiments import reaction", "nudge_train.training.reaction", False),
        ("from .. import experiments", "nudge_train.training.reaction", False),
        ("from .experiments import stats", "nudge_train", True),
        ("from . import experiments", "nudge_train.constants", False),
        ("def f():\n    from ..experiments import stats\n    return stats", "nudge_train.data.build", False),
        ("import importlib\nm = importlib.import_module('nudge_train.experiments.paper')", "nudge_train.paths", False),
    ],
)
def test_every_spelling_of_an_experiments_import_is_found(source: str, module: str, is_package: bool) -> None:
    assert len(experiment_imports(source, module, is_package)) == 1, source


@pytest.mark.parametrize(
    ("source", "module", "is_package"),
    [
        ("from nudge_train.training.reaction_measure import keep_lane", "nudge_train.training.reaction", False),
        ("from .reaction_measure import keep_lane", "nudge_train.training.reaction", False),
        ("from . import experiments_log", "nudge_train.training.reaction", False),
        ("import nudge_train.experimentsx", "nudge_train.paths", False),
        ("from .experiments import stats", "nudge_train.training", True),
        ('"""See nudge_train.experiments.reaction_cutins."""', "nudge_train.training.reaction_measure", False),
    ],
)
def test_other_imports_are_not_flagged(source: str, module: str, is_package: bool) -> None:
    assert experiment_imports(source, module, is_package) == [], source
