"""Typed errors of the training package: every one names the item it is about.

:class:`NudgeTrainError` is the base; the ``nudge-train`` command prints any of them as
``error: <message>`` (no traceback) and exits with status 2.

* :class:`~nudge_train.data.errors.DataError` (a subclass, in ``nudge_train.data``): bad input
  data, naming the file, row and field;
* :class:`ArtefactError`: a file nudge wrote itself (shard, manifest entry, checkpoint) that fails
  its integrity check (content hash, sha256 in a manifest, non-finite values, unreadable);
* :class:`ConfigError`: a JSON or TOML file we read (training configs, weights metadata,
  manifests, summaries) that is malformed, including duplicate keys;
* :class:`TrainingError`: training cannot continue (a non-finite loss or validation metric),
  naming the epoch and batch.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["ArtefactError", "ConfigError", "NudgeTrainError", "TrainingError"]


class NudgeTrainError(Exception):
    """Base of every typed error of ``nudge_train``."""


class ArtefactError(NudgeTrainError, RuntimeError):
    """A written artefact fails its integrity check. ``path``: the file; ``message``: what failed."""

    def __init__(self, path: Path | str, message: str) -> None:
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")


class ConfigError(NudgeTrainError, ValueError):
    """A JSON/TOML file is malformed. ``path``: the file (or the metadata entry read from it);
    ``key``: the offending key where known; ``row``: 1-based line where known."""

    def __init__(self, path: Path | str, message: str, key: str | None = None, row: int | None = None) -> None:
        self.path = str(path)
        self.key = key
        self.row = row
        self.message = message
        where = self.path if row is None else f"{self.path}, row {row}"
        super().__init__(f"{where}: {message}")


class TrainingError(NudgeTrainError, RuntimeError):
    """Training stopped: ``epoch`` (0-based) and ``batch`` (0-based, ``None`` for the validation
    pass) where it happened; the message prints them 1-based."""

    def __init__(self, message: str, epoch: int, batch: int | None = None) -> None:
        self.epoch = epoch
        self.batch = batch
        self.message = message
        where = f"epoch {epoch + 1}" + (f", batch {batch + 1}" if batch is not None else ", validation")
        super().__init__(f"{message} at {where}")
