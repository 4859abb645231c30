"""Export and load generator weights as ``.safetensors`` (format ``nudge.weights/1``).

File layout: every tensor of ``TrajectoryGenerator.state_dict()`` under its PyTorch name, float32,
little-endian; metadata (all strings):

* ``format``: ``"nudge.weights/1"``
* ``config``: :meth:`ModelConfig.to_json` (sizes, kind, seeds, ...)
* ``trained``: ``"true"`` or ``"false"`` (random initialisation)
* ``provenance``: JSON object, free form (data, run, commit, ...)
* ``sha256``: content hash of the config and the tensors (:func:`weights_sha256`); the Rust loader
  refuses files without it or whose content does not match it

The Rust predictor reads the same files; docs/models.md lists every name and shape.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import torch
from safetensors import safe_open
from safetensors.torch import save as save_bytes

from nudge_train.artefacts import atomic_write_bytes
from nudge_train.constants import WEIGHTS_FORMAT
from nudge_train.data.st_io import canonicalize
from nudge_train.errors import ConfigError
from nudge_train.jsonio import loads_json
from nudge_train.models.config import ModelConfig
from nudge_train.models.networks import TrajectoryGenerator, build_model

__all__ = [
    "WeightsFile",
    "export_generator",
    "load_generator",
    "read_weights",
    "save_safetensors",
    "stamp_weights",
    "weights_sha256",
]


def save_safetensors(tensors: dict[str, torch.Tensor], path: Path, metadata: dict[str, str]) -> Path:
    """``safetensors.torch.save_file`` with byte-for-byte reproducible output, written
    temp-then-rename.

    The safetensors library writes the ``__metadata__`` entries in hash-map order, which changes
    from one process to the next; this rewrites the header with the metadata keys sorted (tensor
    entries and data untouched, :func:`nudge_train.data.st_io.canonicalize`), so regenerating a
    file gives identical bytes.
    """
    raw = save_bytes({k: tensors[k] for k in sorted(tensors)}, metadata=metadata)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, canonicalize(raw, path))
    return path


def weights_sha256(config_json: str, tensors: dict[str, torch.Tensor]) -> str:
    """Content hash of a weights file: 64 lowercase hex digits.

    SHA-256 over these fields, each preceded by its byte length as a u64 little endian: the
    format string ``nudge.weights/1``; the ``config`` metadata string (UTF-8, as stored); then for
    every tensor in ascending byte order of its name: the name (UTF-8), the dtype name ``F32``, the
    shape (here: the dimension count, then each dimension, all u64 little endian) and the raw
    little-endian data bytes. The same layout is documented and verified in Rust
    (``crates/predictor/src/weights.rs``); ``trained`` and ``provenance`` are not covered.
    """
    h = hashlib.sha256()

    def field(data: bytes) -> None:
        h.update(len(data).to_bytes(8, "little"))
        h.update(data)

    field(WEIGHTS_FORMAT.encode("utf-8"))
    field(config_json.encode("utf-8"))
    for name in sorted(tensors, key=lambda n: n.encode("utf-8")):
        tensor = tensors[name].detach().to("cpu").contiguous()
        if tensor.dtype != torch.float32:
            raise ValueError(f"{name}: dtype {tensor.dtype}, expected float32")
        field(name.encode("utf-8"))
        field(b"F32")
        h.update(len(tensor.shape).to_bytes(8, "little"))
        for dim in tensor.shape:
            h.update(int(dim).to_bytes(8, "little"))
        field(tensor.numpy().astype("<f4", copy=False).tobytes())
    return h.hexdigest()


def stamp_weights(path: Path) -> str:
    """Adds (or refreshes) the ``sha256`` entry of an existing weights file, tensors untouched.

    For files written before the hash existed; returns the hash.
    """
    path = Path(path)
    with safe_open(str(path), framework="pt", device="cpu") as f:
        metadata = dict(f.metadata() or {})
        tensors = {name: f.get_tensor(name) for name in f.keys()}  # noqa: SIM118 (safe_open API)
    if "config" not in metadata:
        raise ValueError(f"{path}: metadata key 'config' missing")
    metadata["sha256"] = weights_sha256(metadata["config"], tensors)
    save_safetensors(tensors, path, metadata)
    return metadata["sha256"]


class WeightsFile:
    """Tensors and parsed metadata of one weights file (see :func:`read_weights`)."""

    def __init__(
        self, config: ModelConfig, trained: bool, provenance: dict[str, Any], tensors: dict[str, torch.Tensor]
    ) -> None:
        self.config = config
        self.trained = trained
        self.provenance = provenance
        self.tensors = tensors


def export_generator(
    gen: TrajectoryGenerator,
    cfg: ModelConfig,
    path: Path,
    trained: bool,
    provenance: dict[str, Any],
) -> Path:
    """Writes ``gen``'s state_dict (float32, CPU, contiguous) with the metadata above.

    Raises:
        ValueError: ``cfg`` differs from the generator's own config, or a tensor is not finite.
    """
    cfg.validate()
    if gen.cfg != cfg:
        raise ValueError(f"config: generator was built with {gen.cfg}, asked to export as {cfg}")
    tensors: dict[str, torch.Tensor] = {}
    for name, value in gen.state_dict().items():
        tensor = value.detach().to("cpu", torch.float32).contiguous().clone()
        if not torch.isfinite(tensor).all():
            raise ValueError(f"{name}: contains NaN or infinite values")
        tensors[name] = tensor
    metadata = {
        "format": WEIGHTS_FORMAT,
        "config": cfg.to_json(),
        "trained": "true" if trained else "false",
        "provenance": json.dumps(provenance, sort_keys=True, separators=(",", ":")),
    }
    metadata["sha256"] = weights_sha256(metadata["config"], tensors)
    return save_safetensors(tensors, Path(path), metadata)


def read_weights(path: Path) -> WeightsFile:
    """Reads a weights file and parses its metadata (no model is built).

    Raises:
        ValueError: missing/wrong metadata or tensors that are not float32.
        ConfigError (a ValueError): the config or provenance entry is not JSON or repeats a key
            (naming the file, the entry and the key).
        FileNotFoundError: no such file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"weights file not found: {path}")
    with safe_open(str(path), framework="pt", device="cpu") as f:
        metadata = f.metadata() or {}
        tensors = {name: f.get_tensor(name) for name in f.keys()}  # noqa: SIM118 (safe_open API)
    for key in ("format", "config", "trained", "provenance"):
        if key not in metadata:
            raise ValueError(f"{path}: metadata key {key!r} missing")
    if metadata["format"] != WEIGHTS_FORMAT:
        raise ValueError(f"{path}: format {metadata['format']!r}, expected {WEIGHTS_FORMAT!r}")
    if metadata["trained"] not in ("true", "false"):
        raise ValueError(f"{path}: trained must be 'true' or 'false', got {metadata['trained']!r}")
    try:
        provenance = loads_json(metadata["provenance"], "provenance")
        config_data = loads_json(metadata["config"], "config")
    except ConfigError as err:
        raise ConfigError(path, f"{err.path}: {err.message}", key=err.key) from None
    if not isinstance(provenance, dict):
        raise ValueError(f"{path}: provenance must be a JSON object")
    config = ModelConfig.from_dict(config_data)
    for name, tensor in tensors.items():
        if tensor.dtype != torch.float32:
            raise ValueError(f"{path}: tensor {name} has dtype {tensor.dtype}, expected float32")
    if "sha256" in metadata:
        found = weights_sha256(metadata["config"], tensors)
        if found != metadata["sha256"]:
            raise ValueError(f"{path}: content sha256 mismatch: metadata {metadata['sha256']}, content {found}")
    return WeightsFile(config, metadata["trained"] == "true", provenance, tensors)


def load_generator(path: Path, device: torch.device | str = "cpu") -> TrajectoryGenerator:
    """Rebuilds the generator from the file's config and loads its tensors (in eval mode).

    Raises:
        ValueError: naming the first missing, unexpected or mis-shaped tensor.
    """
    weights = read_weights(path)
    gen, _ = build_model(weights.config, "cpu")
    expected = gen.state_dict()
    for name, ref in expected.items():
        if name not in weights.tensors:
            raise ValueError(f"{path}: tensor {name} missing (expected shape {list(ref.shape)})")
        got = weights.tensors[name]
        if got.shape != ref.shape:
            raise ValueError(
                f"{path}: tensor {name} has shape {list(got.shape)}, expected {list(ref.shape)}"
            )
    unexpected = sorted(set(weights.tensors) - set(expected))
    if unexpected:
        raise ValueError(f"{path}: unexpected tensor {unexpected[0]}")
    gen.load_state_dict(weights.tensors, strict=True)
    return gen.to(device).eval()
