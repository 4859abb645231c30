"""Training and evaluation of the networks: :mod:`~nudge_train.training.config` (TOML training
configs), :mod:`~nudge_train.training.loop` (the training loop, checkpoints, ``nudge-train
train``), :mod:`~nudge_train.training.log` (the per-epoch metrics log),
:mod:`~nudge_train.training.evaluate` (ADE / FDE and the constant-velocity baseline) and
:mod:`~nudge_train.training.export` (weights files for the Rust predictor)."""
