"""Stop signals as an exception: with `stop_on_signals`, SIGINT (Ctrl-C) and SIGTERM (a
scheduler, ``kill``) raise `RunInterrupted` in the main thread, except inside
`signals_deferred` blocks (a checkpoint being written), where they act at the block's end.

`RunInterrupted` is a ``BaseException``, so no ``except Exception`` swallows it, and Lightning
re-raises it after closing its loggers (its own handling of Ctrl-C ends the process with
status 1). A second signal while a stopped run winds down ends the process at once. The
command-line apps turn it into an exit status and one line (`hysteresis_lab.cli._interrupt`).
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator
from types import FrameType
from typing import Any

#: the signals that stop a run (Ctrl-C; a scheduler's or ``kill``'s request)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class RunInterrupted(BaseException):  # noqa: N818 - not an error: a request to stop
    """SIGINT or SIGTERM arrived (``signum``)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_status(self) -> int:
        """The shell's convention for a process a signal ended: 128 + its number."""
        return 128 + self.signum


class _State:
    stopping = False  # RunInterrupted was raised: the run winds down
    deferring = 0  # depth of signals_deferred blocks
    pending: int | None = None  # a signal that arrived in one


def _on_signal(signum: int, frame: FrameType | None) -> None:
    if _State.stopping:  # asked again while winding down: stop now
        os._exit(128 + signum)
    if _State.deferring:
        _State.pending = signum
        return
    _State.stopping = True
    raise RunInterrupted(signum)


def stop_on_signals(signals: tuple[int, ...] = STOP_SIGNALS) -> dict[int, Any]:
    """``signals`` raise `RunInterrupted` from now on (call in the main thread); returns the
    handlers they had."""
    _State.stopping, _State.pending = False, None
    previous = {signum: signal.getsignal(signum) for signum in signals}
    for signum in signals:
        signal.signal(signum, _on_signal)
    return previous


@contextlib.contextmanager
def stopping_on_signals(signals: tuple[int, ...] = STOP_SIGNALS) -> Iterator[None]:
    """`stop_on_signals` for the block; the earlier handlers afterwards."""
    previous = stop_on_signals(signals)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """A stop signal that arrives in the block raises `RunInterrupted` at its end, so that
    what the block writes (a checkpoint) is written whole."""
    _State.deferring += 1
    try:
        yield
    finally:
        _State.deferring -= 1
        if not _State.deferring and _State.pending is not None:
            signum, _State.pending = _State.pending, None
            _State.stopping = True
            raise RunInterrupted(signum)
