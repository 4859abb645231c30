"""Property tests (hypothesis) for the pipeline's building blocks."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays
from safetensors import safe_open
from safetensors.numpy import load_file

from nudge_train.data.coifman import LANE_W, lateral_path
from nudge_train.data.raw import smooth_flicker
from nudge_train.data.splits import SplitConfig, assign
from nudge_train.data.st_io import write_safetensors

DTYPES = st.sampled_from([np.float64, np.float32, np.int64, np.uint8])


@settings(max_examples=40, deadline=None)
@given(st.dictionaries(st.from_regex(r"[a-z_]{1,8}", fullmatch=True),
                       DTYPES.flatmap(lambda d: arrays(d, array_shapes(min_dims=1, max_dims=3, max_side=5))),
                       min_size=1, max_size=4),
       st.dictionaries(st.from_regex(r"[a-z]{1,6}", fullmatch=True), st.text(max_size=10), max_size=3))
def test_safetensors_writer_roundtrip(tensors: dict[str, np.ndarray], meta: dict[str, str]) -> None:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "x.safetensors"
        write_safetensors(p, tensors, meta)
        back = load_file(str(p))
        assert set(back) == set(tensors)
        for k, v in tensors.items():
            assert back[k].dtype == v.dtype and back[k].shape == v.shape
            assert np.array_equal(back[k], v, equal_nan=v.dtype.kind == "f")
        with safe_open(str(p), "np") as fh:
            assert (fh.metadata() or {}) == meta
        first = p.read_bytes()
        write_safetensors(p, dict(reversed(list(tensors.items()))), dict(reversed(list(meta.items()))))
        assert p.read_bytes() == first


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(1, 4), min_size=1, max_size=60), st.integers(1, 12))
def test_flicker_smoothing_properties(lanes: list[int], max_run: int) -> None:
    a = np.asarray(lanes, dtype=np.int64)
    out, changed = smooth_flicker(a, max_run)
    assert out.shape == a.shape and changed == int(np.sum(out != a))
    assert out[0] == a[0] and out[-1] == a[-1]
    again, c2 = smooth_flicker(out, max_run)
    assert c2 == 0 and np.array_equal(again, out)
    # No short run is left between two runs of the same lane.
    starts = np.flatnonzero(np.concatenate([[True], out[1:] != out[:-1]]))
    ends = np.concatenate([starts[1:], [out.shape[0]]])
    for k in range(1, len(starts) - 1):
        assert not (ends[k] - starts[k] < max_run and out[starts[k - 1]] == out[starts[k + 1]])


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(1, 7), min_size=2, max_size=80), st.floats(0.5, 8.0))
def test_lateral_path_stays_between_lane_centres(lanes: list[int], duration: float) -> None:
    lane = np.asarray(lanes)
    t = np.arange(lane.shape[0]) * 0.1
    y = lateral_path(t, lane, duration)
    centres = -(lane - 0.5) * LANE_W
    assert np.all(np.isfinite(y))
    assert y.min() >= centres.min() - 1e-9 and y.max() <= centres.max() + 1e-9
    assert abs(y[0] - centres[0]) <= abs(centres).max() + LANE_W


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(1.0, 100.0), min_size=3, max_size=12), st.integers(0, 5))
def test_assign_every_group_exactly_one_split(weights: list[float], seed: int) -> None:
    w = {f"g{i:02d}": x for i, x in enumerate(weights)}
    a = assign(w, SplitConfig(seed=seed, tries=50), salt=7)
    assert set(a) == set(w)
    assert set(a.values()) <= {"train", "val", "test"} and "test" in a.values() and "train" in a.values()
