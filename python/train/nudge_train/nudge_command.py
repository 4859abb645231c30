"""The ``nudge`` command as the CommonRoad tools run it: finding it, its assets argument, its
failures, and the world its CommonRoad runs use (shared by :mod:`nudge_train.commonroad_planner`
and the checker experiment)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from nudge_train import paths
from nudge_train.errors import NudgeTrainError

__all__ = ["CHECK_WORLD", "CommandError", "find_nudge", "run_solution"]

# The world of CommonRoad runs: the scenario's obstacles follow their recorded trajectories.
CHECK_WORLD = "log_replay"


class CommandError(NudgeTrainError, RuntimeError):
    """The ``nudge`` command failed or cannot be found: ``command`` (the argument list) and
    the reason (its exit status and the last lines of its stderr)."""

    def __init__(self, command: list[str], reason: str) -> None:
        self.command = command
        super().__init__(f"{' '.join(command[:2])} ...: {reason}")


def find_nudge(given: Path | None = None) -> Path:
    """The ``nudge`` command: ``given``, else ``<repo>/target/release/nudge`` when built, else
    ``nudge`` on ``PATH`` (the command of the installed wheel). Raises :class:`CommandError`
    naming what was tried."""
    if given is not None:
        if not Path(given).is_file():
            raise CommandError([str(given)], "not found (build it: make build)")
        return Path(given).absolute()
    built = paths.repo() / "target" / "release" / "nudge"
    if built.is_file():
        return built
    found = shutil.which("nudge")
    if found is None:
        raise CommandError(["nudge"], f"not found: neither {built} (make build) nor `nudge` on PATH (pip install "
                                      "the nudge-planner wheel)")
    return Path(found)


def _assets_args() -> list[str]:
    """``--assets DIR`` with the checkout's assets as an absolute path when they are there (so
    the command resolves its models wherever it runs), else nothing (the command's own)."""
    assets = paths.assets()
    if (assets / "models").is_dir():
        return ["--assets", str(assets.absolute())]
    return []


def run_solution(command: list[str], out: Path) -> Path:
    """Runs ``command`` (a ``nudge simulate --commonroad ...`` writing into ``out``) and returns
    the one solution file it wrote. Raises :class:`CommandError` naming the command when it
    cannot run, fails (its exit status and the last lines of its stderr) or writes no single
    solution."""
    try:
        done = subprocess.run(command, capture_output=True, text=True, check=False)
    except OSError as exc:
        raise CommandError(command, f"cannot run: {exc}") from None
    if done.returncode != 0:
        tail = " | ".join(done.stderr.strip().splitlines()[-3:]) or "no message"
        raise CommandError(command, f"exit status {done.returncode}: {tail}")
    sols = sorted(out.glob("solution_*.xml"))
    if len(sols) != 1:
        raise CommandError(command, f"expected one solution file in {out}, found {len(sols)}")
    return sols[0]
