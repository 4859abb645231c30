"""Training checkpoints and reports: a content hash in every checkpoint verified on resume,
non-finite checkpoints and losses refused with a typed error, every file written
temp-then-rename, and a resume after a kill at any point giving the same final weights and the
same metrics rows as an uninterrupted run, bit for bit (docs/reliability_data.md)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from nudge_train.data.loader import WindowSet
from nudge_train.errors import ArtefactError, TrainingError
from nudge_train.models.config import teacher_config
from nudge_train.training.checkpoint import load_checkpoint, save_checkpoint
from nudge_train.training.config import TrainConfig
from nudge_train.training.log import read_metrics
from nudge_train.training.loop import train

MCFG = teacher_config().replace(pool_hidden_dim=16)


def _windows(n_windows: int = 24, seed: int = 0) -> WindowSet:
    rng = np.random.default_rng(seed)
    pos, offs, inter = [], [0], []
    t = np.arange(14, dtype=np.float64) * 0.3
    for _ in range(n_windows):
        n = int(rng.integers(1, 6))
        x0 = rng.uniform(-40, 40, n)
        x0[0] = 0.0
        lane = rng.integers(0, 4, n) * 3.7
        v = rng.uniform(8, 25, n)
        drift = rng.choice([0.0, 0.0, 0.8], n)
        p = np.stack([x0[:, None] + v[:, None] * t, lane[:, None] + drift[:, None] * t], axis=-1)
        pos.append(p.astype(np.float32))
        offs.append(offs[-1] + n)
        inter.append(int(drift.any()))
    return WindowSet(np.concatenate(pos), np.array(offs, np.int64), np.array(inter, np.uint8))


DATA = _windows(20)
VAL = _windows(6, seed=1)


def _tcfg(out: Path, **kw: object) -> TrainConfig:
    base = TrainConfig(out_dir=str(out), epochs=3, patience=5, batch_size=8, k_samples=2, lr=3e-3,
                       device="cpu", seed=3, i_adv=1, threads=1)
    return dataclasses.replace(base, **kw)


def _state(out: Path) -> dict[str, object]:
    """Both checkpoints, without the wall-clock ``seconds`` of the metrics rows (the one field
    that is not a function of the inputs)."""
    last = load_checkpoint(out / "last.pt")
    last["metrics"] = [{k: v for k, v in r.items() if k != "seconds"} for r in last["metrics"]]
    return {"last": last, "best": load_checkpoint(out / "best.pt")}


def _rows(out: Path) -> list[dict[str, object]]:
    return [{k: v for k, v in r.items() if k != "seconds"} for r in read_metrics(out)]


def _assert_same_tensors(a: object, b: object, where: str = "") -> None:
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype and a.shape == b.shape, where
        assert torch.equal(a, b), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), where
        for k in a:
            _assert_same_tensors(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where  # type: ignore[arg-type]
        for i, (x, y) in enumerate(zip(a, b)):  # type: ignore[call-overload]
            _assert_same_tensors(x, y, f"{where}[{i}]")
    else:
        assert a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b)), where  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "run"
    train(MCFG, _tcfg(out), train_set=DATA, val_set=VAL, progress=False)
    return out


def _largest_storage(path: Path) -> tuple[int, int]:
    """(offset, size) of the largest tensor storage inside a torch zip checkpoint."""
    with zipfile.ZipFile(path) as z:
        info = max((i for i in z.infolist() if "/data/" in i.filename), key=lambda i: i.file_size)
    raw = path.read_bytes()
    h = info.header_offset
    name_len = int.from_bytes(raw[h + 26:h + 28], "little")
    extra_len = int.from_bytes(raw[h + 28:h + 30], "little")
    return h + 30 + name_len + extra_len, info.file_size


def test_flipped_bytes_in_last_pt_are_refused_naming_the_file(tmp_path: Path, reference: Path) -> None:
    out = tmp_path / "run"
    train(MCFG, _tcfg(out, epochs=1), train_set=DATA, val_set=VAL, progress=False)
    last = out / "last.pt"
    start, size = _largest_storage(last)
    b = bytearray(last.read_bytes())
    b[start + size // 2 + 3] ^= 0x7F  # an exponent byte: the weight becomes huge or NaN
    last.write_bytes(bytes(b))
    with pytest.raises(ArtefactError, match=r"last\.pt: .*content hash") as ei:
        train(MCFG, _tcfg(out, epochs=2), resume=True, train_set=DATA, val_set=VAL, progress=False)
    assert ei.value.path == str(last)


def test_a_checkpoint_without_a_hash_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "last.pt"
    torch.save({"epoch": 0, "generator": {"w": torch.ones(3)}}, path)
    with pytest.raises(ArtefactError, match=r"last\.pt: no content hash"):
        load_checkpoint(path)


def test_non_finite_checkpoint_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "last.pt"
    save_checkpoint(path, {"epoch": 0, "generator": {"w": torch.tensor([1.0, float("nan")])}})
    with pytest.raises(ArtefactError, match=r"last\.pt: non-finite values in generator/w"):
        load_checkpoint(path)


def test_non_finite_loss_stops_with_an_error_naming_epoch_and_batch(tmp_path: Path) -> None:
    pos = DATA.positions.copy()
    w = int(np.flatnonzero(np.diff(DATA.offsets) >= 2)[0])
    pos[DATA.offsets[w] + 1, 8:] = 3e19  # a finite future whose squared error overflows float32
    bad = WindowSet(pos, DATA.offsets.copy(), DATA.interactive.copy())
    with pytest.raises(TrainingError, match=r"non-finite .*loss .*epoch 1, batch \d+") as ei:
        train(MCFG, _tcfg(tmp_path / "run", i_adv=0), train_set=bad, val_set=VAL, progress=False)
    assert ei.value.epoch == 0 and ei.value.batch is not None
    assert not (tmp_path / "run" / "last.pt").exists()


def test_every_checkpoint_and_report_is_written_temp_then_rename(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    direct: list[str] = []
    real_save = torch.save

    def spy_save(obj: object, f: object, *a: object, **k: object) -> None:
        if isinstance(f, (str, os.PathLike)) and not Path(f).name.startswith("."):
            direct.append(Path(f).name)
        real_save(obj, f, *a, **k)  # type: ignore[arg-type]

    real_write_text = Path.write_text

    def spy_write_text(self: Path, *a: object, **k: object) -> int:
        if not self.name.startswith("."):
            direct.append(self.name)
        return real_write_text(self, *a, **k)  # type: ignore[arg-type]

    monkeypatch.setattr(torch, "save", spy_save)
    monkeypatch.setattr(Path, "write_text", spy_write_text)
    out = tmp_path / "run"
    train(MCFG, _tcfg(out, epochs=2), train_set=DATA, val_set=VAL, progress=False)
    assert direct == [], f"written in place: {direct}"
    assert {p.name for p in out.iterdir()} == {"best.pt", "last.pt", "metrics.jsonl", "config.json", "summary.json"}


FAULTS = [("batch", 0, 1), ("validated", 0, None), ("best_written", 1, None), ("checkpoint_temp", 1, None),
          ("checkpoint", 0, None), ("metrics", 1, None), ("checkpoint", 2, None), ("batch", 2, 2)]


class _Crash(Exception):
    pass


@pytest.mark.parametrize(("point", "epoch", "batch"), FAULTS)
def test_resume_after_a_crash_at_any_point_is_bit_identical(tmp_path: Path, reference: Path, point: str,
                                                             epoch: int, batch: int | None) -> None:
    out = tmp_path / "run"

    def fault(p: str, e: int, b: int | None) -> None:
        if (p, e) == (point, epoch) and (batch is None or b == batch):
            raise _Crash(p)

    with pytest.raises(_Crash):
        train(MCFG, _tcfg(out), train_set=DATA, val_set=VAL, progress=False, fault_hook=fault)
    if (out / "last.pt").exists():
        train(MCFG, _tcfg(out), resume=True, train_set=DATA, val_set=VAL, progress=False)
    else:  # crashed before the first checkpoint: a resume has nothing to continue from
        with pytest.raises(FileNotFoundError):
            train(MCFG, _tcfg(out), resume=True, train_set=DATA, val_set=VAL, progress=False)
        train(MCFG, _tcfg(out), train_set=DATA, val_set=VAL, progress=False)
    _assert_same_tensors(_state(out), _state(reference))
    assert _rows(out) == _rows(reference)
    assert not list(out.glob(".*tmp*"))


_KILL = """
import os, signal, sys
from pathlib import Path
sys.path.insert(0, sys.argv[3])
import test_training_integrity as t
from nudge_train.training.loop import train
point, epoch = sys.argv[2].split(":")
def fault(p, e, b):
    if p == point and e == int(epoch):
        os.kill(os.getpid(), signal.SIGKILL)
extra = {"fault_hook": fault} if point != "none" else {}
train(t.MCFG, t._tcfg(Path(sys.argv[1])), train_set=t.DATA, val_set=t.VAL, progress=False, **extra)
"""


@pytest.mark.parametrize("where", ["checkpoint_temp:1", "checkpoint:1", "random"])
def test_kill_9_and_resume_is_bit_identical(tmp_path: Path, reference: Path, where: str) -> None:
    """A real SIGKILL: at a chosen point inside the process, or from outside as soon as the first
    epoch row is logged (wherever the process happens to be then)."""
    out = tmp_path / "run"
    here = str(Path(__file__).parent)
    if where == "random":
        proc = subprocess.Popen([sys.executable, "-c", _KILL, str(out), "none:0", here],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 300
        log = out / "metrics.jsonl"
        while not (log.exists() and log.stat().st_size > 0) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        rc = proc.wait(timeout=60)
    else:
        rc = subprocess.run([sys.executable, "-c", _KILL, str(out), where, here], capture_output=True,
                            timeout=300).returncode
        assert rc == -9
    resume = (out / "last.pt").exists()
    train(MCFG, _tcfg(out), resume=resume, train_set=DATA, val_set=VAL, progress=False)
    _assert_same_tensors(_state(out), _state(reference))
    assert _rows(out) == _rows(reference)
    assert not list(out.glob(".*tmp*"))
    assert rc in (-9, 0)


def test_metrics_file_never_holds_more_epochs_than_the_checkpoint(tmp_path: Path) -> None:
    """The defect: a kill between the metrics append and the checkpoint duplicated an epoch row."""
    out = tmp_path / "run"

    def fault(p: str, e: int, b: int | None) -> None:
        if p == "checkpoint_temp" and e == 1:
            raise _Crash(p)

    with pytest.raises(_Crash):
        train(MCFG, _tcfg(out), train_set=DATA, val_set=VAL, progress=False, fault_hook=fault)
    epochs = [r["epoch"] for r in read_metrics(out)]
    assert epochs == [0]
    assert int(load_checkpoint(out / "last.pt")["epoch"]) == 0
    train(MCFG, _tcfg(out), resume=True, train_set=DATA, val_set=VAL, progress=False)
    assert [r["epoch"] for r in read_metrics(out)] == [0, 1, 2]


def test_duplicate_keys_in_a_summary_are_refused(tmp_path: Path) -> None:
    from nudge_train.errors import ConfigError
    from nudge_train.jsonio import load_json

    p = tmp_path / "summary.json"
    p.write_text('{"best_epoch": 1, "best_epoch": 2}')
    with pytest.raises(ConfigError, match=r"summary\.json: duplicate key 'best_epoch'"):
        load_json(p)
    assert json.loads(p.read_text())["best_epoch"] == 2  # what the standard library would accept
