"""The weights content hash: written by the exporter, verified by the Rust loader, same bytes hashed."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from safetensors import safe_open

from nudge_train import paths
from nudge_train.models.config import student_config
from nudge_train.models.networks import build_model
from nudge_train.training.export import export_generator, read_weights, save_safetensors, stamp_weights, weights_sha256

REPO_ROOT = paths.repo()
SHIPPED = [
    REPO_ROOT / "assets" / "models" / "teacher.safetensors",
    REPO_ROOT / "assets" / "models" / "student.safetensors",
    REPO_ROOT / paths.GOLDEN_DIR / "weights_teacher_random.safetensors",
    REPO_ROOT / paths.GOLDEN_DIR / "weights_student_random.safetensors",
]


def _documented_hash(path: Path) -> str:
    """The documented layout, computed from the raw file bytes (independent of torch)."""
    raw = path.read_bytes()
    n = int.from_bytes(raw[:8], "little")
    header = json.loads(raw[8 : 8 + n])
    meta = header.pop("__metadata__")
    data = raw[8 + n :]
    h = hashlib.sha256()

    def field(b: bytes) -> None:
        h.update(len(b).to_bytes(8, "little"))
        h.update(b)

    field(b"nudge.weights/1")
    field(meta["config"].encode("utf-8"))
    for name in sorted(header, key=lambda k: k.encode("utf-8")):
        entry = header[name]
        begin, end = entry["data_offsets"]
        field(name.encode("utf-8"))
        field(entry["dtype"].encode("ascii"))
        h.update(len(entry["shape"]).to_bytes(8, "little"))
        for d in entry["shape"]:
            h.update(int(d).to_bytes(8, "little"))
        field(data[begin:end])
    return h.hexdigest()


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_shipped_files_carry_the_documented_hash(path: Path) -> None:
    with safe_open(str(path), "pt") as f:
        meta = f.metadata()
        tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 (safe_open API)
    assert meta["sha256"] == _documented_hash(path) == weights_sha256(meta["config"], tensors)
    read_weights(path)  # verifies


def test_exported_hash_is_accepted_by_the_rust_loader(tmp_path: Path) -> None:
    nudge = pytest.importorskip("nudge")
    gen, _ = build_model(student_config())
    path = export_generator(gen, student_config(), tmp_path / "s.safetensors", trained=False, provenance={})
    assert nudge.Predictor.load(path).name == "student"
    raw = bytearray(path.read_bytes())
    raw[-3] ^= 0x01  # a low mantissa bit of the last float: still finite
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="sha256"):
        read_weights(path)
    with pytest.raises(nudge.WeightsError, match="sha256 mismatch"):
        nudge.Predictor.load(path)


def test_stamp_keeps_tensor_bytes(tmp_path: Path) -> None:
    src = REPO_ROOT / "assets" / "models" / "student.safetensors"
    with safe_open(str(src), "pt") as f:
        meta = f.metadata()
        tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 (safe_open API)
    # The file as written before the hash existed, then stamped.
    old = tmp_path / "old.safetensors"
    save_safetensors(tensors, old, {k: v for k, v in meta.items() if k != "sha256"})
    assert stamp_weights(old) == meta["sha256"]
    assert old.read_bytes() == src.read_bytes()
    # Re-stamping a stamped file changes nothing.
    dst = tmp_path / "student.safetensors"
    shutil.copy(src, dst)
    assert stamp_weights(dst) == meta["sha256"]
    assert dst.read_bytes() == src.read_bytes()
