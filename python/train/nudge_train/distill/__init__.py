"""Distillation data: closed-loop planning with the teacher over the planner scenarios of each
split, recording every candidate the Z-update evaluates with its history and the teacher's
interactive prediction (the student's training set). See docs/distill.md."""

from .config import DistillConfig
from .pipeline import ShardSpec, generate, plan_shards, run_shard
from .scenes import scene_interactive, split_scenes

__all__ = ["DistillConfig", "ShardSpec", "generate", "plan_shards", "run_shard", "scene_interactive", "split_scenes"]
