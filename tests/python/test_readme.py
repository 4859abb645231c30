"""The README is a README: at most 12,000 characters, one Rust and one Python example, its Python
example runs as written (the Rust one is a doctest of the facade crate, `src/lib.rs`), its picture
is a run `make demo` writes, every relative link of it, the changelog and the results index
resolves, and the results index has a row, with its status, for every report."""

from __future__ import annotations

import csv
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
MAX_CHARS = 12_000


def _fenced(text: str, lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", text, flags=re.S | re.M)


def test_readme_is_short_with_one_example_per_language() -> None:
    text = README.read_text()
    assert len(text) <= MAX_CHARS, f"README.md has {len(text)} characters (at most {MAX_CHARS})"
    assert len(_fenced(text, "rust")) == 1, "README.md should show one Rust example"
    assert len(_fenced(text, "python")) == 1, "README.md should show one Python example"


@pytest.mark.parametrize("index", range(len(_fenced(README.read_text(), "python"))))
def test_readme_python_example_runs(index: int, tmp_path: Path) -> None:
    code = _fenced(README.read_text(), "python")[index]
    script = tmp_path / f"readme_example_{index}.py"
    script.write_text(code)
    done = subprocess.run(
        [sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, f"README.md's Python example {index} failed:\n{done.stderr}"
    assert done.stderr == "", f"README.md's Python example {index} wrote to stderr:\n{done.stderr}"
    assert done.stdout.strip(), f"README.md's Python example {index} printed nothing"


def _demo_simulate_args() -> list[str]:
    """The arguments of the first `nudge simulate` of the Makefile's `demo` target."""
    make = (ROOT / "Makefile").read_text().replace("\\\n", " ")
    recipe = re.search(r"^demo:.*\n((?:\t.*\n)+)", make, flags=re.M)
    assert recipe is not None, "the Makefile has no demo target"
    line = next(x for x in recipe[1].splitlines() if " simulate " in x)
    predictor = re.search(r"^PREDICTOR \?= (\S+)", make, flags=re.M)
    assert predictor is not None
    args = shlex.split(line.replace("$(PREDICTOR)", predictor[1]))
    return args[args.index("simulate") :]


def test_readme_picture_is_a_run_make_demo_writes(tmp_path: Path) -> None:
    text = README.read_text()
    named = re.search(r"`out/demo/animations/(\S+)-seed(\d+)\.gif`", text)
    assert named is not None, "the README's caption names no animation of make demo"
    scene, seed = named[1], named[2]
    steps = re.search(r"settles\s+in\s+the\s+target\s+lane\s+after\s+(\d+)\s+steps", text)
    assert steps is not None, "the README's caption says not when the ego settles"
    assert (ROOT / "docs" / "figures" / "run_animation.gif").is_file()

    exe = Path(os.environ.get("NUDGE_CLI", ROOT / "target" / "release" / "nudge"))
    assert exe.is_file(), f"the nudge CLI is not built at {exe} (cargo build --release, or set NUDGE_CLI)"
    args = _demo_simulate_args()
    out = tmp_path / "demo"
    args[args.index("--out") + 1] = str(out)
    done = subprocess.run([str(exe), *args], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (out / "animations" / f"{scene}-seed{seed}.gif").is_file(), (
        f"make demo writes no {scene}-seed{seed}.gif: {sorted(p.name for p in (out / 'animations').glob('*'))}"
    )
    with (out / "runs.csv").open() as f:
        run = next(r for r in csv.DictReader(f) if r["scenario"] == scene and r["seed"] == seed)
    assert run["success"] == "true" and run["steps_to_target"] == steps[1], run


LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


@pytest.mark.parametrize("doc", ["README.md", "CHANGELOG.md", "docs/results/README.md"])
def test_relative_links_resolve(doc: str) -> None:
    path = ROOT / doc
    targets = [t for t in LINK.findall(path.read_text()) if "://" not in t]
    assert targets, f"{doc} links nothing"
    missing = [t for t in targets if not (path.parent / t).exists()]
    assert not missing, f"{doc} links to missing files: {missing}"


def test_results_index_lists_every_report() -> None:
    results = ROOT / "docs" / "results"
    index = (results / "README.md").read_text()
    rows = set(re.findall(r"^\| \[([^\]]+\.md)\]\(\1\) \|", index, flags=re.M))
    reports = {p.name for p in results.glob("*.md")} - {"README.md"}
    assert rows == reports, (
        f"docs/results/README.md: reports without a row {sorted(reports - rows)}, rows without a report "
        f"{sorted(rows - reports)}"
    )
    for row in re.findall(r"^\| \[[^\]]+\.md\]\(.*$", index, flags=re.M):
        status = row.rstrip(" |").rsplit("|", 1)[1]
        assert re.search(r"\b(adopted|not adopted|measurement)\b", status), f"a row without its status: {row}"
