"""Strict JSON reading: duplicate object keys are an error, not "last one wins".

Every JSON file or JSON string the training package reads (manifests, summaries, metrics rows,
model configs and provenance in weights metadata, distillation shard metadata) goes through
:func:`loads_json` / :func:`load_json`, so a duplicated key is refused with a
:class:`~nudge_train.errors.ConfigError` naming the file and the key.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any

from nudge_train.errors import ConfigError

__all__ = ["MAX_JSON_BYTES", "load_json", "loads_json", "read_checked"]

MAX_JSON_BYTES = 256 << 20
"""Largest JSON file :func:`load_json` reads (bytes): the largest the package writes (closed-loop
caches, records) are a few MB."""


class _Duplicate(Exception):
    def __init__(self, key: str) -> None:
        self.key = key


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _Duplicate(k)
        out[k] = v
    return out


def loads_json(text: str | bytes, source: Path | str) -> Any:
    """Parses ``text``; ``source`` names where it came from in errors (a file, or
    ``"<file>: <metadata key>"``).

    Raises:
        ConfigError: invalid JSON (with its line) or a duplicate key (naming it).
    """
    try:
        return json.loads(text, object_pairs_hook=_no_duplicates)
    except _Duplicate as dup:
        raise ConfigError(source, f"duplicate key {dup.key!r}", key=dup.key) from None
    except json.JSONDecodeError as err:
        raise ConfigError(source, f"not valid JSON: {err.msg} (line {err.lineno}, column {err.colno})") from None
    except (UnicodeDecodeError, RecursionError) as err:
        raise ConfigError(source, f"not valid JSON: {type(err).__name__}") from None


def read_checked(path: Path | str, max_bytes: int) -> bytes:
    """The bytes of ``path``, opened the checked way: a regular file (symbolic links followed) of
    at most ``max_bytes`` bytes, its type and size checked on the path before opening (a FIFO is
    never opened, so nothing blocks) and again on the open handle; the read stops after
    ``max_bytes + 1`` bytes, so a file that grows meanwhile is refused too.

    Raises:
        FileNotFoundError: no such file. ConfigError: naming the file, when it is not a regular
        file (a FIFO, device, socket or directory), larger than ``max_bytes``, or unreadable.
    """
    path = Path(path)

    def check(st: os.stat_result) -> None:
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(path, "not a regular file (a FIFO, device or directory is refused before reading)")
        if st.st_size > max_bytes:
            raise ConfigError(path, f"{st.st_size} bytes, more than the {max_bytes}-byte budget")

    try:
        check(path.stat())
        with open(path, "rb") as fh:
            check(os.fstat(fh.fileno()))
            data = fh.read(max_bytes + 1)
    except FileNotFoundError:
        raise
    except OSError as err:
        raise ConfigError(path, f"cannot read: {err}") from None
    if len(data) > max_bytes:
        raise ConfigError(path, f"more than the {max_bytes}-byte budget")
    return data


def load_json(path: Path | str, max_bytes: int = MAX_JSON_BYTES) -> Any:
    """Reads (by :func:`read_checked`, at most ``max_bytes``) and parses the JSON file ``path``
    (see :func:`loads_json`).

    Raises:
        FileNotFoundError: no such file. ConfigError: not a regular file, too large, unreadable,
        invalid or duplicate keys.
    """
    path = Path(path)
    return loads_json(read_checked(path, max_bytes), path)
