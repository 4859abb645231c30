"""The ``nudge`` command of the Python package (``nudge.__main__``, installed as a console
script) is the Rust command line of the ``nudge`` binary: the same subcommands, text and exit
statuses (0, 1, 2, 3); its assets default to the package's own (``nudge.SHIPPED_ASSETS``), and
both follow ``$NUDGE_ASSETS`` by the one Rust rule (``nudge_predictor::assets_dir``). The binary
is ``$NUDGE_CLI``, else ``target/release/nudge``."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import nudge

SCRIPT = Path(sys.executable).with_name("nudge")


def _default_sigint() -> None:
    """In the child before exec: SIGINT back to its default disposition (a parent that ignores
    it, such as a background job of a non-interactive shell, would otherwise pass that on)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _binary(repo: Path) -> Path:
    exe = Path(os.environ.get("NUDGE_CLI", repo / "target" / "release" / "nudge"))
    exe = exe if exe.is_absolute() else repo / exe
    assert exe.is_file(), f"the nudge CLI is not built at {exe} (cargo build --release, or set NUDGE_CLI)"
    return exe


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "NUDGE_ASSETS"}
    return {**env, **extra}


def _both(repo: Path, cwd: Path, *args: str, env: dict[str, str] | None = None
          ) -> tuple[subprocess.CompletedProcess[str], subprocess.CompletedProcess[str]]:
    """(the binary run from the repository root, the package's command run from ``cwd``)."""
    assert SCRIPT.is_file(), f"the package's nudge command is not installed at {SCRIPT} (make develop)"
    run = lambda exe, where: subprocess.run([str(exe), *args], capture_output=True, text=True,  # noqa: E731
                                            timeout=300, cwd=where, env=env or _env())
    return run(_binary(repo), repo), run(SCRIPT, cwd)


def _scenes(tmp_path: Path, n: int = 2) -> Path:
    d = tmp_path / "scenes"
    d.mkdir(exist_ok=True)
    for p in nudge.scene_paths()[:n]:
        shutil.copy(p, d / p.name)
    return d


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize(("args", "status"), [
    (["--help"], 0),
    (["--version"], 0),
    (["simulate", "--help"], 0),
    ([], 2),
    (["simulate", "--no-such-flag"], 2),
    (["simulate", "--world", "log-replay"], 2),
    (["simulate", "--scenes", "{scenes}", "--runs", "0"], 1),
    (["simulate", "--scenes", "{scenes}", "--predictor", "nope.safetensors"], 1),
], ids=lambda a: " ".join(a) if isinstance(a, list) else str(a))
def test_the_package_command_is_the_binary(repo: Path, tmp_path: Path, args: list[str], status: int) -> None:
    scenes = str(_scenes(tmp_path))
    binary, script = _both(repo, tmp_path, *(scenes if a == "{scenes}" else a for a in args))
    assert binary.returncode == status, binary.stderr
    assert (script.returncode, script.stdout, script.stderr) == (binary.returncode, binary.stdout, binary.stderr)


def test_runs_give_the_same_records_and_status(repo: Path, tmp_path: Path) -> None:
    scenes = _scenes(tmp_path)
    common = ["simulate", "--scenes", str(scenes), "--predictor", "student", "--max-steps", "3", "--threads", "1"]
    binary, script = _both(repo, tmp_path, *common, "--out", str(tmp_path / "b"))
    assert binary.returncode == 0, binary.stderr
    script = subprocess.run([str(SCRIPT), *common, "--out", str(tmp_path / "s")], capture_output=True, text=True,
                            timeout=300, cwd=tmp_path, env=_env())
    assert script.returncode == 0, script.stderr
    assert _rows(tmp_path / "s" / "runs.csv") == _rows(tmp_path / "b" / "runs.csv")
    assert len(_rows(tmp_path / "s" / "runs.csv")) == 2


def _jumping_future(path: Path) -> None:
    """Agent 1 of the scene at ``path`` jumps 50 m in its logged future: the scene loads, but a
    log-replay run cannot plan its second step."""
    raw = bytearray(path.read_bytes())
    n = int.from_bytes(raw[:8], "little")
    future = json.loads(raw[8:8 + n])["future"]
    at = 8 + n + future["data_offsets"][0] + future["shape"][1] * 2 * 8  # future[1, 0, 0]
    raw[at:at + 8] = (np.frombuffer(raw[at:at + 8], "<f8") + 50.0).tobytes()
    path.write_bytes(bytes(raw))


def test_a_run_that_could_not_run_ends_both_with_status_3(repo: Path, tmp_path: Path) -> None:
    scenes = _scenes(tmp_path)
    _jumping_future(scenes / nudge.scene_paths()[0].name)
    binary, script = _both(repo, tmp_path, "simulate", "--scenes", str(scenes), "--predictor", "constant_velocity",
                           "--world", "log_replay", "--max-steps", "3", "--threads", "1")
    assert binary.returncode == script.returncode == 3, binary.stderr + script.stderr
    assert script.stderr == binary.stderr and "1 of 2 runs could not run" in script.stderr


def test_the_command_defaults_to_the_package_assets(tmp_path: Path) -> None:
    """From a directory without assets, with no paths given: the package's models and scenes."""
    r = subprocess.run([str(SCRIPT), "simulate", "--predictor", "student", "--world", "log_replay", "--max-steps", "1",
                        "--threads", "1", "--out", "out"], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                       env=_env())
    assert r.returncode == 0, r.stderr
    names = [row["scenario"] for row in _rows(tmp_path / "out" / "runs.csv")]
    assert names == [p.stem for p in sorted((nudge.SHIPPED_ASSETS / "scenes").glob("*.safetensors"))]


@pytest.mark.parametrize("front", ["binary", "package"])
def test_nudge_assets_moves_the_models_and_scenes_of_both(repo: Path, tmp_path: Path, front: str) -> None:
    mine = tmp_path / "mine"
    (mine / "models").mkdir(parents=True)
    shutil.copy(nudge.SHIPPED_ASSETS / "models" / "student.safetensors", mine / "models")
    _scenes(mine, 1)
    exe = _binary(repo) if front == "binary" else SCRIPT
    common = [str(exe), "simulate", "--max-steps", "1", "--threads", "1", "--world", "log_replay"]
    r = subprocess.run([*common, "--out", "out"], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                       env=_env(NUDGE_ASSETS=str(mine)))
    assert r.returncode == 0, r.stderr
    assert [row["scenario"] for row in _rows(tmp_path / "out" / "runs.csv")] == [nudge.scene_paths()[0].stem]
    # The teacher is not there: the named model resolves under $NUDGE_ASSETS, not the package.
    r = subprocess.run([*common, "--predictor", "teacher"], capture_output=True, text=True, timeout=300,
                       cwd=tmp_path, env=_env(NUDGE_ASSETS=str(mine)))
    assert r.returncode == 1 and str(mine / "models" / "teacher.safetensors") in r.stderr, r.stderr


def test_python_resolves_the_assets_by_the_rust_rule(repo: Path, monkeypatch: pytest.MonkeyPatch,
                                                       tmp_path: Path) -> None:
    monkeypatch.delenv("NUDGE_ASSETS", raising=False)
    # In a checkout the package's assets are the repository's (python/nudge/assets links there).
    assert nudge.SHIPPED_ASSETS == (Path(nudge.__file__).parent / "assets").resolve() == (repo / "assets").resolve()
    assert nudge.assets_dir() == nudge.SHIPPED_ASSETS
    assert nudge.scene_paths() == sorted((nudge.SHIPPED_ASSETS / "scenes").glob("*.safetensors"))
    monkeypatch.setenv("NUDGE_ASSETS", "")  # empty is unset, in Rust as in Python
    assert nudge.assets_dir() == nudge.SHIPPED_ASSETS
    (tmp_path / "scenes").mkdir()
    monkeypatch.setenv("NUDGE_ASSETS", str(tmp_path))
    assert nudge.assets_dir() == tmp_path
    assert nudge.model_path("student") == tmp_path / "models" / "student.safetensors"
    assert nudge.scene_paths() == []


def test_python_m_nudge_runs_the_command(tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "nudge", "--version"], capture_output=True, text=True, timeout=60,
                       cwd=tmp_path)
    assert (r.returncode, r.stdout) == (0, f"nudge {nudge.__version__}\n"), r.stderr


@pytest.mark.parametrize("front", ["binary", "package"])
def test_ctrl_c_ends_the_command_like_the_binary(repo: Path, tmp_path: Path, front: str) -> None:
    """Ctrl-C ends a long ``nudge simulate`` at once (default SIGINT: the process ends by the
    signal), from the package's command as from the binary."""
    exe = _binary(repo) if front == "binary" else SCRIPT
    # A shell without job control starts background jobs with SIGINT ignored, and the child
    # inherits that: restore the default so the signal reaches the command as Ctrl-C does.
    p = subprocess.Popen([str(exe), "simulate", "--scenes", str(_scenes(tmp_path, 10)), "--predictor", "teacher",
                          "--runs", "100", "--threads", "1"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         cwd=repo, env=_env(), preexec_fn=_default_sigint)
    time.sleep(1.0)
    assert p.poll() is None, "the command ended before Ctrl-C"
    sent = time.perf_counter()
    p.send_signal(signal.SIGINT)
    try:
        code = p.wait(timeout=5)
    finally:
        p.kill()
        p.communicate()
    assert code == -signal.SIGINT, code
    assert time.perf_counter() - sent < 2.0
