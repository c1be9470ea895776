"""Where a measured table came from: the commit of the code that produced it."""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from pathlib import Path

#: the measured tables the scripts write: a change there does not make the code dirty
RESULTS_DIR = "docs/results/"


def commit_stamp(repo: Path, paths: Sequence[str] = ()) -> str:
    """The short HEAD of ``repo``, with ``+dirty`` when tracked files differ from it (only
    those under ``paths`` when given; never the measured tables in ``docs/results/``);
    ``unknown`` outside a git checkout."""
    head = _git(repo, "rev-parse", "--short", "HEAD")
    status = _git(repo, "status", "--porcelain", "--untracked-files=no", "--", *paths)
    dirty = [line for line in status.splitlines() if RESULTS_DIR not in line]
    return head + ("+dirty" if dirty and head != "unknown" else "")


def _git(repo: Path, *args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
