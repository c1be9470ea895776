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
import functools
import os
import signal
import sys
import threading
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
    stopping: int | None = None  # RunInterrupted was raised for this signal: the run winds down
    deferring = 0  # depth of signals_deferred blocks
    pending: int | None = None  # a signal that arrived in one
    pid = 0  # the process that installed the handler


def _on_signal(signum: int, frame: FrameType | None) -> None:
    if os.getpid() != _State.pid:  # a forked child (a data-loader worker): its parent stops
        if signum == signal.SIGINT:  # Ctrl-C reaches the whole process group
            return
        os._exit(128 + signum)
    if _State.stopping is not None:  # asked again while winding down: stop now
        os._exit(128 + signum)
    if _State.deferring:
        _State.pending = signum
        return
    _State.stopping = signum
    raise RunInterrupted(signum)


def _quiet_when_lost(unraisable: Any, *, fallback: Any = None) -> None:
    """``sys.unraisablehook``: a `RunInterrupted` raised where Python ignores exceptions is
    no traceback on the terminal (it is raised again: `raise_if_stopped`)."""
    if isinstance(unraisable.exc_value, RunInterrupted):
        return
    (fallback or sys.__unraisablehook__)(unraisable)


def stop_on_signals(signals: tuple[int, ...] = STOP_SIGNALS) -> dict[int, Any]:
    """``signals`` raise `RunInterrupted` from now on; returns the handlers they had. Only the
    main thread handles signals: called in another (a launcher's), it changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    _State.stopping, _State.pending, _State.pid = None, None, os.getpid()
    previous = {signum: signal.getsignal(signum) for signum in signals}
    for signum in signals:
        signal.signal(signum, _on_signal)
    hook = sys.unraisablehook
    if getattr(hook, "func", None) is not _quiet_when_lost:
        sys.unraisablehook = functools.partial(_quiet_when_lost, fallback=hook)
    return previous


@contextlib.contextmanager
def stopping_on_signals(signals: tuple[int, ...] = STOP_SIGNALS) -> Iterator[None]:
    """`stop_on_signals` for the block; the earlier handlers (and no stop signal received)
    afterwards."""
    hook = sys.unraisablehook
    previous = stop_on_signals(signals)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        sys.unraisablehook = hook
        _State.stopping = _State.pending = None


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
            _State.stopping = signum
            raise RunInterrupted(signum)


def stop_signal() -> int | None:
    """The stop signal that arrived since `stop_on_signals`, None when none did."""
    return _State.stopping


def raise_if_stopped() -> None:
    """Raise `RunInterrupted` again when a stop signal arrived: its first one is lost where
    it was raised in code whose exceptions Python ignores (a ``__del__``, such as a data
    loader's shutting down its workers)."""
    if _State.stopping is not None:
        raise RunInterrupted(_State.stopping)
