"""Smoke test of an installed nudge wheel, run by ``make wheel-smoke`` in a fresh virtual
environment outside the checkout (numpy the only dependency; no torch).

Checks that the package and its assets come from the installed package, then predicts with the
shipped teacher and student, plans one step, simulates a shipped scene and animates it
(``trace=True``, ``nudge.animate``), and runs the ``nudge`` command: its help, ``nudge simulate
--animate`` on the package's scenes (no path given), and one case of each failing exit status
(1 refused, 2 unparsable, 3 a run that could not run).

Usage: ``python smoke.py [--scenes N]`` (N: the number of scenes the wheel must carry).
``$NUDGE_SMOKE_T0`` (seconds since the epoch, taken before ``pip install``) adds the time from
the install to the first plan.
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import nudge

SAFE = ("Converged", "MaxIterations", "Refined", "Backtracked")


def check(ok: bool, what: str) -> None:
    if not ok:
        raise SystemExit(f"wheel smoke test FAILED: {what}")


def installed() -> Path:
    """The package directory, checked to lie in this environment with its assets."""
    pkg = Path(nudge.__file__).resolve().parent
    check(pkg.is_relative_to(Path(sys.prefix).resolve()), f"nudge imported from {pkg}, not from {sys.prefix}")
    check("NUDGE_ASSETS" not in os.environ, "NUDGE_ASSETS is set")
    check(nudge.assets_dir() == pkg / "assets" == nudge.SHIPPED_ASSETS, f"assets at {nudge.assets_dir()}")
    check(importlib.util.find_spec("torch") is None, "torch is installed")
    return pkg


def predict(scene: Path) -> None:
    sc = nudge.Scenario.load(scene)
    x0, y0 = sc.history[0, -1]
    t = np.arange(1, 7) * nudge.DT
    cands = np.stack([np.stack([x0 + sc.speed[0] * t, np.full(6, y0 + dy)], -1) for dy in (-1.0, 0.0, 1.0)])
    for name in ("teacher", "student"):
        out = nudge.Predictor.load(nudge.model_path(name)).predict(sc.history, cands)
        check(out.shape == (3, sc.n_agents - 1, 6, 2), f"{name}: prediction shape {out.shape}")
        check(bool(np.isfinite(out).all()), f"{name}: non-finite prediction")
        print(f"predict  {name:8s} {sc.name}: {out.shape} finite")


def plan(scene: Path, t0: float | None) -> None:
    sc = nudge.Scenario.load(scene)
    for name in ("student", "teacher"):
        start = time.perf_counter()
        planner = nudge.Planner(nudge.PlannerSettings.default(), nudge.Predictor.load(nudge.model_path(name)))
        p = planner.plan_scenario(sc, seed=0)
        ms = (time.perf_counter() - start) * 1e3
        check(p["status"] in SAFE, f"{name}: plan status {p['status']}")
        check(bool(np.isfinite(p["states"]).all() and np.isfinite(p["cost"])), f"{name}: non-finite plan")
        print(f"plan     {name:8s} {sc.name}: {p['status']}, {p['iterations']} iterations, "
              f"cost {p['cost']:.2f}, {ms:.1f} ms (loading included)")
        if t0 is not None and name == "student":
            print(f"time from pip install to the first plan: {time.time() - t0:.1f} s")


def gif_frames(path: Path) -> int:
    """The number of images of the GIF at ``path``, read block by block (the smoke test's
    environment has no image library)."""
    data = path.read_bytes()
    check(data[:6] == b"GIF89a", f"{path.name}: not a GIF")
    at = 13 + (3 << ((data[10] & 7) + 1) if data[10] & 0x80 else 0)

    def sub_blocks(i: int) -> int:
        while data[i]:
            i += data[i] + 1
        return i + 1

    frames = 0
    while data[at] != 0x3B:  # the trailer
        if data[at] == 0x21:  # an extension: label, sub-blocks
            at = sub_blocks(at + 2)
        else:
            check(data[at] == 0x2C, f"{path.name}: unexpected block {data[at]:#x} at {at}")
            flags = data[at + 9]
            at += 10 + (3 << ((flags & 7) + 1) if flags & 0x80 else 0)
            at = sub_blocks(at + 1)  # the LZW code size, then the image data
            frames += 1
    return frames


def simulate(scene: Path, work: Path) -> None:
    rec = nudge.simulate([scene], "student", world="teacher", seed=0, threads=1, trace=True)
    runs, steps = rec["runs"], rec["steps"]
    check(len(runs["scenario"]) == 1 and not runs["error"][0], f"simulate: {runs['error']}")
    check(not runs["collision"][0], "simulate: collision")
    check(bool(np.isfinite(steps["ego"]).all()), "simulate: non-finite ego states")
    print(f"simulate student/teacher {runs['scenario'][0]}: success {runs['success'][0]}, "
          f"{runs['n_steps'][0]} steps, no collision")
    start = time.perf_counter()
    (gif,) = nudge.animate(rec, work / "animations", mp4=False)
    frames = gif_frames(gif)
    check(frames == runs["n_steps"][0] + 1, f"animate: {frames} frames for {runs['n_steps'][0]} steps")
    print(f"animate: {gif.name}, {frames} frames, {gif.stat().st_size // 1024} KiB, "
          f"{time.perf_counter() - start:.2f} s")


def command(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("nudge", path=str(Path(sys.executable).parent))
    check(exe is not None, "no nudge command in the environment")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=600, cwd=cwd)


def jumping_future(src: Path, dst: Path) -> None:
    """A copy of scene ``src`` whose agent 1 jumps 50 m in its logged future: it loads, but a
    log-replay run cannot plan its second step."""
    raw = bytearray(src.read_bytes())
    n = int.from_bytes(raw[:8], "little")
    future = json.loads(raw[8:8 + n])["future"]
    steps = future["shape"][1]
    at = 8 + n + future["data_offsets"][0] + steps * 2 * 8  # future[1, 0, 0]: agent 1, step 1, x
    x = np.frombuffer(raw[at:at + 8], "<f8")[0]
    raw[at:at + 8] = np.array([x + 50.0], "<f8").tobytes()
    dst.write_bytes(bytes(raw))


def cli(work: Path, n_scenes: int | None) -> None:
    r = command("--help", cwd=work)
    check(r.returncode == 0 and "simulate" in r.stdout, f"nudge --help: {r.returncode} {r.stderr}")
    print("nudge --help: exit 0, lists simulate")
    out = work / "out"
    start = time.perf_counter()
    r = command("simulate", "--threads", "2", "--out", str(out), "--animate", "--animate-runs", "1", cwd=work)
    check(r.returncode == 0, f"nudge simulate: exit {r.returncode}: {r.stderr}")
    with (out / "runs.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    check(all(not row["error"] and row["collision"] == "false" for row in rows), "nudge simulate: a run failed")
    check(n_scenes is None or len(rows) == n_scenes, f"nudge simulate ran {len(rows)} scenes, expected {n_scenes}")
    check(len(list((out / "animations").glob("*.gif"))) == 1, "nudge simulate --animate: no GIF")
    ok = sum(row["success"] == "true" for row in rows)
    print(f"nudge simulate (the package's {len(rows)} scenes, student in the teacher world): exit 0, "
          f"{ok}/{len(rows)} lane changes, no collision, {time.perf_counter() - start:.1f} s")
    for line in [x for x in r.stdout.splitlines() if x.strip()][-5:]:
        print(f"    {line}")
    r = command("simulate", "--runs", "0", cwd=work)
    check(r.returncode == 1 and "runs" in r.stderr, f"refused: exit {r.returncode}: {r.stderr}")
    r = command("simulate", "--no-such-flag", cwd=work)
    check(r.returncode == 2 and "--no-such-flag" in r.stderr, f"unparsable: exit {r.returncode}: {r.stderr}")
    bad = work / "bad"
    bad.mkdir()
    jumping_future(nudge.scene_paths()[0], bad / nudge.scene_paths()[0].name)
    r = command("simulate", "--scenes", str(bad), "--predictor", "constant_velocity", "--world", "log_replay",
                "--max-steps", "3", "--threads", "1", cwd=work)
    check(r.returncode == 3 and "could not run" in r.stderr, f"a failing run: exit {r.returncode}: {r.stderr}")
    print("nudge exit statuses: 1 refused (--runs 0), 2 unparsable, 3 a run that could not run")


def distribution(work: Path) -> None:
    """The distribution nudge-planner with its license metadata and files; provenance beside the
    records; the figures command without matplotlib says which extra to install."""
    from importlib import metadata

    meta = metadata.metadata("nudge-planner")
    check(meta["Name"] == "nudge-planner", f"distribution name {meta['Name']}")
    lic = meta.get("License-Expression") or meta.get("License")
    check(lic == "MIT OR Apache-2.0", f"license metadata {lic!r}")
    files = [str(f) for f in metadata.files("nudge-planner") or []]
    check(any(f.endswith("LICENSE-MIT") for f in files) and any(f.endswith("LICENSE-APACHE") for f in files),
          f"license files missing from the wheel: {[f for f in files if 'LICENSE' in f]}")
    prov = json.loads((work / "out" / "provenance.json").read_text())
    check(prov["nudge_version"] == nudge.__version__ and prov["git_sha"] == nudge.GIT_SHA, "provenance.json")
    print(f"distribution nudge-planner {meta['Version']}, license {lic}, git {nudge.GIT_SHA[:12]}; "
          f"provenance.json: {prov['scenes']['count']} scenes, threads {prov['threads']}")
    exe = shutil.which("nudge-figures", path=str(Path(sys.executable).parent))
    check(exe is not None, "no nudge-figures command in the environment")
    r = subprocess.run([str(exe), "runs", str(work / "out")], capture_output=True, text=True, timeout=120, cwd=work)
    if importlib.util.find_spec("matplotlib") is None:
        check(r.returncode == 2 and "nudge-planner[figures]" in r.stderr, f"nudge-figures: {r.returncode} {r.stderr}")
        print("nudge-figures without matplotlib: exit 2, names the figures extra")
    else:
        check(r.returncode == 0 and (work / "out" / "runs.png").is_file(), f"nudge-figures: {r.stderr}")
        print("nudge-figures runs: wrote runs.png")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenes", type=int, default=None, help="the number of scenes the wheel must carry")
    n_scenes = ap.parse_args().scenes
    t0 = float(os.environ["NUDGE_SMOKE_T0"]) if os.environ.get("NUDGE_SMOKE_T0") else None
    pkg = installed()
    scenes = nudge.scene_paths()
    check(n_scenes is None or len(scenes) == n_scenes, f"{len(scenes)} scenes in the wheel, expected {n_scenes}")
    print(f"nudge {nudge.__version__} from {pkg} (numpy {np.__version__}, no torch); "
          f"assets: 2 models, {len(scenes)} scenes")
    plan(scenes[0], t0)
    predict(scenes[0])
    with tempfile.TemporaryDirectory() as work:
        simulate(scenes[0], Path(work))
        cli(Path(work), n_scenes)
        distribution(Path(work))
    print("wheel smoke test passed")


if __name__ == "__main__":
    main()
