"""One process per run folder: `hold_run_folder` takes an operating-system lock on the
folder's ``run.lock`` (`RunFolder.LOCK`) for as long as a run writes there.

The lock belongs to the open file, so it goes when the process ends, however it ends: a lock
file left by a killed run never blocks the next one.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.run_folder import RunFolder

try:  # POSIX
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]
    import msvcrt


@contextlib.contextmanager
def hold_run_folder(path: Path) -> Iterator[None]:
    """Hold ``path``'s run lock (creating the folder) for the block; a folder whose lock
    another process holds is refused with a `ConfigError`."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    lock_path = RunFolder(path).lock
    descriptor = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    with os.fdopen(descriptor, "r+") as handle:
        if not _try_lock(handle):
            raise ConfigError(
                f"the run folder {path} is in use by another run{_holder(lock_path)}. Fix: "
                "wait for that run to end, or give this one its own folder "
                "(hydra.run.dir=<another folder>)."
            )
        try:
            if fcntl is not None:  # the holder's process id, for that message
                handle.seek(0)
                handle.truncate()
                handle.write(f"{os.getpid()}\n")
                handle.flush()
            yield
        finally:
            _unlock(handle)


def _try_lock(handle: IO[str]) -> bool:
    try:
        if fcntl is not None:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        else:
            handle.seek(0)
            msvcrt.locking(handle.fileno(), msvcrt.LK_NBLCK, 1)
    except OSError:
        return False
    return True


def _unlock(handle: IO[str]) -> None:
    if fcntl is not None:
        fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
    else:
        handle.seek(0)
        msvcrt.locking(handle.fileno(), msvcrt.LK_UNLCK, 1)


def _holder(lock_path: Path) -> str:
    """`` (process <id>)`` as the lock file names it, or nothing."""
    try:
        pid = int(lock_path.read_text().strip())
    except (OSError, ValueError):
        return ""
    return f" (process {pid})"
