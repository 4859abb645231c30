"""Quick start: plan a lane change on a shipped real NGSIM scene, then drive it closed loop.

Run from the repository root after `make develop`: `.venv/bin/python examples/python/quick_start.py`
(or with the installed wheel: `python examples/python/quick_start.py`).
"""

import nudge

scene = next(p for p in nudge.scene_paths() if p.stem == "us101-11_1-t02.1-ego144")
sc = nudge.Scenario.load(scene)  # agent 0 = ego; road frame: x along the road, y to the left (m)
student = nudge.Predictor.load(nudge.model_path("student"))  # the distilled predictor
planner = nudge.Planner(nudge.PlannerSettings.default(), student)

# One MPC step: 6 steps of 0.3 s towards the lane that seed 1 draws (the closed loop below
# draws the same lane for this scene).
plan = planner.plan_scenario(sc, seed=1)
x, y, psi, v = plan["states"][-1]
print(f"start: y = {sc.history[0, -1, 1]:.2f} m, {sc.speed[0]:.1f} m/s")
print(f"plan: {plan['status']}, target lane {plan['target_lane']} (centre y = {plan['y_target']:.2f} m)")
print(f"after 1.8 s: y = {y:.2f} m, heading {psi:.3f} rad, {v:.1f} m/s")

# Closed loop: re-plan every 0.3 s while the teacher moves the other vehicles.
runs = nudge.simulate([scene], "student", seed=1)["runs"]
print(
    f"closed loop: success {runs['success'][0]}, settled in lane {runs['target_lane'][0]} "
    f"after {runs['steps_to_target'][0]} steps, collision {runs['collision'][0]}"
)
