"""Simulate one shipped real scene closed loop in the three worlds and print its metrics.

Each run re-plans every 0.3 s with the distilled student until the ego has settled in the
target lane (or `max_steps`); the world moves the other vehicles: `teacher` (the teacher
predicts their reaction to the ego's plan), `idm` (fitted car-following drivers), `log_replay`
(the logged traffic, which never reacts). Run from the repository root after `make develop`:
`.venv/bin/python examples/python/simulate_scene.py`.
"""

import numpy as np

import nudge

scene = next(p for p in nudge.scene_paths() if p.stem == "us101-11_1-t02.1-ego144")
config = nudge.SimConfig(max_steps=30)  # every field: nudge.SimConfig.describe()

print(f"{scene.stem}, planner: student, seed 1 (TTC in s, lateral acceleration in m/s²)")
print(f"{'world':<11}{'success':>8}{'steps':>6}{'at fault':>9}{'min TTC':>8}"
      f"{'max lat acc':>12}{'comfort':>8}{'score':>7}{'median plan ms':>15}")
for world in ("teacher", "idm", "log_replay"):
    out = nudge.simulate([scene], "student", seed=1, config=config.replace(world=world))
    run = {k: v[0] for k, v in out["runs"].items()}  # one run: column -> its value
    plan_ms = 1e3 * np.median(out["steps"]["mpc_s"])  # wall-clock time of each MPC call
    print(f"{world:<11}{run['success']!s:>8}{run['steps_to_target']:>6}"
          f"{run['collisions_at_fault']:>9}{run['min_ttc']:>8.2f}{run['max_abs_lat_accel']:>12.2f}"
          f"{run['comfortable']!s:>8}{run['score']:>7.3f}{plan_ms:>15.2f}")
