"""Deterministic safetensors bytes, written temp-then-rename, with an optional content hash.

The ``safetensors`` library writes ``__metadata__`` entries in hash-map order, so two writes of
the same data can differ byte-wise (from one process to the next). :func:`write_safetensors`
emits the standard format (8-byte little-endian header length, JSON header, raw little-endian
C-order data) with the metadata keys sorted, tensors laid out in name order and the header padded
with spaces to a multiple of 8 bytes; :func:`canonicalize` rewrites the output of the library's
``save`` the same way (metadata sorted, tensor entries in data order, data untouched). Any
safetensors reader (Python ``safetensors``, Rust ``safetensors`` crate) reads both.

Content hash (:func:`add_content_hash`, :func:`verify_content_hash`): the metadata entry
``content_sha256`` = hex sha256 of (the canonical header JSON without that entry, unpadded)
followed by the data section. It covers every tensor byte, dtype, shape and offset and every
other metadata entry, so a flipped data byte or an edited metadata value is detected from the
file alone.
"""

from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

from safetensors.numpy import load as load_bytes

from nudge_train.artefacts import atomic_write_bytes
from nudge_train.errors import ArtefactError, ConfigError
from nudge_train.jsonio import loads_json

CONTENT_HASH = "content_sha256"
"""Metadata key of the content hash."""

DTYPES = {
    np.dtype(np.float64): "F64", np.dtype(np.float32): "F32", np.dtype(np.int64): "I64",
    np.dtype(np.int32): "I32", np.dtype(np.uint8): "U8", np.dtype(np.bool_): "BOOL",
}


def serialize(tensors: dict[str, np.ndarray], metadata: dict[str, str]) -> bytes:
    """The deterministic file bytes of ``tensors`` (name -> array of a dtype in DTYPES) and
    string ``metadata``."""
    header: dict[str, object] = {"__metadata__": {k: str(metadata[k]) for k in sorted(metadata)}}
    blobs = []
    offset = 0
    for name in sorted(tensors):
        arr = np.ascontiguousarray(tensors[name])
        if arr.dtype not in DTYPES:
            raise TypeError(f"tensor {name!r}: unsupported dtype {arr.dtype}")
        data = arr.astype(arr.dtype.newbyteorder("<"), copy=False).tobytes()
        header[name] = {"dtype": DTYPES[arr.dtype], "shape": list(arr.shape), "data_offsets": [offset, offset + len(data)]}
        blobs.append(data)
        offset += len(data)
    hb = json.dumps(header, separators=(",", ":")).encode("utf-8")
    hb += b" " * ((8 - len(hb) % 8) % 8)
    return struct.pack("<Q", len(hb)) + hb + b"".join(blobs)


def write_safetensors(path: Path | str, tensors: dict[str, np.ndarray], metadata: dict[str, str]) -> None:
    """Write ``tensors`` and ``metadata`` (see :func:`serialize`) to ``path``, temp-then-rename."""
    atomic_write_bytes(path, serialize(tensors, metadata))


def _is_entry(v: object) -> bool:
    if not isinstance(v, dict):
        return False
    offs = v.get("data_offsets")
    if not (isinstance(offs, list) and len(offs) == 2):
        return False
    return all(isinstance(x, int) and not isinstance(x, bool) for x in offs) and offs[0] <= offs[1]


def _split(raw: bytes, source: Path | str) -> tuple[dict[str, Any], bytes]:
    """(header, data section) of safetensors bytes; ArtefactError naming ``source`` if malformed."""
    if len(raw) < 8:
        raise ArtefactError(source, "not a safetensors file (shorter than 8 bytes)")
    n = int.from_bytes(raw[:8], "little")
    if n > len(raw) - 8:
        raise ArtefactError(source, f"header length {n} runs past the end of the file (truncated?)")
    try:
        header = loads_json(raw[8 : 8 + n], source)
    except ConfigError as err:
        raise ArtefactError(source, f"header: {err.message}") from None
    if not isinstance(header, dict) or not all(_is_entry(v) for k, v in header.items() if k != "__metadata__"):
        raise ArtefactError(source, "header is not a safetensors header")
    meta = header.get("__metadata__", {})
    if not isinstance(meta, dict) or not all(isinstance(v, str) for v in meta.values()):
        raise ArtefactError(source, "metadata must map strings to strings")
    return header, raw[8 + n :]


def _canonical_header(header: dict[str, Any]) -> bytes:
    out: dict[str, Any] = {}
    meta = header.get("__metadata__")
    if meta is not None:
        out["__metadata__"] = {k: meta[k] for k in sorted(meta)}
    names = sorted((k for k in header if k != "__metadata__"), key=lambda k: (header[k]["data_offsets"], k))
    for name in names:
        out[name] = header[name]
    return json.dumps(out, separators=(",", ":"), ensure_ascii=False).encode("utf-8")


def _assemble(header_json: bytes, data: bytes) -> bytes:
    padded = header_json + b" " * (-len(header_json) % 8)
    return len(padded).to_bytes(8, "little") + padded + data


def canonicalize(raw: bytes, source: Path | str = "<bytes>") -> bytes:
    """Safetensors bytes (e.g. from ``safetensors.numpy.save``) with the header rewritten in a
    fixed order (metadata keys sorted, tensor entries by data offset); the data is untouched."""
    header, data = _split(raw, source)
    return _assemble(_canonical_header(header), data)


def _content_hash(header: dict[str, Any], data: bytes) -> str:
    h = dict(header)
    meta = dict(h.get("__metadata__") or {})
    meta.pop(CONTENT_HASH, None)
    h["__metadata__"] = meta
    return hashlib.sha256(_canonical_header(h) + data).hexdigest()


def add_content_hash(raw: bytes, source: Path | str = "<bytes>") -> bytes:
    """Canonical safetensors bytes with the ``content_sha256`` metadata entry set."""
    header, data = _split(raw, source)
    meta = dict(header.get("__metadata__") or {})
    meta.pop(CONTENT_HASH, None)
    header = {**header, "__metadata__": meta}
    meta[CONTENT_HASH] = _content_hash(header, data)
    return _assemble(_canonical_header(header), data)


def verify_content_hash(raw: bytes, source: Path | str) -> dict[str, str]:
    """The metadata of safetensors bytes whose ``content_sha256`` matches their content.

    Raises:
        ArtefactError: naming ``source``: malformed, no content hash, a data section whose length
        does not match the header, or a hash mismatch (modified or damaged file).
    """
    header, data = _split(raw, source)
    meta: dict[str, str] = dict(header.get("__metadata__") or {})
    stored = meta.get(CONTENT_HASH)
    if stored is None:
        raise ArtefactError(source, f"no content hash ({CONTENT_HASH}) in its metadata")
    ends = [v["data_offsets"][-1] for k, v in header.items() if k != "__metadata__"]
    if max(ends, default=0) != len(data):
        raise ArtefactError(source, f"data section holds {len(data)} bytes, the header describes "
                            f"{max(ends, default=0)} (truncated or extended file)")
    actual = _content_hash(header, data)
    if actual != stored:
        raise ArtefactError(source, f"content hash mismatch: metadata says {stored[:16]}..., the content hashes "
                            f"to {actual[:16]}... (the file was modified or damaged)")
    return meta


def load_verified_shard(manifest_path: Path, entry: dict) -> tuple[Path, dict[str, np.ndarray]]:
    """(path, tensors) of the shard ``entry`` (``{file, sha256, ...}``) of the manifest at
    ``manifest_path``, after checking the file's sha256 against the entry's.

    Raises:
        FileNotFoundError: the shard is missing.
        ArtefactError: naming the shard: a name that is not a plain file name, no sha256 in the
            entry, a sha256 mismatch (modified or damaged file), or unparseable bytes.
    """
    rel = entry["file"]
    path = manifest_path.parent / rel
    if Path(rel).name != rel:
        raise ArtefactError(path, f"shard name {rel!r} in {manifest_path.name} is not a plain file name")
    if not path.exists():
        raise FileNotFoundError(f"shard listed in {manifest_path} is missing: {path}")
    expected = entry.get("sha256")
    if not isinstance(expected, str):
        raise ArtefactError(path, f"{manifest_path.name} records no sha256 for it (written by an older version: "
                            "rebuild or regenerate the set)")
    raw = path.read_bytes()
    actual = hashlib.sha256(raw).hexdigest()
    if actual != expected:
        raise ArtefactError(path, f"sha256 {actual[:16]}... does not match {expected[:16]}... recorded in "
                            f"{manifest_path.name} (the file was modified or damaged)")
    try:
        return path, load_bytes(raw)
    except Exception as err:  # noqa: BLE001 - the parser's own error types vary by version
        raise ArtefactError(path, f"not a readable safetensors file ({err})") from None
