"""Tests of the safetensors export format (nudge.weights/1)."""

from __future__ import annotations

from collections.abc import Iterator
import json
from pathlib import Path

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file

from nudge_train.constants import WEIGHTS_FORMAT
from nudge_train.models.config import ModelConfig, student_config, teacher_config
from nudge_train.models.interactive import student_interactive, teacher_interactive
from nudge_train.models.networks import build_model
from nudge_train.training.export import export_generator, load_generator, read_weights, save_safetensors


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """Single-threaded torch: these small ops only slow down with threads on a shared machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize("cfg", [teacher_config(), student_config()], ids=["teacher", "student"])
def test_round_trip_is_bit_exact(tmp_path: Path, cfg: ModelConfig) -> None:
    gen, _ = build_model(cfg)
    with torch.no_grad():  # make it differ from a fresh init so loading really matters
        for p in gen.parameters():
            p.add_(torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())) * 0.01)
    path = export_generator(gen, cfg, tmp_path / "g.safetensors", trained=True, provenance={"run": "test", "epoch": 3})
    loaded = load_generator(path)
    assert loaded.cfg == cfg
    assert not loaded.training
    ref, got = gen.state_dict(), loaded.state_dict()
    assert list(ref) == list(got)
    for name in ref:
        assert torch.equal(ref[name], got[name]), name
    history = torch.randn(4, 8, 2, generator=torch.Generator().manual_seed(0)).cumsum(1)
    cands = history[0, -1] + torch.randn(3, 6, 2, generator=torch.Generator().manual_seed(1)).cumsum(1)
    fn = teacher_interactive if cfg.kind == "teacher" else student_interactive
    assert torch.equal(fn(gen, history, cands), fn(loaded, history, cands))


def test_metadata_and_dtypes(tmp_path: Path) -> None:
    cfg = teacher_config()
    gen, _ = build_model(cfg)
    path = export_generator(gen, cfg, tmp_path / "t.safetensors", trained=False, provenance={"init": "random"})
    with safe_open(str(path), "pt") as f:
        meta = f.metadata()
        assert meta["format"] == WEIGHTS_FORMAT
        assert meta["trained"] == "false"
        assert json.loads(meta["provenance"]) == {"init": "random"}
        assert ModelConfig.from_json(meta["config"]) == cfg
        assert set(f.keys()) == set(gen.state_dict())
        assert all(f.get_tensor(k).dtype == torch.float32 for k in f.keys())  # noqa: SIM118
    weights = read_weights(path)
    assert (weights.trained, weights.provenance, weights.config) == (False, {"init": "random"}, cfg)


def test_export_is_byte_reproducible(tmp_path: Path) -> None:
    cfg = student_config()
    gen, _ = build_model(cfg)
    a = export_generator(gen, cfg, tmp_path / "a.safetensors", trained=False, provenance={"b": 1, "a": 2})
    b = export_generator(gen, cfg, tmp_path / "b.safetensors", trained=False, provenance={"a": 2, "b": 1})
    assert a.read_bytes() == b.read_bytes()
    # header: 8-byte length, then JSON padded to a multiple of 8, metadata keys sorted
    raw = a.read_bytes()
    n = int.from_bytes(raw[:8], "little")
    assert n % 8 == 0
    header = json.loads(raw[8 : 8 + n])
    assert list(header["__metadata__"]) == sorted(header["__metadata__"])


def test_save_safetensors_zero_size_tensor(tmp_path: Path) -> None:
    path = save_safetensors({"e": torch.zeros(4, 0, 6, 2), "x": torch.ones(3)}, tmp_path / "z.safetensors", {"k": "v"})
    with safe_open(str(path), "pt") as f:
        assert f.get_tensor("e").shape == (4, 0, 6, 2)
        assert torch.equal(f.get_tensor("x"), torch.ones(3))


def test_export_rejects_mismatched_config_and_nan(tmp_path: Path) -> None:
    gen, _ = build_model(student_config())
    with pytest.raises(ValueError, match="config"):
        export_generator(gen, teacher_config(), tmp_path / "x.safetensors", trained=False, provenance={})
    with torch.no_grad():
        gen.decoder.hidden2pos.bias[0] = float("nan")
    with pytest.raises(ValueError, match="decoder.hidden2pos.bias"):
        export_generator(gen, student_config(), tmp_path / "x.safetensors", trained=False, provenance={})


def _write(tmp_path: Path, tensors: dict[str, torch.Tensor], metadata: dict[str, str]) -> Path:
    path = tmp_path / "w.safetensors"
    save_file(tensors, str(path), metadata=metadata)
    return path


def _valid(cfg: ModelConfig) -> tuple[dict[str, torch.Tensor], dict[str, str]]:
    gen, _ = build_model(cfg)
    tensors = {k: v.clone() for k, v in gen.state_dict().items()}
    meta = {"format": WEIGHTS_FORMAT, "config": cfg.to_json(), "trained": "false", "provenance": "{}"}
    return tensors, meta


def test_load_names_the_first_problem(tmp_path: Path) -> None:
    cfg = student_config()
    tensors, meta = _valid(cfg)
    assert load_generator(_write(tmp_path, tensors, meta)).cfg == cfg

    missing = dict(tensors)
    del missing["decoder.mlp.2.bias"]
    with pytest.raises(ValueError, match=r"decoder\.mlp\.2\.bias missing"):
        load_generator(_write(tmp_path, missing, meta))

    wrong = dict(tensors)
    wrong["pool_net.mlp_pre_pool.0.weight"] = torch.zeros(16, 31)
    with pytest.raises(ValueError, match=r"pool_net\.mlp_pre_pool\.0\.weight has shape \[16, 31\], expected \[16, 32\]"):
        load_generator(_write(tmp_path, wrong, meta))

    extra = {**tensors, "decoder.extra": torch.zeros(2)}
    with pytest.raises(ValueError, match=r"unexpected tensor decoder\.extra"):
        load_generator(_write(tmp_path, extra, meta))

    half = {**tensors, "decoder.hidden2pos.bias": torch.zeros(2, dtype=torch.float16)}
    with pytest.raises(ValueError, match="float32"):
        load_generator(_write(tmp_path, half, meta))

    with pytest.raises(ValueError, match="format"):
        load_generator(_write(tmp_path, tensors, {**meta, "format": "other/1"}))
    with pytest.raises(ValueError, match="'config' missing"):
        load_generator(_write(tmp_path, tensors, {k: v for k, v in meta.items() if k != "config"}))
    with pytest.raises(ValueError, match="trained"):
        load_generator(_write(tmp_path, tensors, {**meta, "trained": "yes"}))
    bad_cfg = json.loads(meta["config"])
    bad_cfg["noise_dim"] = 16
    with pytest.raises(ValueError, match="^noise_dim:"):
        load_generator(_write(tmp_path, tensors, {**meta, "config": json.dumps(bad_cfg)}))
    with pytest.raises(FileNotFoundError):
        load_generator(tmp_path / "absent.safetensors")
