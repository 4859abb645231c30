"""A long ``nudge.simulate`` answers Ctrl-C: SIGINT raises KeyboardInterrupt within about a
second (the batch stops at the next closed-loop step of every run), and the interpreter is
usable afterwards."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest


# A batch that runs for minutes on one thread: every shipped scene, many runs each.
SCRIPT = """
import signal, sys, time
import nudge
# Python leaves SIGINT ignored when it starts ignored (a background job of a non-interactive
# shell); Ctrl-C in a terminal is what this checks, so install Python's own handler.
signal.signal(signal.SIGINT, signal.default_int_handler)
paths = nudge.scene_paths()
print("started", flush=True)
t0 = time.monotonic()
try:
    nudge.simulate(paths, "student", runs=200, threads=1, max_steps=30)
except KeyboardInterrupt:
    print(f"interrupted {time.monotonic() - t0:.3f}", flush=True)
    # The interpreter is usable afterwards, and so is the extension.
    r = nudge.simulate(paths[:1], "constant_velocity", world="log_replay", max_steps=1, threads=1)
    print("after", len(r["runs"]["scenario"]), flush=True)
    sys.exit(0)
print("finished without interruption", flush=True)
sys.exit(1)
"""


def interrupt(args: list[str], wait: float) -> tuple[str, float, str, str, int]:
    """Runs ``python -c *args``, sends SIGINT ``wait`` s after it prints ``started`` (while it
    still runs); its first line after the signal, how long that line took (s), the rest of its
    output, its stderr and its exit status."""
    proc = subprocess.Popen([sys.executable, "-c", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    assert proc.stdout is not None
    try:
        assert proc.stdout.readline().strip() == "started"
        time.sleep(wait)
        assert proc.poll() is None, proc.communicate()
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        line = proc.stdout.readline().strip()
        answered = time.monotonic() - sent
        rest, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert line.startswith("interrupted"), f"no KeyboardInterrupt: {line!r} {err}"
    return line, answered, rest, err, proc.returncode


def test_simulate_answers_ctrl_c_within_a_second() -> None:
    _, answered, rest, err, status = interrupt([SCRIPT], 1.0)  # the batch is running
    assert answered < 1.5, f"KeyboardInterrupt came {answered:.2f} s after SIGINT"
    assert "after 1" in rest, rest + err
    assert status == 0, err


# One planning step that runs for a long time: settings at the ends of their ranges (ADMM that
# never converges, 100 descent steps of 30 halvings) call the predictor up to the work cap
# (5,000 calls) or the wall-clock cap (30 s); the slow Python predictor makes each call 20 ms,
# the teacher about 1 ms. Ctrl-C must end the step itself, not wait for it.
STEP_SCRIPT = """
import signal, sys, time
import numpy as np
import nudge
signal.signal(signal.SIGINT, signal.default_int_handler)


class Slow:
    def predict(self, history, candidates):
        time.sleep(0.02)
        last, prev = history[1:, -1], history[1:, -2]
        k = np.arange(1, candidates.shape[1] + 1, dtype=np.float64)[None, :, None]
        one = last[:, None, :] + k * (last - prev)[:, None, :]
        return np.broadcast_to(one, (candidates.shape[0], *one.shape)).copy()


settings = nudge.PlannerSettings.default().replace(
    admm={"max_iter": 10000, "pgd_steps": 100, "pgd_halvings": 30, "eps_primal": 1e-9, "eps_change": 1e-9},
    repair={"refine_iters": 20})
what, predictor = sys.argv[1], sys.argv[2]
# The scene with the most agents: the teacher's calls are dearest there (a step reaches the
# 5,000-call cap after about 1.2-1.7 s on a 2-core machine).
paths = [max(nudge.scene_paths(), key=lambda p: nudge.Scenario.load(p).n_agents)]
p = Slow() if predictor == "python" else nudge.Predictor.load(nudge.model_path(predictor))
scenario = nudge.Scenario.load(paths[0])
planner = nudge.Planner(settings, p)
print("started", flush=True)
t0 = time.monotonic()
try:
    if what == "plan":
        planner.plan_scenario(scenario)
    else:
        nudge.simulate(paths, p if predictor == "python" else predictor, settings=settings, threads=1,
                       max_steps=30)
except KeyboardInterrupt:
    print(f"interrupted {time.monotonic() - t0:.3f}", flush=True)
    # The interpreter and the planner are usable afterwards.
    plan = nudge.Planner(None, nudge.Predictor.constant_velocity()).plan_scenario(nudge.Scenario.load(paths[0]))
    print("after", plan["status"], flush=True)
    sys.exit(0)
print(f"finished without interruption {time.monotonic() - t0:.3f}", flush=True)
sys.exit(1)
"""


@pytest.mark.parametrize("what", ["plan", "simulate"])
@pytest.mark.parametrize("predictor", ["python", "teacher"])
def test_ctrl_c_ends_a_long_planning_step(what: str, predictor: str) -> None:
    """SIGINT during one long MPC call (``Planner.plan_scenario``, or a step of
    ``nudge.simulate``) raises KeyboardInterrupt within about a second, with a Python and a
    built-in predictor, and the interpreter plans again afterwards."""
    # Inside the first planning step: the teacher's lasts about a second (the work cap), the
    # slow Python predictor's up to 30 s (the wall-clock cap).
    _, answered, rest, err, status = interrupt([STEP_SCRIPT, what, predictor], 0.3 if predictor == "teacher" else 1.5)
    # Well before the step would have ended by itself (at least ~0.9 s later for the teacher).
    assert answered < 0.5, f"KeyboardInterrupt came {answered:.2f} s after SIGINT"
    assert "after " in rest, rest + err
    assert status == 0, err
