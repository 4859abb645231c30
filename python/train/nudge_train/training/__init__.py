"""Training and evaluation of the networks: :mod:`~nudge_train.training.config` (TOML training
configs), :mod:`~nudge_train.training.loop` (the training loop, checkpoints, ``nudge-train
train``), :mod:`~nudge_train.training.log` (the per-epoch metrics log),
:mod:`~nudge_train.training.evaluate` (ADE / FDE and the constant-velocity baseline),
:mod:`~nudge_train.training.export` (weights files for the Rust predictor),
:mod:`~nudge_train.training.reaction_measure` (a model's reaction to the ego's plan) and
:mod:`~nudge_train.training.reaction` (distillation with a loss on that reaction).

Nothing here imports :mod:`nudge_train.experiments` (tests/test_layering.py): the experiments
build on the library, not the other way round."""
