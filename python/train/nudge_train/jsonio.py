"""Strict JSON reading: duplicate object keys are an error, not "last one wins".

Every JSON file or JSON string the training package reads (manifests, summaries, metrics rows,
model configs and provenance in weights metadata, distillation shard metadata) goes through
:func:`loads_json` / :func:`load_json`, so a duplicated key is refused with a
:class:`~nudge_train.errors.ConfigError` naming the file and the key.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from nudge_train.errors import ConfigError

__all__ = ["load_json", "loads_json"]


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


def load_json(path: Path | str) -> Any:
    """Reads and parses the JSON file ``path`` (see :func:`loads_json`).

    Raises:
        FileNotFoundError: no such file. ConfigError: unreadable, invalid or duplicate keys.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise
    except OSError as err:
        raise ConfigError(path, f"cannot read: {err}") from None
    return loads_json(data, path)
