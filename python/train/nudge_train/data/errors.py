"""Typed errors of the NGSIM data pipeline, and the one way its readers open a source file."""

from __future__ import annotations

import gzip
import stat
import zlib
from pathlib import Path

from nudge_train.errors import NudgeTrainError

__all__ = ["DataError", "read_source"]


class DataError(NudgeTrainError):
    """Bad input data: names the file and, where known, the row (1-based, header = row 1; the
    line for XML) and the field (column or element)."""

    def __init__(self, path: Path | str, message: str, row: int | None = None, field: str | None = None) -> None:
        self.path = str(path)
        self.row = row
        self.field = field
        self.message = message
        where = f"{self.path}" if row is None else f"{self.path}, row {row}"
        super().__init__(f"{where}: {message}")


def read_source(path: Path) -> bytes:
    """The bytes of a source file, gunzipped when the name ends in ``.gz``.

    Raises:
        DataError: naming the file when it is missing, not a regular file (a FIFO or device would
        block or never end), unreadable, or a truncated or corrupted gzip stream.
    """
    try:
        st = path.stat()
    except OSError as exc:
        raise DataError(path, f"cannot read file: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise DataError(path, "not a regular file")
    try:
        if path.suffix == ".gz":
            with gzip.open(path, "rb") as fh:
                return fh.read()
        return path.read_bytes()
    except EOFError:
        raise DataError(path, "truncated gzip stream (the file ends before the end-of-stream marker)") from None
    except (gzip.BadGzipFile, zlib.error) as exc:
        raise DataError(path, f"corrupt gzip stream: {exc}") from None
    except OSError as exc:
        raise DataError(path, f"cannot read file: {exc}") from None
