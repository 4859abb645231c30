"""Distillation data: closed-loop planning with the teacher over the planner scenarios of each
split, recording every candidate the Z-update evaluates with its history and the teacher's
interactive prediction (the student's training set). See docs/distill.md.

Modules: :mod:`~nudge_train.distill.config` (what to generate, size presets),
:mod:`~nudge_train.distill.scenes` (the scenes of each split), :mod:`~nudge_train.distill.pipeline`
(sharded, resumable generation with ``nudge.simulate``), :mod:`~nudge_train.distill.stats`
(statistics for docs/distill.md). Command: ``nudge-train distill``.
"""
