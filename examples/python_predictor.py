"""Plan with your own PyTorch predictor: any Python object with ``predict(history, candidates)``
(and, optionally, ``set_scene(history)``) can check the planner's candidates.

This one runs the shipped student network in PyTorch (the model class of ``nudge_train``, the
weights of ``assets/models/student.safetensors``): the same network as the built-in ``student``,
so the two plans agree up to float32 rounding, and the difference in time is the price of
predicting from Python. The way back to native speed for a model of your own is to distil it
into the built-in student format (``docs/python_predictor.md``).

Run from the repository root in the development environment (torch and ``nudge_train`` are
development dependencies; the ``nudge`` package needs neither)::

    .venv/bin/python examples/python_predictor.py
"""

from __future__ import annotations

import time

import numpy as np
import torch

import nudge
from nudge_train.models.interactive import student_interactive
from nudge_train.training.export import load_generator

SCENE = "us101-11_1-t02.1-ego132.safetensors"  # a shipped scene with dense traffic


class TorchStudent:
    """The student network in PyTorch, as a nudge predictor.

    ``history`` ``[n, 8, 2]`` and ``candidates`` ``[batch, horizon, 2]`` arrive as read-only
    float64 arrays (metres, road frame, 0.3 s steps, agent 0 = the ego); ``predict`` returns the
    other agents' positions ``[batch, n - 1, horizon, 2]`` (float32 is accepted).
    """

    def __init__(self, weights: str) -> None:
        self.net = load_generator(weights)  # eval mode
        self.horizon = self.net.cfg.t_plan  # optional: default is the planner's horizon
        self.history = torch.empty(0)
        self.calls = 0
        self.seconds = 0.0

    def set_scene(self, history: np.ndarray) -> None:
        # Once per planning step. torch.tensor copies (the array is read-only).
        self.history = torch.tensor(history, dtype=torch.float32)

    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        cands = torch.tensor(candidates, dtype=torch.float32)
        out = student_interactive(self.net, self.history, cands).numpy()
        self.calls += 1
        self.seconds += time.perf_counter() - t0
        return out


def main() -> None:
    torch.set_num_threads(1)
    scene = nudge.Scenario.load(nudge.assets_dir() / "scenes" / SCENE)
    settings = nudge.PlannerSettings.default()
    ours = TorchStudent(str(nudge.model_path("student")))
    planners = {
        "student (Rust)": nudge.Planner(settings, nudge.Predictor.load(nudge.model_path("student"))),
        "student (PyTorch)": nudge.Planner(settings, predictor=ours),
    }
    plans = {}
    for name, planner in planners.items():
        plans[name] = plan = planner.plan_scenario(scene, seed=0)
        last = plan["states"][-1]
        print(
            f"{name:>17}: status {plan['status']:<13} lateral move {last[1] - scene.history[0, -1, 1]:+.2f} m, "
            f"speed {last[3]:.2f} m/s after 1.8 s, {plan['predictor_calls']} predictor calls, "
            f"{plan['timings']['total_s'] * 1e3:.1f} ms"
        )
    rust, torch_plan = plans["student (Rust)"], plans["student (PyTorch)"]
    gap = float(np.abs(rust["states"] - torch_plan["states"]).max())
    print(f"largest difference between the two plans' states: {gap:.2e}")
    print(
        f"PyTorch inside predict: {ours.seconds / ours.calls * 1e3:.2f} ms per call over {ours.calls} calls "
        f"(the planner's whole call with the Rust student: {rust['timings']['total_s'] * 1e3:.1f} ms)"
    )
    # Same network, float32 on both sides: the plans agree (a different status or a gap of
    # centimetres would mean the predictions differ).
    assert ours.calls == torch_plan["predictor_calls"] > 0
    assert rust["status"] == torch_plan["status"], (rust["status"], torch_plan["status"])
    assert gap < 1e-2, gap


if __name__ == "__main__":
    main()
