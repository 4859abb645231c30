"""Provenance of the artefacts nudge writes: file hashes and the repository's commit."""

from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path

from nudge_train import paths

__all__ = ["git_commit", "machine", "scene_list_sha256", "sha256_file", "write_provenance"]


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def git_commit() -> str:
    """The repository's HEAD commit, or ``"unknown"`` outside a git checkout."""
    try:
        return subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=paths.repo(), capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


PROVENANCE_SCHEMA = "nudge.provenance/1"
"""The schema tag of a ``provenance.json`` (the fields of ``docs/records.md``)."""


def machine() -> dict[str, object]:
    """The machine: host name, operating system, architecture, CPU model, logical cores."""
    import os
    import platform

    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        cpu = platform.processor() or "unknown"
    return {"hostname": platform.node() or "unknown", "os": platform.system().lower(), "arch": platform.machine(),
            "cpu": cpu, "cores": os.cpu_count() or 1}


def scene_list_sha256(files: list[tuple[str, str]]) -> str:
    """sha256 of the lines ``<file name> <sha256>\\n`` of ``files`` (name, sha256), in order: the
    scene-list hash of ``provenance.json`` (``nudge::provenance::scene_list_sha256``)."""
    text = "".join(f"{name} {sha}\n" for name, sha in files)
    return hashlib.sha256(text.encode()).hexdigest()


def write_provenance(folder: Path, record: dict) -> Path:
    """Writes ``folder/provenance.json``: ``record`` after the schema tag, nudge's version and git
    commit (the extension's build), the time and the machine. Returns the file."""
    import json
    import time

    import nudge

    out = {"schema": PROVENANCE_SCHEMA, "nudge_version": nudge.__version__, "git_sha": nudge.GIT_SHA,
           "created_unix_s": int(time.time()), **record, "machine": machine()}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "provenance.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out, indent=1) + "\n")
    tmp.replace(path)
    return path
