"""Training checkpoints with a content hash: ``last.pt`` (resume state) and ``best.pt`` (best
generator), written temp-then-rename.

A checkpoint is an ordinary ``torch.save`` file of a dict (tensors, nested dicts and lists,
numbers, strings) plus the entry ``content_sha256``: a sha256 over a canonical walk of every
other entry (keys sorted; each tensor's dtype, shape and raw bytes; numbers exactly). Loading
recomputes it, so a flipped bit anywhere in a tensor, a changed number or a missing entry is
refused, and then refuses non-finite floating-point tensors (a checkpoint that would resume
into NaN training).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import torch

from nudge_train.artefacts import atomic_write
from nudge_train.errors import ArtefactError

__all__ = ["CONTENT_HASH", "load_checkpoint", "save_checkpoint", "state_hash"]

CONTENT_HASH = "content_sha256"
"""Key of the content hash in a checkpoint dict."""


def _feed(h: Any, obj: Any) -> None:
    if isinstance(obj, torch.Tensor):
        t = obj.detach().to("cpu").contiguous()
        h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    elif isinstance(obj, dict):
        h.update(b"D%d" % len(obj))
        for k in sorted(obj, key=lambda k: (type(k).__name__, repr(k))):
            _feed(h, k)
            _feed(h, obj[k])
    elif isinstance(obj, (list, tuple)):
        h.update(b"L%d" % len(obj))
        for v in obj:
            _feed(h, v)
    elif isinstance(obj, bool) or obj is None:
        h.update(f"B{obj}".encode())
    elif isinstance(obj, int):
        h.update(f"I{obj};".encode())
    elif isinstance(obj, float):
        h.update(f"F{obj.hex()};".encode())
    elif isinstance(obj, str):
        b = obj.encode("utf-8")
        h.update(b"S%d:" % len(b) + b)
    else:
        raise TypeError(f"cannot hash a checkpoint entry of type {type(obj).__name__}")


def state_hash(state: dict[str, Any]) -> str:
    """Hex sha256 of a checkpoint dict without its ``content_sha256`` entry."""
    h = hashlib.sha256()
    _feed(h, {k: v for k, v in state.items() if k != CONTENT_HASH})
    return h.hexdigest()


def save_checkpoint(path: Path | str, state: dict[str, Any], before_rename: Callable[[], None] | None = None) -> Path:
    """Writes ``state`` with its content hash to ``path``, temp-then-rename; returns ``path``.
    ``before_rename`` (fault injection in tests) runs once the temp file is complete."""
    full = {**{k: v for k, v in state.items() if k != CONTENT_HASH}, CONTENT_HASH: state_hash(state)}

    def write(tmp: Path) -> None:
        torch.save(full, tmp)
        if before_rename is not None:
            before_rename()

    return atomic_write(path, write)


def _tensors(obj: Any, where: str) -> Iterator[tuple[str, torch.Tensor]]:
    if isinstance(obj, torch.Tensor):
        yield where, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _tensors(v, f"{where}/{k}" if where else str(k))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from _tensors(v, f"{where}[{i}]")


def load_checkpoint(path: Path | str) -> dict[str, Any]:
    """A checkpoint written by :func:`save_checkpoint`, verified (without the hash entry).

    Raises:
        FileNotFoundError: no such file.
        ArtefactError: naming the file: unreadable or not a checkpoint, no content hash, a hash
            mismatch (modified or damaged), or a non-finite tensor (named by its path in the dict).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unpickling failure means a corrupted file
        raise ArtefactError(path, f"corrupted or unreadable checkpoint ({err})") from None
    if not isinstance(state, dict):
        raise ArtefactError(path, f"not a checkpoint (a {type(state).__name__}, expected a dict)")
    stored = state.pop(CONTENT_HASH, None)
    if not isinstance(stored, str):
        raise ArtefactError(path, f"no content hash ({CONTENT_HASH}): not written by this version, or damaged")
    try:
        actual = state_hash(state)
    except TypeError as err:
        raise ArtefactError(path, f"unexpected entry: {err}") from None
    if actual != stored:
        raise ArtefactError(path, f"content hash mismatch: stored {stored[:16]}..., the content hashes to "
                            f"{actual[:16]}... (the file was modified or damaged)")
    for where, t in _tensors(state, ""):
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise ArtefactError(path, f"non-finite values in {where}: refusing a checkpoint that would resume "
                                "into NaN training")
    for key, v in state.items():
        if isinstance(v, float) and math.isnan(v):
            raise ArtefactError(path, f"{key} is NaN")
    return state
