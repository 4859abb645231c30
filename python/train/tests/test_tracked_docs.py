"""No `nudge-train` command overwrites a tracked document unless asked: every output argument
whose default lies under docs/ is marked, and `main` moves an unnamed one to runs/reports/ (a
named one is written where named)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from nudge_train import cli, paths


def _actions(parser: argparse.ArgumentParser, where: str = "nudge-train"):  # noqa: ANN202
    for action in parser._actions:  # noqa: SLF001 (argparse keeps no public list)
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for name, sub in action.choices.items():
                yield from _actions(sub, f"{where} {name}")
        else:
            yield where, action


def _under_docs(value: object) -> bool:
    if not isinstance(value, (str, Path)) or not str(value):
        return False
    docs = paths.docs().absolute()
    return Path(value).absolute().is_relative_to(docs)


def test_every_default_under_docs_is_marked() -> None:
    unmarked = [f"{where} {'/'.join(a.option_strings)}" for where, a in _actions(cli.build_parser())
                if _under_docs(a.default) and not isinstance(a.default, (cli._DocPath, cli._DocStr))]  # noqa: SLF001
    assert not unmarked, f"outputs under docs/ written by default: {unmarked}"


@pytest.mark.parametrize(("argv", "key", "tracked"), [
    (["teacher"], "report", "results/teacher.md"),
    (["reaction"], "report", "results/reaction.md"),
    (["bench", "latency"], "out", "results/latency.md"),
    (["idm", "fit"], "doc", "results/idm_fit.md"),
    (["idm", "fit"], "figures", "figures"),
])
def test_an_unnamed_output_goes_to_runs_reports(argv: list[str], key: str, tracked: str,
                                                capsys: pytest.CaptureFixture) -> None:
    args = cli.build_parser().parse_args(argv)
    assert Path(getattr(args, key)) == paths.docs() / tracked
    cli._redirect_tracked_defaults(args)  # noqa: SLF001
    assert Path(getattr(args, key)) == paths.runs() / "reports" / tracked
    assert f"{tracked}" in capsys.readouterr().err
    named = cli.build_parser().parse_args([*argv, f"--{key}", str(paths.docs() / tracked)])
    cli._redirect_tracked_defaults(named)  # noqa: SLF001
    assert Path(getattr(named, key)) == paths.docs() / tracked
