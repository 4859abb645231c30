"""The ``nudge`` command (``python -m nudge``): the Rust command line of the ``nudge`` binary,
run in this process with this package's assets (:data:`nudge.SHIPPED_ASSETS`, overridden by
``$NUDGE_ASSETS`` or ``--assets``). Same subcommands, output and exit statuses: 0 every run ran,
1 refused before any run, 2 the command line does not parse, 3 some runs could not run."""

from __future__ import annotations

import signal
import sys

from nudge import SHIPPED_ASSETS
from nudge._native import cli_main


def main() -> int:
    """Runs ``nudge`` on ``sys.argv``; returns the exit status."""
    # Like the binary, Ctrl-C ends the process (Python's handler would wait for the command).
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    return cli_main(["nudge", *sys.argv[1:]], SHIPPED_ASSETS)


if __name__ == "__main__":
    sys.exit(main())
