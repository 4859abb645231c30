"""NGSIM data pipeline: readers -> tidy track tables -> 0.3 s windows -> splits -> safetensors
shards + manifest, planner scenarios ("nudge.scenario/1") and the dataset report.

Formats: docs/data_schema.md. CLI: ``nudge-train data build|report|scenes``. The build side
(readers, :mod:`~nudge_train.data.windows`, :mod:`~nudge_train.data.build`) needs no torch;
:mod:`~nudge_train.data.loader` reads the shards back as torch batches for training.
"""
