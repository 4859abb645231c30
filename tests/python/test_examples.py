"""The Python examples run, the quick start reads as a successful lane change, and the README
shows the quick start's code and output as they are."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "examples" / "python").glob("*.py"))
QUICK_START = ROOT / "examples" / "python" / "quick_start.py"


def _run(path: Path) -> str:
    done = subprocess.run(
        [sys.executable, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, f"{path.name} failed:\n{done.stderr}"
    assert done.stderr == "", f"{path.name} wrote to stderr:\n{done.stderr}"
    return done.stdout


def test_there_are_python_examples() -> None:
    assert {p.name for p in EXAMPLES} >= {"quick_start.py", "simulate_scene.py"}


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(path: Path) -> None:
    assert _run(path).strip()


def test_quick_start_plans_a_lane_change_that_succeeds() -> None:
    out = _run(QUICK_START)
    start = float(re.search(r"start: y = (-?[\d.]+) m", out)[1])
    status, lane, centre = re.search(r"plan: (\w+), target lane (\d+) \(centre y = (-?[\d.]+) m\)", out).groups()
    end = float(re.search(r"after 1\.8 s: y = (-?[\d.]+) m", out)[1])
    assert status in ("Converged", "Refined"), out
    # A lane change (the target lane's centre is a lane width away) whose plan ends near it.
    assert abs(float(centre) - start) > 1.5, out
    assert abs(end - float(centre)) < 0.3, out
    closed = re.search(r"closed loop: success (\w+), settled in lane (\d+) after (\d+) steps, collision (\w+)", out)
    assert closed is not None, out
    assert closed[1] == "True" and closed[2] == lane and closed[4] == "False", out
    assert 0 < int(closed[3]) <= 30, out


def _fenced(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


def _close(shown: str, got: str) -> bool:
    """Same words and integers; decimals within 0.02 (the last digit may differ across CPUs)."""
    split = re.compile(r"(-?\d+\.\d+)")
    a, b = split.split(shown), split.split(got)
    if len(a) != len(b):
        return False
    return all(
        abs(float(x) - float(y)) <= 0.02 if i % 2 else x == y for i, (x, y) in enumerate(zip(a, b))
    )


def test_readme_shows_the_quick_start_and_its_output() -> None:
    readme = (ROOT / "README.md").read_text()
    code = QUICK_START.read_text().split('"""', 2)[2].lstrip("\n")
    assert code in _fenced(readme, "python"), "README.md's Python quick start differs from examples/python/quick_start.py"
    shown = [b for b in _fenced(readme, "text") if "examples/python/quick_start.py" in b]
    assert len(shown) == 1, "README.md shows no quick-start output"
    shown_out = shown[0].split("\n", 1)[1]
    got = _run(QUICK_START)
    assert _close(shown_out, got), f"README.md's quick-start output is stale; it now prints:\n{got}"


def test_simulate_scene_prints_a_metrics_row_per_world() -> None:
    out = _run(ROOT / "examples" / "python" / "simulate_scene.py")
    rows = [line.split() for line in out.splitlines() if line.split()[:1] in (["teacher"], ["idm"], ["log_replay"])]
    assert [r[0] for r in rows] == ["teacher", "idm", "log_replay"], out
    for r in rows:
        assert r[1] in ("True", "False") and 0.0 <= float(r[7]) <= 1.0, out
