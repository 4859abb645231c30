"""nudge_train: data pipeline, training, distillation, experiments and figures for the nudge planner.

Layout: :mod:`~nudge_train.cli` (the ``nudge-train`` command), :mod:`~nudge_train.paths` (every
default path; ``NUDGE_REPO`` / ``NUDGE_ASSETS``), :mod:`~nudge_train.constants` (time grid,
window lengths, schema names), :mod:`~nudge_train.provenance` (file hashes, commit), and the
subpackages ``data`` (NGSIM pipeline, training-window loader), ``models`` (networks),
``training`` (configs, loop, evaluation, export), ``distill`` (distillation set),
``experiments`` (teacher / student / closed-loop experiments, benches, figures) and ``testing``
(synthetic scenes, golden files).
"""
