"""Stopping a command-line run: SIGINT (Ctrl-C) and SIGTERM (a scheduler, ``kill``) end it
with exit status 130 or 143 and one logged line that says what its run folder keeps and how
to resume (`hysteresis_lab.interrupts`); while it runs, the folder is locked against a second
run (`hysteresis_lab.run_lock`).
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from hydra.core.hydra_config import HydraConfig

from hysteresis_lab.interrupts import RunInterrupted, stop_on_signals, stop_signal
from hysteresis_lab.run_folder import RunFolder
from hysteresis_lab.run_lock import hold_run_folder

log = logging.getLogger("hysteresis_lab")

T = TypeVar("T")


def interruptible(resumable: bool) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """Run a Hydra task function (``task(cfg)``) holding its run folder's lock; turn
    `RunInterrupted` into one logged line and exit status 130 (SIGINT) or 143 (SIGTERM).
    ``resumable``: a rerun in the folder goes on from what it keeps (training, the loop);
    else the line says to run the command again."""

    def decorate(task: Callable[..., T]) -> Callable[..., T]:
        @functools.wraps(task)
        def wrapper(cfg: Any, *args: Any, **kwargs: Any) -> T:
            output_dir = Path(HydraConfig.get().runtime.output_dir)
            stop_on_signals()
            try:
                with hold_run_folder(output_dir):
                    result = task(cfg, *args, **kwargs)
            except RunInterrupted as exc:
                log.error("%s", interrupted_message(exc, output_dir, resumable))
                sys.exit(exc.exit_status)
            late = stop_signal()  # its exception was lost, and the run finished
            if late is not None:
                stopped = RunInterrupted(late)
                log.error("stopped by %s as the run ended (exit status %d); %s holds its "
                          "complete results", stopped.name, stopped.exit_status, output_dir)
                sys.exit(stopped.exit_status)
            return result

        return wrapper

    return decorate


def run_console_app(hydra_main: Callable[[], Any]) -> None:
    """A console script's body: a signal before or after the run itself (while Hydra starts
    or ends) ends it with the same status and one line, too."""
    stop_on_signals()
    try:
        hydra_main()
    except RunInterrupted as exc:
        log.error("stopped by %s outside the run (starting or ending): nothing to resume",
                  exc.name)
        sys.exit(exc.exit_status)


def interrupted_message(exc: RunInterrupted, output_dir: Path, resumable: bool) -> str:
    """One line: the signal, what ``output_dir`` keeps, how to go on."""
    if not resumable:
        return (f"stopped by {exc.name} (exit status {exc.exit_status}); its results in "
                f"{output_dir} are incomplete. Run the same command again to redo it.")
    kept = _kept(output_dir)
    return (
        f"stopped by {exc.name} (exit status {exc.exit_status}); {output_dir} keeps "
        f"{kept}. To resume, run the same command with hydra.run.dir={output_dir}"
    )


def _kept(output_dir: Path) -> str:
    """What a rerun resumes from: finished fits (the loop's rounds, the paper's models) and
    the last checkpoints of unfinished ones."""
    parts = []
    finished = sorted(path.parent for path in output_dir.rglob(RunFolder.FIT_RECORD))
    if finished:
        names = ", ".join(_relative(path, output_dir) for path in finished)
        parts.append(f"{len(finished)} finished fit(s) ({names})")
    for last in sorted(output_dir.rglob(RunFolder.LAST_CHECKPOINT)):
        parts.append(f"{_relative(last, output_dir)}{_epochs(last)}")
    return " and ".join(parts) if parts else "no finished epoch (it starts over)"


def _relative(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix() or "."


def _epochs(checkpoint: Path) -> str:
    """`` (<n> epochs done)`` as the checkpoint records it, or nothing."""
    import torch

    try:
        epoch = torch.load(checkpoint, map_location="cpu", weights_only=True)["epoch"]
    except Exception:  # noqa: BLE001 - only a detail of the message
        return ""
    return f" ({int(epoch) + 1} epoch(s) done)"
