"""A long ``nudge.simulate`` answers Ctrl-C: SIGINT raises KeyboardInterrupt within about a
second (the batch stops at the next closed-loop step of every run), and the interpreter is
usable afterwards."""

from __future__ import annotations

import signal
import subprocess
import sys
import time


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


def test_simulate_answers_ctrl_c_within_a_second() -> None:
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    assert proc.stdout is not None
    try:
        assert proc.stdout.readline().strip() == "started"
        time.sleep(1.0)  # the batch is running
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
    assert answered < 1.5, f"KeyboardInterrupt came {answered:.2f} s after SIGINT"
    assert "after 1" in rest, rest + err
    assert proc.returncode == 0, err
