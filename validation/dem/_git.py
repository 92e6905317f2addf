"""The git state of the DEM scripts, for the provenance of runs and datasets."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _git(*args: str) -> str | None:
    try:
        return subprocess.run(["git", *args], cwd=HERE, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def state(*files: str | Path) -> dict:
    """HEAD's commit, and whether ``files`` (names beside this module, or paths) differ from it.

    ``scripts_modified`` is None outside a git checkout.
    """
    paths = [os.fspath(HERE / f) if not os.path.isabs(f) else os.fspath(f) for f in files]
    changes = _git("status", "--porcelain", "--", *paths)
    return {"commit": _git("rev-parse", "HEAD"),
            "scripts_modified": None if changes is None else bool(changes)}
