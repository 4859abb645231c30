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


def read_source(path: Path, max_bytes: int | None = None) -> bytes:
    """The bytes of a source file, gunzipped when the name ends in ``.gz``.

    ``max_bytes`` (None: no budget) bounds the bytes returned, after decompression: a plain file
    larger than it is refused before reading and a gzip stream is inflated by at most
    ``max_bytes + 1`` bytes, so a small file that inflates to gigabytes is refused early.

    Raises:
        DataError: naming the file when it is missing, not a regular file (a FIFO or device would
        block or never end), unreadable, a truncated or corrupted gzip stream, or (naming the
        budget) larger than ``max_bytes``.
    """
    def too_big() -> DataError:
        return DataError(path, f"exceeds the size budget of {max_bytes} bytes (after decompression)")

    try:
        st = path.stat()
    except OSError as exc:
        raise DataError(path, f"cannot read file: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise DataError(path, "not a regular file")
    limit = -1 if max_bytes is None else max_bytes + 1
    try:
        if path.suffix == ".gz":
            with gzip.open(path, "rb") as fh:
                data = fh.read(limit)
        else:
            if max_bytes is not None and st.st_size > max_bytes:
                raise too_big()
            with open(path, "rb") as fh:
                data = fh.read(limit)
    except EOFError:
        raise DataError(path, "truncated gzip stream (the file ends before the end-of-stream marker)") from None
    except (gzip.BadGzipFile, zlib.error) as exc:
        raise DataError(path, f"corrupt gzip stream: {exc}") from None
    except OSError as exc:
        raise DataError(path, f"cannot read file: {exc}") from None
    if max_bytes is not None and len(data) > max_bytes:
        raise too_big()
    return data
