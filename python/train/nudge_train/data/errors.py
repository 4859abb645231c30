"""Typed errors of the NGSIM data pipeline."""

from __future__ import annotations

from pathlib import Path


class DataError(Exception):
    """Bad input data: names the file and, where known, the row (1-based, header = row 1)."""

    def __init__(self, path: Path | str, message: str, row: int | None = None) -> None:
        self.path = str(path)
        self.row = row
        self.message = message
        where = f"{self.path}" if row is None else f"{self.path}, row {row}"
        super().__init__(f"{where}: {message}")
