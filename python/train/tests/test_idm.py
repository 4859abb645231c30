"""IDM car-following (nudge_train.idm): the model against hand-computed and analytic values, the
calibration against known parameters, pairs and cut-ins on real excerpts, determinism."""

from __future__ import annotations

import csv
import gzip
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from nudge_train.data.coifman import read_coifman
from nudge_train.data.commonroad import read_commonroad
from nudge_train.data.errors import DataError
from nudge_train.idm import cutins as ci
from nudge_train.idm.fit import FitConfig, calibrate, fit_driver
from nudge_train.idm.model import (MAX_DECEL, PairBatch, batch_errors, constant_speed_errors, equilibrium_gap,
                                   idm_accel, simulate_follower)
from nudge_train.idm.pairs import Pair, PairStats, read_i80_pairs, scene_pairs
from nudge_train.idm.sources import SceneSource
from nudge_train.idm.yielding import YieldConfig, simulate_event

FIX = Path(__file__).resolve().parent / "fixtures" / "idm"
DATA = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "ngsim"


# ------------------------------------------------------------------------------------------ model


def test_idm_acceleration_matches_a_hand_computed_case() -> None:
    # v = 20, v0 = 30, leader 2 m/s slower at s = 30 m; T 1.5, s0 2, a 1, b 1.5, delta 4.
    # s* = 2 + 20*1.5 + 20*2 / (2*sqrt(1.5)) = 32 + 16.329932 = 48.329932
    # a = 1 * (1 - (2/3)^4 - (48.329932/30)^2) = 1 - 0.197531 - 2.595314 = -1.792845
    a = idm_accel(np.array(20.0), np.array(2.0), np.array(30.0), 30.0, 1.5, 2.0, 1.0, 1.5, 4.0)
    assert float(a) == pytest.approx(-1.792845, abs=1e-6)
    # Free road: 1.2 * (1 - (10/25)^4) = 1.2 * 0.9744 = 1.16928
    free = idm_accel(np.array(10.0), np.array(0.0), np.array(np.inf), 25.0, 1.5, 2.0, 1.2, 1.5)
    assert float(free) == pytest.approx(1.16928, abs=1e-9)
    # Braking is floored at the physical limit.
    hard = idm_accel(np.array(30.0), np.array(15.0), np.array(1.0), 30.0, 1.5, 2.0, 1.0, 1.5)
    assert float(hard) == -MAX_DECEL


def test_simulator_holds_and_reaches_the_analytic_equilibrium_gap() -> None:
    T, s0, a_max, b, v0, v = 1.3, 2.0, 1.0, 1.8, 30.0, 15.0
    se = float(equilibrium_gap(np.array(v), v0, T, s0))
    assert se == pytest.approx((s0 + v * T) / math.sqrt(1 - (v / v0) ** 4), rel=1e-12)
    k = 1200  # 120 s
    lead_rear = 500.0 + v * 0.1 * np.arange(k)
    lead_v = np.full(k, v)
    params = np.array([[T, s0, a_max, b]])
    held = simulate_follower(500.0 - se, v, lead_rear, lead_v, params, v0, 0.1)
    assert np.max(np.abs(held.s[0] - se)) < 1e-6
    assert np.max(np.abs(held.a[0])) < 1e-6
    # From 10 m too close and 3 m/s too slow it settles on the same gap.
    moved = simulate_follower(500.0 - se + 10.0, v - 3.0, lead_rear, lead_v, params, v0, 0.1)
    assert abs(moved.s[0, -1] - se) < 0.01
    assert abs(moved.v[0, -1] - v) < 0.01
    assert not moved.collided[0]


def _synthetic_leader(k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A leader that slows to 5 m/s, speeds up to 25 m/s, brakes hard and recovers (dt 0.1 s)."""
    t = np.arange(k) * 0.1
    v = 15 + 10 * np.sin(2 * np.pi * t / 40.0) + 3 * np.sin(2 * np.pi * t / 9.0 + rng.uniform(0, 1))
    v = np.maximum(v, 0.0)
    x = 100.0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * 0.1)])
    return x, v


def _synthetic_pair(true: np.ndarray, v0: float, noise: float, seed: int) -> tuple[Pair, float]:
    """A follower simulated with ``true`` [4] and desired speed ``v0`` behind a synthetic leader,
    positions with Gaussian noise; also returns the true v0 / v_ref (v_ref = highest speed)."""
    rng = np.random.default_rng(seed)
    lead_rear, lead_v = _synthetic_leader(900, rng)
    sim = simulate_follower(lead_rear[0] - 25.0, lead_v[0], lead_rear, lead_v, true[None, :], v0, 0.1)
    ratio = v0 / float(sim.v[0].max())
    xf = sim.x[0] + rng.normal(0, noise, sim.x.shape[1])
    pair = Pair(source="synthetic", scene="s", group="g", split="train", follower=seed, leader=0, frame0=0, dt=0.1,
                xf=xf, vf=sim.v[0].copy(), lead_rear=lead_rear, vl=lead_v)
    return pair, ratio


def test_calibration_recovers_known_parameters_from_noisy_synthetic_data() -> None:
    true = np.array([1.4, 2.5, 1.2, 2.0])
    p, ratio = _synthetic_pair(true, v0=30.0, noise=0.05, seed=3)
    cfg = FitConfig(popsize=12, maxiter=200)
    d = fit_driver("synthetic:s:3", [p], cfg)
    got = np.asarray(d.params)
    assert d.status == "ok"
    assert d.rmse_gap < 0.1  # close to the 0.05 m noise
    assert got[0] == pytest.approx(1.4, abs=0.1)
    assert got[1] == pytest.approx(2.5, abs=0.4)
    assert got[2] == pytest.approx(1.2, abs=0.2)
    assert got[3] == pytest.approx(2.0, abs=0.5)
    assert got[4] == pytest.approx(ratio, abs=0.1)


def test_batch_simulation_matches_the_single_follower_simulator_and_baselines() -> None:
    true = np.array([1.1, 2.0, 1.5, 1.7])
    p, ratio = _synthetic_pair(true, v0=28.0, noise=0.0, seed=5)
    batch = PairBatch.of([p])
    e = batch_errors(batch, np.stack([true, true * 1.2]), np.array([ratio, ratio]))
    assert e.rmse_gap()[0, 0] < 1e-9  # the generating parameters reproduce the record exactly
    assert e.rmse_gap()[1, 0] > 0.1
    cs = constant_speed_errors(batch)
    t = np.arange(p.xf.shape[0]) * 0.1
    want = np.sqrt(np.mean((p.xf[0] + p.vf[0] * t - p.xf) ** 2))
    assert cs.rmse_gap()[0, 0] == pytest.approx(want, rel=1e-12)


def test_calibration_is_deterministic() -> None:
    p, _ = _synthetic_pair(np.array([1.2, 2.0, 1.0, 1.5]), v0=30.0, noise=0.1, seed=8)
    cfg = FitConfig(popsize=6, maxiter=20)
    a = calibrate(PairBatch.of([p]), cfg, [0, 1])
    b = calibrate(PairBatch.of([p]), cfg, [0, 1])
    assert a.tobytes() == b.tobytes()


def test_prior_keeps_parameters_the_record_cannot_identify_near_the_prior() -> None:
    """Steady following at constant speed identifies s0 + v T only: a_max and b are free. With the
    prior they stay at the prior; the gap is still reproduced."""
    k, v = 300, 15.0
    T, s0 = 1.2, 2.0
    se = float(equilibrium_gap(np.array(v), 40.0, T, s0))
    lead_rear = 200.0 + v * 0.1 * np.arange(k)
    p = Pair(source="synthetic", scene="s", group="g", split="train", follower=1, leader=0, frame0=0, dt=0.1,
             xf=lead_rear - se, vf=np.full(k, v), lead_rear=lead_rear, vl=np.full(k, v))
    prior = np.array([1.0, 2.5, 2.2, 3.3, 1.5])
    d = fit_driver("synthetic:s:1", [p], FitConfig(popsize=8, maxiter=80, prior_weight=0.5), prior)
    assert d.rmse_gap < 0.2
    assert d.params[2] == pytest.approx(2.2, abs=0.15)
    assert d.params[3] == pytest.approx(3.3, abs=0.15)


def test_fit_config_validation_names_the_setting() -> None:
    with pytest.raises(ValueError, match="bounds\\[s0\\]"):
        FitConfig(bounds=((0.3, 3.0), (5.0, 1.0), (0.3, 4.0), (0.5, 5.0), (1.0, 2.0))).validate()
    with pytest.raises(ValueError, match="delta"):
        FitConfig(delta=float("nan")).validate()
    with pytest.raises(ValueError, match="prior_weight"):
        FitConfig(prior_weight=-1.0).validate()


# ------------------------------------------------------------------------------------------ pairs


def test_i80_pairs_from_real_rows() -> None:
    path = FIX / "i80_pairs_cut.csv.gz"
    st = PairStats()
    pairs = read_i80_pairs(path, None, st)
    assert [p.key for p in pairs] == ["i80:i80-0400-0415:47:39:510", "i80:i80-0400-0415:55:44:513"]
    assert st.dropped == {"gap <= 0 (overlapping vehicles)": 1}
    with gzip.open(path, "rt") as fh:
        rows = [r for r in csv.DictReader(fh) if r["pair_id"] == "47-39"]
    want = [float(r["preceding_local_y"]) - float(r["local_y"]) - float(r["preceding_length"]) for r in rows]
    np.testing.assert_allclose(pairs[0].gap, want, rtol=0, atol=1e-9)
    assert pairs[0].duration == pytest.approx(8.0)


def test_i80_pairs_reader_names_file_and_row_on_bad_input(tmp_path: Path) -> None:
    with gzip.open(FIX / "i80_pairs_cut.csv.gz", "rt") as fh:
        lines = fh.read().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([lines[0], lines[1], lines[2].replace(lines[2].split(",")[6], "nan", 1)]) + "\n")
    with pytest.raises(DataError, match="bad.csv, row 3"):
        read_i80_pairs(bad, None)
    head = lines[0].replace("preceding_length", "x")
    missing = tmp_path / "missing.csv"
    missing.write_text("\n".join([head, lines[1]]) + "\n")
    with pytest.raises(DataError, match="missing columns \\['preceding_length'\\]"):
        read_i80_pairs(missing, None)


def test_us101_pair_extraction_agrees_with_the_flat_rows() -> None:
    table = read_commonroad(Path(__file__).resolve().parent / "fixtures" / "commonroad" / "USA_US101-1_1_T-1.xml.gz")
    st = PairStats()
    pairs = scene_pairs(SceneSource("USA_US101-1_1_T-1", "g1", "train", table), 5.0, st)
    assert [(p.follower, p.leader) for p in pairs] == [(489, 484)]
    p = pairs[0]
    assert p.duration == pytest.approx(6.0)
    # Independent truth: the flat CSV in the original frame; same lane, so the gap is the centre
    # distance minus half of both lengths (up to the road's curvature, < 0.1 m here).
    with open(FIX / "us101_1_1_flat.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    by = {(int(r["obstacle_id"]), int(r["time_step"])): r for r in rows}
    want = []
    for k in range(p.xf.shape[0]):
        f, ld = by[(489, k)], by[(484, k)]
        d = math.hypot(float(ld["x_m"]) - float(f["x_m"]), float(ld["y_m"]) - float(f["y_m"]))
        want.append(d - 0.5 * (float(ld["length_m"]) + float(f["length_m"])))
    np.testing.assert_allclose(p.gap, want, atol=0.1)
    np.testing.assert_allclose(p.vf, [float(by[(489, k)]["velocity_mps"]) for k in range(p.xf.shape[0])])


# ---------------------------------------------------------------------------------------- cut-ins


def test_us101_cut_in_is_found_on_a_real_excerpt() -> None:
    table = read_commonroad(FIX / "USA_US101-3_1_T-1_cutin.xml.gz")
    tr = ci.Tracks(table)
    cfg = ci.CutInConfig()
    ev = ci.detect(tr, "us101", "USA_US101-3_1_T-1", "g", lambda f: "train", cfg, lateral_measured=True)
    hit = [e for e in ev if (e.intruder, e.follower) == (394, 395)]
    assert len(hit) == 1
    e = hit[0]
    assert e.old_leader == 383 and (e.lane_from, e.lane_to) == (2, 1)
    # The centre crossing lies between the last frame in the old lane and the first in the new one.
    sl = tr.rows[394]
    ln = table.lane[sl]
    j = int(np.flatnonzero(ln[1:] != ln[:-1])[0]) + 1
    assert table.t[sl][j - 1] <= e.t_centre <= table.t[sl][j]
    assert e.t_edge is not None and e.t_edge < e.t_centre
    # At the edge crossing, the intruder's outermost corner is on the line.
    _, edge = ci.overlap_series(tr, 394, np.array([e.t_edge]), 2, 1)
    assert abs(edge[0]) < 0.05
    # Gap = longitudinal distance of the centres minus half of both lengths (independent formula).
    xi = np.interp(e.t_centre, table.t[sl], table.x[sl])
    sf = tr.rows[395]
    xf = np.interp(e.t_centre, table.t[sf], table.x[sf])
    assert e.gap == pytest.approx(xi - xf - 0.5 * (table.length[sl][0] + table.length[sf][0]), abs=1e-3)
    assert e.follower_after_s == pytest.approx(4.2)
    fb = ci.fall_back(tr, 395, e.t_centre)
    assert fb[0] == 0.0 and np.all(np.isfinite(fb))


def test_i80_cut_in_is_found_at_the_lane_id_jump() -> None:
    table = read_coifman(FIX / "coifman_cutin.csv.gz")
    tr = ci.Tracks(table)
    ev = ci.detect(tr, "i80", "i80-coifman", "i80", lambda f: "val", ci.CutInConfig(), lateral_measured=False)
    assert [(e.intruder, e.follower, e.old_leader) for e in ev] == [(13, 61, 43)]
    e = ev[0]
    assert e.t_centre == pytest.approx(94.5) and e.t_edge is None
    # Lane_ID (1-based) of the intruder jumps from 4 to 5 at frame 945 in the raw rows.
    with gzip.open(FIX / "coifman_cutin.csv.gz", "rt") as fh:
        raw = {int(r["Frame_ID"]): int(r["Lane_ID"]) for r in csv.DictReader(fh) if r["Vehicle_ID"] == "13"}
    assert raw[944] == 4 and raw[945] == 5
    assert (e.lane_from, e.lane_to) == (3, 4)


def test_cut_in_detection_and_rule_replay_are_deterministic() -> None:
    table = read_commonroad(FIX / "USA_US101-3_1_T-1_cutin.xml.gz")
    tr = ci.Tracks(table)
    cfg = ci.CutInConfig()
    a = ci.detect(tr, "us101", "s", "g", lambda f: "train", cfg, lateral_measured=True)
    b = ci.detect(tr, "us101", "s", "g", lambda f: "train", cfg, lateral_measured=True)
    assert a == b
    e = next(x for x in a if x.intruder == 394)
    drivers = np.array([[1.2, 2.0, 1.5, 2.0, 1.3], [0.8, 3.0, 2.5, 3.0, 1.1]])
    th = np.array([-0.5, 0.0, 0.5, 1.0])
    s1 = simulate_event(tr, e, drivers, th, YieldConfig())
    s2 = simulate_event(tr, e, drivers, th, YieldConfig())
    assert s1.by_threshold.tobytes() == s2.by_threshold.tobytes()
    # Reacting earlier never leaves the follower further ahead at the end of the horizon here.
    end = s1.pos_err[:, -1]
    assert np.all(np.diff(end) >= -1e-9)


def test_replay_without_intruder_reaction_matches_the_plain_simulator() -> None:
    """With a threshold the intruder never reaches, the replay is the follower behind its old leader."""
    table = read_commonroad(FIX / "USA_US101-3_1_T-1_cutin.xml.gz")
    tr = ci.Tracks(table)
    e = next(x for x in ci.detect(tr, "us101", "s", "g", lambda f: "train", ci.CutInConfig(), True) if x.intruder == 394)
    drivers = np.array([[1.2, 2.0, 1.5, 2.0, 1.3]])
    s = simulate_event(tr, e, drivers, np.array([50.0]), replace(YieldConfig(), lead_in_s=2.0))
    assert np.isnan(s.switch_s[0])
    t_ref = e.t_edge if e.t_edge is not None else e.t_centre
    t_s = max(t_ref - 2.0, e.t_centre - e.follower_before_s)
    n = int(np.floor((e.t_centre + e.follower_after_s - t_s) / 0.1 + 1e-9)) + 1
    t = t_s + np.arange(n) * 0.1
    xf = tr.series(395, "x", t) + 0.5 * tr.series(395, "length", t)
    lr = tr.series(383, "x", t) - 0.5 * tr.series(383, "length", t)
    v_ref = float(np.max(table.speed[tr.rows[395]]))
    sim = simulate_follower(xf[0], tr.series(395, "speed", t)[0], lr, tr.series(383, "speed", t), drivers[:, :4],
                            1.3 * v_ref, 0.1)
    x_end = np.interp(e.t_centre + 4.2, t, sim.x[0])
    real_end = tr.series(395, "x", np.array([e.t_centre + 4.2]))[0] + 0.5 * table.length[tr.rows[395]][0]
    assert s.pos_err[0, -1] == pytest.approx(x_end - real_end, abs=1e-9)


# ------------------------------------------------------------------------------------ whole data


@pytest.mark.skipif(not DATA.exists(), reason="shared NGSIM data not present")
def test_splits_follow_the_data_pipeline_manifest() -> None:
    import json

    from nudge_train.idm.sources import load_sources

    manifest = Path(__file__).resolve().parents[3] / "data" / "processed" / "manifest.json"
    if not manifest.exists():
        pytest.skip("no processed manifest to compare with")
    src = load_sources(DATA)
    m = json.loads(manifest.read_text())
    want = {s["name"].split(".")[0]: s["split"] for s in m["sources"] if s["kind"] == "commonroad" and s["split"] != "excluded"}
    assert {s.name: s.split for s in src.us101} == want
    blocks = [s["split"] for s in m["sources"] if s["kind"] == "coifman_block"]
    assert [b[2] for b in src.i80_blocks] == blocks


# --------------------------------------------------------------------------------- shipped assets


ASSETS = Path(__file__).resolve().parents[3] / "assets" / "worlds"


def test_shipped_idm_parameters_are_complete_and_inside_the_box() -> None:
    import json

    path = ASSETS / "idm.json"
    assert path.stat().st_size < 100_000
    doc = json.loads(path.read_text())
    assert doc["schema"] == "nudge.idm/1"
    names = doc["parameter_names"]
    assert names == ["T", "s0", "a_max", "b", "v0_ratio"]
    drivers = np.asarray(doc["drivers"], dtype=np.float64)
    assert drivers.shape[1] == 5 and drivers.shape[0] == len(doc["driver_sources"]) >= 100
    lo = np.array([doc["bounds"][n][0] for n in names])
    hi = np.array([doc["bounds"][n][1] for n in names])
    assert np.all(np.isfinite(drivers)) and np.all(drivers >= lo) and np.all(drivers <= hi)
    assert set(doc["driver_sources"]) == {"i80", "us101"}
    for key in ("i80", "us101", "all"):
        assert len(doc["pooled"][key]) == 5
    rule = doc["intrusion"]
    assert np.isfinite(rule["threshold_m"]) and 0.0 <= rule["p_yield"] <= 1.0
    assert doc["model"]["delta"] == 4.0


def test_shipped_cut_in_events_read_back() -> None:
    events = ci.read_events(ASSETS / "cutins.json")
    assert len(events) >= 50
    assert {e.source for e in events} == {"i80", "us101"}
    assert all(e.split in ("train", "val", "test") and 0 < e.gap <= 60.0 for e in events)
    assert len({e.key for e in events}) == len(events)


def test_world_golden_is_current() -> None:
    """The shared case the Rust idm world is tested against is what this model computes now."""
    from nudge_train import paths
    from nudge_train.idm import golden

    assert (paths.repo() / golden.GOLDEN).read_text() == golden.text(), "rerun python -m nudge_train.idm.golden"


# ------------------------------------------------------------------- hostile cut-in files (issue 49)


def _cutins_doc() -> dict:
    import json

    return json.loads((Path(__file__).resolve().parents[3] / "assets" / "worlds" / "cutins.json").read_text())


def test_cutins_file_opened_by_the_checked_open(tmp_path: Path) -> None:
    """A FIFO is refused without blocking (before: blocked forever), a device without reading
    it (before: /dev/zero read until memory ran out), each a ConfigError naming the file."""
    import os
    import signal

    from nudge_train.errors import ConfigError

    fifo = tmp_path / "cutins.json"
    os.mkfifo(fifo)

    def _alarm(*_: object) -> None:
        raise TimeoutError("reading a FIFO blocked")

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(10)
    try:
        with pytest.raises(ConfigError, match=r"cutins\.json.*not a regular file"):
            ci.read_events(fifo)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    with pytest.raises(ConfigError, match=r"/dev/zero.*not a regular file"):
        ci.read_events(Path("/dev/zero"))


@pytest.mark.parametrize(("mutate", "match"), [
    (lambda d: d["events"][3].update(gap=float("nan")), r"events\[3\]\.gap.*not a finite number"),
    (lambda d: d["events"][5].pop("follower"), r"events\[5\].*missing.*follower"),
    (lambda d: d["events"][0].update(colour="red"), r"events\[0\].*unknown.*colour"),
    (lambda d: d["events"][2].update(intruder=1.5), r"events\[2\]\.intruder.*integer"),
    (lambda d: d["events"][2].update(t_edge="x"), r"events\[2\]\.t_edge.*number"),
    (lambda d: d["events"].__setitem__(1, [1, 2]), r"events\[1\].*object"),
    (lambda d: d.update(events={}), r"events.*list"),
    (lambda d: d["config"].update(zzz=1), r"config.*unknown.*zzz"),
])
def test_cutins_file_is_validated_naming_the_item(tmp_path: Path, mutate, match: str) -> None:
    """Issue 49 class 11: cutins.json was not validated (NaN accepted, bare TypeError/KeyError):
    every event and the config are checked, the error a ConfigError naming the item."""
    import json

    from nudge_train.errors import ConfigError

    doc = _cutins_doc()
    mutate(doc)
    p = tmp_path / "cutins.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(ConfigError, match=match):
        ci.read_events(p)
        ci.read_config(p)


def test_shipped_cutins_file_reads() -> None:
    events = ci.read_events(Path(__file__).resolve().parents[3] / "assets" / "worlds" / "cutins.json")
    assert len(events) == 97 and events[0].follower == 491


# ------------------------------------------------------------- property: hostile cut-in files


from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**70), 2**70), st.booleans(),
                    st.none(), st.text(max_size=4), st.lists(st.integers(), max_size=2), st.just({}))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_cutins_reader_property(data: st.DataObject) -> None:
    """Any edit of the shipped cut-in file is read as valid events (every field of its type,
    numbers finite) or refused with a ConfigError naming the file; never another exception."""
    import json
    import math
    import tempfile

    from nudge_train.errors import ConfigError

    doc = _cutins_doc()
    for _ in range(data.draw(st.integers(0, 3))):
        i = data.draw(st.integers(0, len(doc["events"]) - 1))
        kind = data.draw(st.sampled_from(["value", "drop", "add", "replace_event", "config"]))
        ev = doc["events"][i]
        if kind == "value" and isinstance(ev, dict) and ev:
            ev[data.draw(st.sampled_from(sorted(ev)))] = data.draw(_VALUES)
        elif kind == "drop" and isinstance(ev, dict) and ev:
            del ev[data.draw(st.sampled_from(sorted(ev)))]
        elif kind == "add" and isinstance(ev, dict):
            ev[data.draw(st.text(max_size=5))] = 1
        elif kind == "replace_event":
            doc["events"][i] = data.draw(_VALUES)
        elif kind == "config":
            doc["config"][data.draw(st.sampled_from(sorted(doc["config"]) + ["x"]))] = data.draw(_VALUES)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "cutins.json"
        p.write_text(json.dumps(doc))
        try:
            events = ci.read_events(p)
            cfg = ci.read_config(p)
        except ConfigError as err:
            assert "cutins.json" in str(err)
            return
    for e in events:
        for f in ci.CutIn.__dataclass_fields__:
            v = getattr(e, f)
            assert v is None or isinstance(v, str) or (not isinstance(v, bool) and math.isfinite(v)), (f, v)
    assert all(math.isfinite(getattr(cfg, f)) for f in ci.CutInConfig.__dataclass_fields__)
