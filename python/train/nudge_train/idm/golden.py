"""The shared case of the Rust ``idm`` world and this package's IDM model.

A platoon of three vehicles on one lane, simulated with :func:`nudge_train.idm.model.simulate_follower`
(the model the drivers were fitted with): a leader on a free road whose desired speed is below its
speed (it slows down), and two followers each behind the simulated vehicle ahead. The Rust world
(``crates/sim/src/idm.rs``) integrates the same vehicles together and must reproduce
every position and speed to 1e-9.

Writes ``crates/sim/tests/golden/idm_platoon.json``; rerunning gives identical bytes
(``python -m nudge_train.idm.golden [--check]``, also checked by the test suite).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from nudge_train import paths
from nudge_train.idm.model import GAP_FLOOR, MAX_DECEL, simulate_follower

GOLDEN = Path("crates/sim/tests/golden/idm_platoon.json")
"""Repository-relative path of the shared case."""

DT_SUB = 0.1
"""Sub-step (s): the world's 0.3 s step in three ballistic sub-steps."""
SUBSTEPS = 91
"""Recorded sub-steps (the initial state and 90 updates: 30 closed-loop steps)."""
DELTA = 4.0

# (front position m, speed m/s, length m, T s, s0 m, a_max m/s^2, b m/s^2, v0 m/s): three US-101
# drivers of assets/worlds/idm.json with desired speeds chosen so that the leader slows down.
VEHICLES = (
    (60.0, 14.0, 4.5, 2.3987, 3.2982, 0.3, 3.761, 10.0),
    (38.0, 16.0, 4.0, 0.3683, 2.7953, 1.3439, 0.6427, 20.0),
    (12.0, 15.0, 5.0, 0.5218, 2.8465, 1.13, 0.6888, 18.0),
)


def platoon() -> dict:
    """The case: every vehicle's parameters and its simulated front position and speed
    [SUBSTEPS] (m, m/s)."""
    out = []
    lead_rear = np.full(SUBSTEPS, np.nan)
    lead_v = np.zeros(SUBSTEPS)
    for front, v, length, t, s0, a_max, b, v0 in VEHICLES:
        params = np.array([[t, s0, a_max, b]])
        sim = simulate_follower(front, v, lead_rear, lead_v, params, v0, DT_SUB, DELTA)
        x, speed = sim.x[0], sim.v[0]
        out.append({"front": front, "v": v, "length": length, "T": t, "s0": s0, "a_max": a_max, "b": b,
                    "v0": v0, "x_front": [float(a) for a in x], "speed": [float(a) for a in speed]})
        lead_rear, lead_v = x - length, speed
    return {"generator": "python -m nudge_train.idm.golden", "dt": DT_SUB, "delta": DELTA, "max_decel": MAX_DECEL,
            "gap_floor": GAP_FLOOR, "vehicles": out}


def text() -> str:
    """The golden file's text."""
    return json.dumps(platoon(), indent=1) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write the golden file, or with ``--check`` report whether it is current (exit 1 if not)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="compare instead of writing")
    a = p.parse_args(argv)
    path = paths.repo() / GOLDEN
    if a.check:
        ok = path.is_file() and path.read_text() == text()
        print(f"{GOLDEN}: {'up to date' if ok else 'out of date'}")
        return 0 if ok else 1
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text())
    print(f"wrote {GOLDEN}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
