"""Writing artefacts safely: temp-then-rename, stale temp files, content hashes.

Every file the training package writes (processed-data shards and manifest, planner scenarios,
distillation shards and manifest, checkpoints, summaries, metrics, weights exports, reports) goes
through :func:`atomic_write_bytes` or :func:`atomic_write_text`: the bytes are written to
``.<name>.tmp-<pid>`` in the same folder, flushed to disk and renamed over the final name, so a
file under its final name is always complete. A process killed mid-write leaves only its temp
file; :func:`remove_stale_temps` (called at the start of every build, generation and training
run) deletes those whose process is gone.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "remove_stale_temps", "sha256_bytes",
           "temp_path"]

_TEMP = re.compile(r"^\..+\.tmp(?:-(\d+))?$")


def temp_path(path: Path) -> Path:
    """The temp name of ``path`` for this process: ``.<name>.tmp-<pid>`` in the same folder."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def _write_temp(tmp: Path, data: bytes) -> None:
    with open(tmp, "wb") as fh:
        fh.write(data)


def atomic_write(path: Path | str, write: Callable[[Path], None]) -> Path:
    """Calls ``write(tmp)`` to fill the temp file, fsyncs it and renames it to ``path``; on any
    failure the temp file is removed and the error propagates (``path`` is untouched)."""
    path = Path(path)
    tmp = temp_path(path)
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def atomic_write_bytes(path: Path | str, data: bytes) -> Path:
    """Writes ``data`` to ``path`` temp-then-rename (see the module doc); returns ``path``."""
    return atomic_write(path, lambda tmp: _write_temp(tmp, data))


def atomic_write_text(path: Path | str, text: str) -> Path:
    """Writes UTF-8 ``text`` to ``path`` temp-then-rename; returns ``path``."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temps(folder: Path | str) -> list[str]:
    """Deletes the temp files (``.<name>.tmp-<pid>``, and the pid-less ``.<name>.tmp`` of older
    versions) in ``folder`` whose writing process is no longer alive; returns their names."""
    folder = Path(folder)
    removed: list[str] = []
    if not folder.is_dir():
        return removed
    for p in sorted(folder.iterdir()):
        m = _TEMP.match(p.name)
        if m is None or not p.is_file():
            continue
        if m.group(1) is not None and _alive(int(m.group(1))):
            continue
        p.unlink(missing_ok=True)
        removed.append(p.name)
    return removed


def sha256_bytes(data: bytes) -> str:
    """Hex sha256 of ``data``."""
    return hashlib.sha256(data).hexdigest()
