"""What planning with a predictor written in Python costs per predictor call, against the
built-in predictors, one thread (docs/python_predictor.md). Run::

    nudge-train bench python-predictor [--seeds 2] [--torch-plans 6] [--markdown FILE]

Every shipped scene is planned from its start (a cold-start ``Planner.plan_scenario`` per
target-lane seed ``0..seeds``) with four predictors:

* ``constant_velocity`` (Rust) and the same constant velocity written in numpy
  (:class:`NumpyConstantVelocity`, its prediction computed in ``set_scene``, so ``predict`` is
  almost free): their plans are bit-identical, with the same predictor calls, so the
  difference of the two MPC calls' times divided by the calls is the cost of the Python
  boundary per call (GIL, two read-only arrays, the call, the prediction's check and copy);
* ``student`` (Rust) and the same student network run by PyTorch (:class:`TorchStudent`, the
  model class of ``nudge_train`` with the shipped weights), on the first ``torch_plans`` plans.

Per MPC call, the time per predictor call is the call's time outside the two input QPs
(``total_s - delta_s - alpha_s``: the Z-updates, the roll-out check, the set-up) divided by
its predictor calls; the table gives its median, p99 and max over the plans.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import nudge


class NumpyConstantVelocity:
    """Constant velocity in numpy, the prediction cached per scene: the Python boundary alone."""

    def __init__(self) -> None:
        self.one = np.empty((0, 0, 2))

    def set_scene(self, history: np.ndarray) -> None:
        last, prev = history[1:, -1], history[1:, -2]
        k = np.arange(1, 7, dtype=np.float64)[None, :, None]
        self.one = (last[:, None, :] + k * (last - prev)[:, None, :])[None]

    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        return np.broadcast_to(self.one, (candidates.shape[0], *self.one.shape[1:]))


class TorchStudent:
    """The shipped student network run by PyTorch (float32), timing its own calls."""

    def __init__(self, weights: Path) -> None:
        import torch

        from nudge_train.models.interactive import student_interactive
        from nudge_train.training.export import load_generator

        self.torch, self.forward = torch, student_interactive
        self.net = load_generator(weights)
        self.history = torch.empty(0)
        self.inside: list[float] = []

    def set_scene(self, history: np.ndarray) -> None:
        self.history = self.torch.tensor(history, dtype=self.torch.float32)

    def predict(self, history: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        cands = self.torch.tensor(candidates, dtype=self.torch.float32)
        out = self.forward(self.net, self.history, cands).numpy()
        self.inside.append(time.perf_counter() - t0)
        return out


@dataclass
class Arm:
    """One predictor's plans: per MPC call, the time per predictor call (s) and the plan."""

    name: str
    per_call: list[float] = field(default_factory=list)
    calls: list[int] = field(default_factory=list)
    plans: list[dict[str, Any]] = field(default_factory=list)


def per_call(plan: dict[str, Any]) -> float:
    """Time of the MPC call outside its input QPs per predictor call (s)."""
    t = plan["timings"]
    return (t["total_s"] - t["delta_s"] - t["alpha_s"]) / max(plan["predictor_calls"], 1)


def run_arm(name: str, predictor: Any, problems: list[tuple[nudge.Scenario, int]],
            after_warm_up: Callable[[], None] | None = None) -> Arm:
    """Cold-start plans of every (scene, seed), after one warm-up plan (then ``after_warm_up``)."""
    settings = nudge.PlannerSettings.default()
    nudge.Planner(settings, predictor).plan_scenario(problems[0][0], seed=problems[0][1])
    if after_warm_up is not None:
        after_warm_up()
    arm = Arm(name)
    for sc, seed in problems:
        plan = nudge.Planner(settings, predictor).plan_scenario(sc, seed=seed)
        arm.per_call.append(per_call(plan))
        arm.calls.append(plan["predictor_calls"])
        arm.plans.append(plan)
    return arm


def stats(values: list[float], scale: float = 1e6) -> str:
    """``median | p99 | max`` of seconds in µs (``scale`` 1e3: ms)."""
    v = np.asarray(values) * scale
    return f"{np.median(v):.1f} | {np.percentile(v, 99):.1f} | {v.max():.1f}"


def boundary(python: Arm, rust: Arm) -> list[float]:
    """Per MPC call, (Python time - Rust time) / calls (s) of bit-identical plans."""
    out = []
    for p, r in zip(python.plans, rust.plans, strict=True):
        if not (np.array_equal(p["states"], r["states"]) and p["predictor_calls"] == r["predictor_calls"]):
            raise AssertionError("the numpy and Rust constant-velocity plans differ")
        out.append((p["timings"]["total_s"] - r["timings"]["total_s"]) / max(p["predictor_calls"], 1))
    return out


def table(arms: list[Arm], extra: list[tuple[str, list[float]]]) -> str:
    lines = [
        "| predictor | MPC calls | predictor calls per MPC call (median) | MPC call ms: median | p99 | max "
        "| µs per predictor call: median | p99 | max |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for a in arms:
        mpc = stats([p["timings"]["total_s"] for p in a.plans], 1e3)
        lines.append(f"| {a.name} | {len(a.plans)} | {int(np.median(a.calls))} | {mpc} | {stats(a.per_call)} |")
    for name, values in extra:
        lines.append(f"| {name} | {len(values)} | - | - | - | - | {stats(values)} |")
    return "\n".join(lines)


def run(*, seeds: int, torch_plans: int, markdown: Path | None) -> int:
    """``nudge-train bench python-predictor``: prints the table (and writes it to
    ``markdown``)."""
    import torch

    torch.set_num_threads(1)
    scenes = [nudge.Scenario.load(p) for p in nudge.scene_paths()]
    problems = [(sc, s) for s in range(seeds) for sc in scenes]
    student = nudge.Predictor.load(nudge.model_path("student"))
    torch_student = TorchStudent(nudge.model_path("student"))
    arms = [
        run_arm("constant_velocity (Rust)", nudge.Predictor.constant_velocity(), problems),
        run_arm("constant velocity in numpy (Python)", NumpyConstantVelocity(), problems),
        run_arm("student (Rust)", student, problems[:torch_plans]),
    ]
    arms.append(run_arm("student in PyTorch (Python)", torch_student, problems[:torch_plans],
                        torch_student.inside.clear))
    extra = [
        ("Python boundary: numpy minus Rust constant velocity, same plans", boundary(arms[1], arms[0])),
        ("inside the PyTorch student's predict (one call each)", torch_student.inside),
    ]
    head = (f"nudge {nudge.__version__}, torch {torch.__version__}, one thread; cold-start MPC calls on the "
            f"{len(scenes)} shipped scenes x target-lane seeds 0..{seeds - 1} (student rows: the first "
            f"{torch_plans}); per MPC call, time outside the input QPs / predictor calls.")
    text = head + "\n\n" + table(arms, extra)
    print(text)
    if markdown is not None:
        markdown.write_text(text + "\n")
    return 0
