"""The latency bench's numbers and tables against hand-computed cases, and one small run end to
end (shapes and counts only: no timing claims)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nudge_train import paths
from nudge_train.cli import build_parser, main
from nudge_train.experiments.bench_latency import (STATUSES, Arm, ArmResult, budget_table, bucket_index, bucket_labels,
                                                   latency_rows, latency_table, outcome_table, outcomes, paired,
                                                   percentiles, slow_statuses, status_shares, status_table,
                                                   write_section)
from nudge_train.experiments.latency_config import LatencyConfig


def _nearest_rank(values: np.ndarray, p: float) -> float:
    """The textbook nearest-rank percentile: the ceil(p / 100 * n)-th smallest value."""
    return float(np.sort(values)[math.ceil(p / 100 * values.size) - 1])


def test_percentiles_by_hand() -> None:
    shuffled = np.random.default_rng(0).permutation(np.arange(1.0, 101.0))
    assert percentiles(shuffled) == {"p50": 50.0, "p90": 90.0, "p99": 99.0, "max": 100.0}
    # Ten values: p99 is the largest (ceil(9.9) = 10th), p90 the 9th, p50 the 5th.
    assert percentiles(np.arange(10.0, 0.0, -1.0)) == {"p50": 5.0, "p90": 9.0, "p99": 10.0, "max": 10.0}
    assert percentiles([7.5]) == {"p50": 7.5, "p90": 7.5, "p99": 7.5, "max": 7.5}
    # One slow step among 200: it is the maximum but not the p99 (the 198th value).
    tail = np.concatenate([np.full(199, 2.0), [80.0]])
    assert percentiles(tail) == {"p50": 2.0, "p90": 2.0, "p99": 2.0, "max": 80.0}
    assert all(math.isnan(v) for v in percentiles([]).values())


def test_percentiles_are_the_nearest_rank_ones() -> None:
    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 99, 100, 101, 1234):
        v = rng.lognormal(1.0, 1.0, size=n)
        got = percentiles(v)
        for p in (50, 90, 99):
            assert got[f"p{p}"] == _nearest_rank(v, p), (n, p)
            assert got[f"p{p}"] in v
        assert got["max"] == v.max()


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_percentiles_refuse_non_finite_times(bad: float) -> None:
    with pytest.raises(ValueError, match="step time 2 is not finite"):
        percentiles([1.0, 2.0, bad, 3.0])


def test_buckets() -> None:
    assert bucket_labels((8, 16, 24)) == ["N ≤ 8", "9–16", "17–24", "N ≥ 25"]
    assert bucket_labels((10,)) == ["N ≤ 10", "N ≥ 11"]
    n = np.array([1, 8, 9, 16, 17, 24, 25, 40])
    assert bucket_index(n, (8, 16, 24)).tolist() == [0, 0, 1, 1, 2, 2, 3, 3]


def _result(predictor: str = "student", budget_ms: float | None = None, *, n_agents: list[int],
            step_runs: list[int], mpc_ms: list[float], statuses: list[str] | None = None,
            success: list[bool] | None = None, collision: list[bool] | None = None,
            errors: list[str | None] | None = None) -> ArmResult:
    k = len(n_agents)
    runs = {"scenario": [f"s{i}" for i in range(k)], "seed": list(range(k)), "n_agents": n_agents,
            "success": success if success is not None else [True] * k,
            "collision": collision if collision is not None else [False] * k,
            "collisions_at_fault": [int(c) for c in (collision or [False] * k)],
            "collisions_not_at_fault": [0] * k, "error": errors if errors is not None else [None] * k}
    steps = {"run": step_runs, "mpc_s": [m / 1e3 for m in mpc_ms],
             "status": statuses if statuses is not None else ["Converged"] * len(step_runs)}
    return ArmResult(Arm(predictor, budget_ms), runs, steps, wall_s=1.0)


def test_latency_rows_per_bucket() -> None:
    # Run 0 (N = 5) has steps 1, 3 ms; run 1 (N = 12) 2, 4, 30 ms; run 2 (N = 20) 21.5 ms;
    # run 3 (N = 12) could not run and has no steps.
    res = _result(n_agents=[5, 12, 20, 12], step_runs=[0, 0, 1, 1, 1, 2],
                  mpc_ms=[1.0, 3.0, 2.0, 4.0, 30.0, 21.5], errors=[None, None, None, "bad scene"])
    rows = latency_rows(res, (8, 16, 24), over_ms=21.0)
    assert [r["bucket"] for r in rows] == ["all", "N ≤ 8", "9–16", "17–24"]  # no run with N >= 25
    assert [(r["runs"], r["steps"]) for r in rows] == [(3, 6), (1, 2), (1, 3), (1, 1)]
    assert [r["over"] for r in rows] == [2, 0, 1, 1]
    assert rows[0]["p50"] == pytest.approx(3.0) and rows[0]["max"] == pytest.approx(30.0)
    assert rows[0]["p90"] == pytest.approx(30.0)  # ceil(0.9 * 6) = 6th of six
    assert (rows[2]["p50"], rows[2]["p99"]) == (pytest.approx(4.0), pytest.approx(30.0))
    assert rows[3]["p50"] == pytest.approx(21.5)
    assert "over" not in latency_rows(res, (8, 16, 24))[0]
    # A step time exactly at the bound is not above it.
    edge = _result(n_agents=[5], step_runs=[0, 0], mpc_ms=[21.0, 21.25])
    assert latency_rows(edge, (8,), over_ms=21.0)[0]["over"] == 1
    with pytest.raises(ValueError, match="run 4"):
        latency_rows(_result(n_agents=[5], step_runs=[0, 4], mpc_ms=[1.0, 2.0]), (8,))


def test_status_shares() -> None:
    shares = status_shares(["Converged"] * 6 + ["Fallback"] * 3 + ["Refined"])
    assert list(shares) == list(STATUSES)
    assert shares["Converged"] == pytest.approx(0.6) and shares["Fallback"] == pytest.approx(0.3)
    assert shares["Refined"] == pytest.approx(0.1) and shares["Unsafe"] == 0.0
    # A status the report does not know is kept, not dropped.
    odd = status_shares(["Converged", "Mystery", "Converged", "Aardvark"])
    assert list(odd)[-2:] == ["Aardvark", "Mystery"] and odd["Mystery"] == 0.25
    assert sum(odd.values()) == pytest.approx(1.0)
    assert status_shares([]) == {}


def test_outcomes_and_pairing() -> None:
    off = _result(n_agents=[10, 10, 10, 10], step_runs=[0], mpc_ms=[1.0],
                  success=[True, True, False, False], collision=[False, False, True, False])
    on = _result(budget_ms=20.0, n_agents=[10, 10, 10, 10], step_runs=[0], mpc_ms=[1.0],
                 success=[True, False, True, False], collision=[True, False, False, False],
                 errors=[None, None, None, "failed"])
    assert outcomes(off) == {"runs": 4, "errors": 0, "success": 2, "collision_runs": 1, "collisions": 1}
    assert outcomes(on) == {"runs": 3, "errors": 1, "success": 2, "collision_runs": 1, "collisions": 1}
    # Run 3 failed with the budget: three pairs. Run 1 lost its success, run 2 gained one; run 0
    # collides only with the budget, run 2 only without.
    assert paired(off, on) == {"pairs": 3, "success_off": 2, "success_on": 2, "collision_off": 1,
                               "collision_on": 1, "success_lost": 1, "success_gained": 1, "collision_new": 1,
                               "collision_gone": 1}


def test_tables() -> None:
    off = _result(n_agents=[5, 12], step_runs=[0, 1, 1], mpc_ms=[1.0, 25.0, 3.0],
                  statuses=["Converged", "Fallback", "Converged"])
    on = _result(budget_ms=20.0, n_agents=[5, 12], step_runs=[0, 1, 1], mpc_ms=[1.0, 20.5, 3.0],
                 statuses=["Converged", "BudgetExhausted", "Converged"])
    lat = latency_table([off, on], (8, 16), 20.0).splitlines()
    assert lat[0].endswith("| steps > 21 ms |")
    assert lat[2] == "| student | off | all | 2 | 3 | 3.00 | 25.0 | 25.0 | 25.0 | 1 |"
    assert lat[5] == "| student | 20 ms | all | 2 | 3 | 3.00 | 20.5 | 20.5 | 20.5 | 0 |"
    assert "steps >" not in latency_table([off], (8, 16), None)
    st = status_table([off, on]).splitlines()
    assert st[2].startswith("| student | off | 3 | 66.7 % | 0.0 % | 0.0 % | 0.0 % | 33.3 % |")
    assert st[3] == "| student | 20 ms | 3 | 66.7 % | 0.0 % | 0.0 % | 0.0 % | 0.0 % | 0.0 % | 33.3 % | 0.0 % |"
    assert slow_statuses(off, 21.0) == {"Fallback": 1} and slow_statuses(on, 20.0) == {"BudgetExhausted": 1}
    assert slow_statuses(on, 21.0) == {}
    on.cpu_s = 0.25  # of wall_s = 1.0
    assert outcome_table([on]).splitlines()[2] == "| student | 20 ms | 2 | 0 | 2 | 0 | 0 | 1 | 25 % |"
    bud = budget_table([off, on], (8, 16), 20.0).splitlines()
    assert bud[2] == "| student | 2 | 1 → 0 | 25.0 → 20.5 | 2 → 2 | 0 / 0 | 0 → 0 | 0 / 0 |"


def test_write_section_replaces_its_own_section_only(tmp_path: Path) -> None:
    out = tmp_path / "docs" / "latency.md"
    write_section(out, "budget off", "### Budget off\nfirst\n")
    assert out.read_text() == ("# Planning-step latency in closed loop\n\n<!-- bench latency: budget off -->\n"
                               "### Budget off\nfirst\n<!-- /bench latency: budget off -->\n")
    write_section(out, "budget 20 ms", "### Budget 20 ms\nsecond\n")
    text = out.read_text().replace("# Planning-step latency in closed loop\n", "# Title\n\nHand-written notes.\n")
    out.write_text(text + "\nMore notes.\n")
    write_section(out, "budget off", "### Budget off\nrerun\n")
    new = out.read_text()
    assert new.startswith("# Title\n\nHand-written notes.\n") and new.endswith("\nMore notes.\n")
    assert "first" not in new and new.count("rerun") == 1 and new.count("second") == 1
    assert new.index("rerun") < new.index("second")  # the section stays where it was
    write_section(out, "budget off", "### Budget off\nrerun\n")
    assert out.read_text() == new


@pytest.mark.parametrize(("change", "message"), [
    ({"n": 0}, "--n"), ({"runs": 0}, "--runs"), ({"teacher_n": 0}, "--teacher-n"), ({"chunk": 0}, "--chunk"),
    ({"predictors": ()}, "--predictors"), ({"predictors": ("student", "student")}, "twice"),
    ({"world": "predictor"}, "--world"), ({"budget_ms": 0.0}, "--budget-ms"), ({"budget_ms": math.nan}, "--budget-ms"),
    ({"n_edges": (16, 8)}, "--n-edges"), ({"n_edges": ()}, "--n-edges"),
])
def test_config_names_the_bad_argument(change: dict, message: str) -> None:
    cfg = LatencyConfig(scenes=Path("scenes"), **change)
    with pytest.raises(ValueError, match=message):
        cfg.validate()


def test_cli_defaults() -> None:
    a = build_parser().parse_args(["bench", "latency"])
    assert (a.split, a.scenes, a.n, a.seed, a.runs, a.world, a.budget_ms, a.teacher_n) == (
        "test", None, 120, 0, 1, "teacher", None, None)
    assert a.predictors == ["student", "teacher", "constant_velocity"] and a.n_edges == [8, 16, 24]
    assert a.out == paths.repo() / "docs" / "results" / "latency.md"


def test_bad_arguments_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "latency", "--n", "0", "--out", str(tmp_path / "x.md")]) == 2
    assert "--n must be >= 1" in capsys.readouterr().err
    assert main(["bench", "latency", "--scenes", str(tmp_path), "--out", str(tmp_path / "x.md")]) == 2
    assert "no scenario files" in capsys.readouterr().err
    assert not (tmp_path / "x.md").exists()


def test_small_run_end_to_end(tmp_path: Path) -> None:
    """Two shipped scenes, the constant-velocity planner with and without a budget: the section
    is written and its counts agree between the tables."""
    out = tmp_path / "latency.md"
    assert main(["bench", "latency", "--scenes", str(paths.shipped_scenes()), "--n", "2",
                 "--predictors", "constant_velocity", "--budget-ms", "50", "--no-progress", "--out", str(out)]) == 0
    text = out.read_text()
    assert "<!-- bench latency: budget 50 ms -->" in text and "<!-- /bench latency: budget 50 ms -->" in text
    cells = [ln.strip("|").split(" | ") for ln in text.splitlines() if ln.startswith("| constant_velocity |")]
    cells = [[c.strip() for c in row] for row in cells]
    for budget in ("off", "50 ms"):
        # Latency rows: predictor, budget, N, runs, steps, p50, p90, p99, max, steps > 51 ms.
        latency = [c for c in cells if c[1] == budget and c[2] == "all"]
        assert len(latency) == 1 and latency[0][3] == "2" and int(latency[0][4]) > 0
        # Status rows: predictor, budget, steps, one share per status.
        status = [c for c in cells if c[1] == budget and len(c) == 3 + len(STATUSES)]
        assert len(status) == 1 and status[0][2] == latency[0][4]
        shares = [float(x.rstrip(" %")) for x in status[0][3:]]
        assert len(shares) == len(STATUSES) and sum(shares) == pytest.approx(100.0, abs=0.05 * len(shares))
    paired_rows = [c for c in cells if c[1] == "2"]  # predictor, paired runs, ...
    # Runs rows: predictor, budget, runs, errors, success, ... (no run fails here: the same runs)
    success = {c[1]: c[4] for c in cells if len(c) == 9 and c[1] in ("off", "50 ms")}
    assert len(paired_rows) == 1 and paired_rows[0][4] == f"{success['off']} → {success['50 ms']}"


def test_horizons_run_side_by_side(tmp_path: Path) -> None:
    """``--horizons 6 10``: every predictor at both horizons on the same runs, in a section of its
    own; a student asked for 10 steps is refused before any run (exit 2, naming the horizon)."""
    out = tmp_path / "latency.md"
    assert main(["bench", "latency", "--scenes", str(paths.shipped_scenes()), "--n", "2",
                 "--predictors", "constant_velocity", "--horizons", "6", "10", "--no-progress",
                 "--out", str(out)]) == 0
    text = out.read_text()
    assert "<!-- bench latency: budget off, horizons 6 10 -->" in text
    rows = [ln for ln in text.splitlines() if ln.startswith("| constant_velocity, h = ")]
    assert {r.split(" | ")[0] for r in rows} == {"| constant_velocity, h = 6", "| constant_velocity, h = 10"}
    with pytest.raises(ValueError, match="--horizons"):
        LatencyConfig(scenes=Path("s"), horizons=(6, 6)).validate()
    assert main(["bench", "latency", "--scenes", str(paths.shipped_scenes()), "--n", "1", "--predictors", "student",
                 "--horizons", "10", "--no-progress", "--out", str(tmp_path / "y.md")]) == 2
    assert not (tmp_path / "y.md").exists()
