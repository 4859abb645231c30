"""Test fixtures: :mod:`~nudge_train.testing.synthetic` (seeded synthetic highway scenes) and
:mod:`~nudge_train.testing.goldens` (the golden files of the Rust predictor tests and the
benchmark scenes, ``nudge-train goldens``)."""
