"""Integrity of the distillation set: a sha256 content hash in every shard and in the manifest,
verified on resume (a damaged shard is named and regenerated, never kept) and on load (a typed
error naming the file); byte-identical shards from two processes; temp-then-rename writes with
stale temp files removed on the next run (docs/reliability_data.md)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

nudge = pytest.importorskip("nudge", reason="the nudge extension is not built (run `make develop`)")

from safetensors import safe_open  # noqa: E402
from safetensors.numpy import load_file, save  # noqa: E402

from nudge_train.data.loader import load_split  # noqa: E402
from nudge_train.distill import pipeline as gen_mod  # noqa: E402
from nudge_train.distill.config import DistillConfig  # noqa: E402
from nudge_train.distill.pipeline import generate  # noqa: E402
from nudge_train.errors import ArtefactError  # noqa: E402
from nudge_train.provenance import sha256_file  # noqa: E402


@pytest.fixture(scope="module")
def scenes_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("scenes")
    (root / "test").mkdir()
    small = [p for p in nudge.scene_paths() if nudge.Scenario.load(p).n_agents <= 5][:3]
    assert len(small) == 3
    for p in small:
        shutil.copy(p, root / "test" / p.name)
    return root


def _cfg(out: Path, scenes_root: Path, **kw: object) -> DistillConfig:
    base = DistillConfig(out=out, splits=("test",), scenes_root=scenes_root, max_scenes={"test": None},
                         max_steps=2, scenes_per_shard=2, threads=1, progress=False)
    return replace(base, **kw)  # type: ignore[arg-type]


def _shard_bytes(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.glob("*.safetensors"))}


def _data_start(path: Path) -> int:
    return 8 + int.from_bytes(path.read_bytes()[:8], "little")


def _flip(path: Path, pos: int) -> None:
    b = bytearray(path.read_bytes())
    b[pos] ^= 0x40
    path.write_bytes(bytes(b))


@pytest.fixture
def counting(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    calls: list[str] = []
    real = gen_mod.compute_shard

    def wrapped(spec, *a, **k):  # type: ignore[no-untyped-def]
        calls.append(spec.file)
        return real(spec, *a, **k)

    monkeypatch.setattr(gen_mod, "compute_shard", wrapped)
    return calls


def test_every_shard_and_the_manifest_carry_content_hashes(tmp_path: Path, scenes_root: Path) -> None:
    cfg = _cfg(tmp_path / "d", scenes_root)
    m = generate(cfg, log=lambda _: None)
    shards = m["splits"]["test"]["shards"]
    assert len(shards) == 2
    for e in shards:
        path = cfg.out / e["file"]
        with safe_open(str(path), "numpy") as f:
            meta = f.metadata()
        assert re.fullmatch(r"[0-9a-f]{64}", meta["content_sha256"])
        assert e["content_sha256"] == meta["content_sha256"]
        assert e["sha256"] == sha256_file(path)
    on_disk = json.loads((cfg.out / "manifest.json").read_text())
    assert on_disk["splits"]["test"]["shards"] == shards


def test_resume_regenerates_a_shard_with_flipped_data_bytes(tmp_path: Path, scenes_root: Path,
                                                             counting: list[str]) -> None:
    cfg = _cfg(tmp_path / "d", scenes_root)
    m1 = generate(cfg, log=lambda _: None)
    good = _shard_bytes(cfg.out)
    victim = sorted(good)[0]
    path = cfg.out / victim
    size = path.stat().st_size
    _flip(path, (_data_start(path) + size) // 2)
    counting.clear()
    logs: list[str] = []
    m2 = generate(cfg, log=logs.append)
    assert counting == [victim], "the damaged shard must be regenerated, the intact one kept"
    assert any(victim in line and "content hash" in line for line in logs), logs
    assert _shard_bytes(cfg.out) == good
    assert m2["splits"]["test"]["examples"] == m1["splits"]["test"]["examples"]
    assert m2["last_run"]["replaced"] == [victim]


def test_resume_regenerates_a_shard_with_edited_metadata(tmp_path: Path, scenes_root: Path,
                                                          counting: list[str]) -> None:
    cfg = _cfg(tmp_path / "d", scenes_root)
    m1 = generate(cfg, log=lambda _: None)
    good = _shard_bytes(cfg.out)
    victim = sorted(good)[1]
    path = cfg.out / victim
    with safe_open(str(path), "numpy") as f:
        meta = dict(f.metadata())
    tensors = load_file(str(path))
    summary = json.loads(meta["summary"])
    summary["examples"] = 16775
    meta["summary"] = json.dumps(summary)
    path.write_bytes(save(tensors, metadata=meta))
    counting.clear()
    m2 = generate(cfg, log=lambda _: None)
    assert counting == [victim]
    assert m2["splits"]["test"]["examples"] == m1["splits"]["test"]["examples"] != 16775
    assert _shard_bytes(cfg.out) == good


def test_load_split_refuses_a_damaged_shard_naming_it(tmp_path: Path, scenes_root: Path) -> None:
    cfg = _cfg(tmp_path / "d", scenes_root)
    generate(cfg, log=lambda _: None)
    ws = load_split(cfg.out, "test")
    assert len(ws) > 0
    victim = sorted(_shard_bytes(cfg.out))[0]
    path = cfg.out / victim
    _flip(path, path.stat().st_size - 3)
    with pytest.raises(ArtefactError, match=rf"{re.escape(victim)}: .*sha256") as ei:
        load_split(cfg.out, "test")
    assert ei.value.path == str(path)
    # A manifest whose recorded hash does not match the shard is refused the same way.
    generate(cfg, log=lambda _: None)
    man = json.loads((cfg.out / "manifest.json").read_text())
    man["splits"]["test"]["shards"][1]["sha256"] = "0" * 64
    (cfg.out / "manifest.json").write_text(json.dumps(man))
    other = man["splits"]["test"]["shards"][1]["file"]
    with pytest.raises(ArtefactError, match=re.escape(other)):
        load_split(cfg.out, "test")


_GEN = """
import sys
from dataclasses import replace
from pathlib import Path
from nudge_train.distill.config import DistillConfig
from nudge_train.distill.pipeline import generate
out, scenes = Path(sys.argv[1]), Path(sys.argv[2])
cfg = DistillConfig(out=out, splits=("test",), scenes_root=scenes, max_scenes={"test": None},
                    max_steps=2, scenes_per_shard=2, threads=1, progress=False)
generate(cfg, log=lambda _: None)
"""


def test_two_processes_write_byte_identical_shards(tmp_path: Path, scenes_root: Path) -> None:
    outs = []
    for k, hashseed in enumerate(("1", "2")):
        out = tmp_path / f"p{k}"
        env = {**os.environ, "PYTHONHASHSEED": hashseed}
        subprocess.run([sys.executable, "-c", _GEN, str(out), str(scenes_root)], check=True, env=env,
                       capture_output=True, timeout=600)
        outs.append(out)
    a, b = (_shard_bytes(o) for o in outs)
    assert a and a == b
    ma, mb = (json.loads((o / "manifest.json").read_text())["splits"] for o in outs)
    assert ma == mb


def test_stale_temp_files_are_removed_on_the_next_run(tmp_path: Path, scenes_root: Path) -> None:
    cfg = _cfg(tmp_path / "d", scenes_root)
    cfg.out.mkdir(parents=True)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    pid = int(dead.stdout)
    stale = [cfg.out / f".test-00000.safetensors.tmp-{pid}", cfg.out / f".manifest.json.tmp-{pid}",
             cfg.out / ".manifest.json.tmp"]
    for p in stale:
        p.write_bytes(b"half a shard")
    logs: list[str] = []
    generate(cfg, log=logs.append)
    assert not [p for p in stale if p.exists()]
    assert not list(cfg.out.glob(".*tmp*"))
    assert any("stale" in line for line in logs)


def test_a_kill_during_a_shard_write_leaves_only_a_temp_file(tmp_path: Path, scenes_root: Path) -> None:
    """kill -9 while the first shard's bytes are being written: no file under the final name; the
    next run removes the temp file and writes the same shards as an uninterrupted run."""
    ref = _cfg(tmp_path / "ref", scenes_root)
    generate(ref, log=lambda _: None)
    out = tmp_path / "k"
    script = _GEN.replace("generate(cfg", """
import os, signal
from nudge_train import artefacts
real = artefacts._write_temp
def dying(tmp, data):
    tmp.write_bytes(data[: len(data) // 2])
    os.kill(os.getpid(), signal.SIGKILL)
artefacts._write_temp = dying
generate(cfg""")
    r = subprocess.run([sys.executable, "-c", script, str(out), str(scenes_root)], capture_output=True, timeout=600)
    assert r.returncode == -9
    assert list(out.glob(".*tmp-*")) and not list(out.glob("*.safetensors"))
    generate(_cfg(out, scenes_root), log=lambda _: None)
    assert not list(out.glob(".*tmp*"))
    assert _shard_bytes(out) == _shard_bytes(ref.out)
    assert np.array_equal(load_split(out, "test").positions, load_split(ref.out, "test").positions)
