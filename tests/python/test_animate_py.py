"""nudge.simulate(..., trace=True) and nudge.animate: trace shapes and content, the records
unchanged by tracing, the GIF decoded by Pillow against the world -> pixel transform, and
every malformed input refused with a typed error."""

from __future__ import annotations

import copy
import os
import shutil
import stat
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

import nudge
import nudge._native as native

from test_simulate_py import _same_records

# The ego's colour and the caption height of the renderer (src/animate).
EGO_RGB = (40, 130, 255)
CAPTION_PX = 38


@pytest.fixture(scope="module")
def traced(scenes: list[Path]) -> dict[str, Any]:
    return nudge.simulate(scenes[:2], "constant_velocity", world="log_replay", threads=1, trace=True)


def test_tracing_is_off_by_default_and_changes_no_record(scenes: list[Path], traced: dict[str, Any]) -> None:
    plain = nudge.simulate(scenes[:2], "constant_velocity", world="log_replay", threads=1)
    assert "traces" not in plain
    _same_records(plain, traced)


def test_traces_have_the_documented_shapes_and_agree_with_the_steps(traced: dict[str, Any]) -> None:
    runs, steps = traced["runs"], traced["steps"]
    assert len(traced["traces"]) == len(runs["scenario"]) == 2
    for r, t in enumerate(traced["traces"]):
        s, n = int(runs["n_steps"][r]), int(runs["n_agents"][r])
        assert s >= 1
        assert t["plan"].shape == (s, 7, 4)
        assert t["predicted"].shape == (s, n - 1, 6, 2)
        assert t["agents"].shape == (s + 1, n, 3)
        assert t["sizes"].shape == (n, 2)
        assert t["semi_axes"].shape == (s, 6, 2)
        for k in ("speed", "collision"):
            assert t[k].shape == (s + 1,)
        for k in ("mpc_s", "binding", "binding_step", "binding_b"):
            assert t[k].shape == (s,)
        assert len(t["status"]) == s
        ego = steps["ego"][steps["run"] == r]
        # The ego after each step, and each plan starting from the state before it.
        np.testing.assert_array_equal(t["agents"][1:, 0, :2], ego[:, :2])
        np.testing.assert_array_equal(t["plan"][1:, 0], ego[:-1])
        np.testing.assert_array_equal(t["speed"][1:], ego[:, 3])
        assert t["status"] == list(np.asarray(steps["status"], dtype=object)[steps["run"] == r])
        none = t["binding"] == -1
        assert np.all((t["binding"] >= 1) | none) and np.all(t["binding"] < n)
        assert np.all(np.isnan(t["binding_b"][none])) and not np.any(np.isnan(t["binding_b"][~none]))


def test_the_gif_has_one_frame_per_state_and_the_ego_where_the_transform_puts_it(
    traced: dict[str, Any], tmp_path: Path
) -> None:
    written = nudge.animate(traced, tmp_path, runs=[0], mp4=False, px_per_m=8.0, behind_m=25.0)
    t = traced["traces"][0]
    name = f"{traced['runs']['scenario'][0]}-seed{traced['runs']['seed'][0]}.gif"
    assert written == [tmp_path / name]
    with Image.open(written[0]) as im:
        assert im.n_frames == len(t["status"]) + 1
        road = t["lane_bounds"][-1] - t["lane_bounds"][0]
        # 8 px/m over 25 + 90 m; (road + 2 × 2 m verge) × 8 px/m + the caption, rounded up to even.
        w, h = int(np.ceil(115 * 8)), int(np.ceil((road + 4) * 8 + CAPTION_PX))
        assert im.size == (w + w % 2, h + h % 2)
        for k in (0, im.n_frames - 1):
            im.seek(k)
            rgb = im.convert("RGB")
            # The camera puts the ego's centre 25 m from the left edge; y grows upwards from
            # the road's left edge plus the verge at the caption's lower edge.
            x, y = t["agents"][k, 0, :2]
            col = round(25 * 8)
            row = round(CAPTION_PX + (t["lane_bounds"][-1] + 2.0 - y) * 8)
            assert rgb.getpixel((col, row)) == EGO_RGB, k


def _fake_ffmpeg(tmp_path: Path) -> Path:
    p = tmp_path / "ffmpeg"
    p.write_text('#!/bin/sh\nfor a; do out="$a"; done; cat > "$out"\n')
    p.chmod(p.stat().st_mode | stat.S_IEXEC)
    return p


@pytest.mark.skipif(os.name != "posix", reason="a shell-script stand-in for ffmpeg")
def test_mp4_frames_go_to_ffmpeg_as_rgb24(traced: dict[str, Any], tmp_path: Path) -> None:
    t = traced["traces"][0]
    w = native.animate(t, tmp_path / "a.gif", mp4=tmp_path / "a.mp4", ffmpeg=_fake_ffmpeg(tmp_path))
    assert w["frames"] == len(t["status"]) + 1
    assert (tmp_path / "a.mp4").stat().st_size == w["frames"] * w["width"] * w["height"] * 3


def test_mp4_true_without_ffmpeg_is_an_error(traced: dict[str, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    assert nudge.find_ffmpeg() is None
    with pytest.raises(nudge.NudgeError, match="ffmpeg not found"):
        nudge.animate(traced, tmp_path, mp4=True)
    # mp4=None: the GIFs only.
    assert [p.suffix for p in nudge.animate(traced, tmp_path)] == [".gif", ".gif"]


def _spoiled(trace: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    t = copy.deepcopy(trace)
    if value is _DROP:
        del t[key]
    else:
        t[key] = value
    return t


_DROP = object()


def test_malformed_traces_raise_input_error_naming_the_key(traced: dict[str, Any], tmp_path: Path) -> None:
    t = traced["traces"][0]
    s = len(t["status"])
    nan_plan = t["plan"].copy()
    nan_plan[0, 3, 1] = np.nan
    far = t["binding"].copy()
    far[0] = 99
    cases = [
        ("plan", _DROP, "plan"),
        ("plan", t["plan"][:, :, :3], "plan"),
        ("plan", t["plan"].tolist(), "plan"),
        ("plan", t["plan"].astype(np.float32), "plan"),
        ("plan", nan_plan, "frame 0 plan"),
        ("plan", t["plan"][:, :1], "plan"),
        ("predicted", t["predicted"][:, 1:], "predicted"),
        ("agents", t["agents"][:0], "agents"),
        ("agents", t["agents"][:, :1], "agents"),
        ("status", ["Bogus"] * s, "status"),
        ("status", "Converged", "status"),
        ("binding", far, "binding"),
        ("binding_step", np.zeros(s, dtype=np.int64) - 2, "binding"),
        ("collision", t["collision"].astype(np.int64), "collision"),
        ("lane_bounds", t["lane_bounds"][::-1].copy(), "lane_bounds"),
        ("sizes", -t["sizes"], "sizes"),
        ("title", 3, "title"),
    ]
    for key, value, named in cases:
        with pytest.raises(nudge.InputError, match=named):
            native.animate(_spoiled(t, key, value), tmp_path / "x.gif")
    for bad in (None, [], "trace", {}):
        with pytest.raises(nudge.InputError):
            native.animate(bad, tmp_path / "x.gif")


def test_bad_records_runs_and_settings_raise_typed_errors(traced: dict[str, Any], tmp_path: Path) -> None:
    with pytest.raises(nudge.InputError, match="no traces"):
        nudge.animate({"runs": traced["runs"]}, tmp_path)
    with pytest.raises(nudge.InputError, match="no traces"):
        nudge.animate([1, 2], tmp_path)  # type: ignore[arg-type]
    for runs in ([2], [-1], [True], ["0"]):
        with pytest.raises(nudge.InputError, match="runs"):
            nudge.animate(traced, tmp_path, runs=runs)  # type: ignore[arg-type]
    with pytest.raises(nudge.SettingsError, match="px_per_m"):
        nudge.animate(traced, tmp_path, px_per_m=-1.0)
    with pytest.raises(nudge.SettingsError, match="frame_s"):
        nudge.animate(traced, tmp_path, frame_s=0.0)
    with pytest.raises(nudge.SettingsError, match="bogus"):
        nudge.animate(traced, tmp_path, bogus=1.0)
    with pytest.raises(nudge.NudgeError):
        native.animate(traced["traces"][0], tmp_path / "no" / "such" / "dir" / "x.gif")


@pytest.mark.skipif(nudge.find_ffmpeg() is None, reason="ffmpeg is not on PATH")
def test_a_real_ffmpeg_writes_an_mp4_of_every_frame(traced: dict[str, Any], tmp_path: Path) -> None:
    written = nudge.animate(traced, tmp_path, runs=[0], mp4=True)
    assert [p.suffix for p in written] == [".gif", ".mp4"]
    data = written[1].read_bytes()
    assert data[4:8] == b"ftyp"
    probe = shutil.which("ffprobe")
    if probe is not None:
        out = subprocess.run([probe, "-v", "error", "-count_frames", "-show_entries", "stream=nb_read_frames",
                              "-of", "csv=p=0", str(written[1])], capture_output=True, text=True, check=True)
        assert int(out.stdout.strip()) == len(traced["traces"][0]["status"]) + 1
