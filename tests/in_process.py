"""Running a console app in the test process, as a fresh interpreter would run it (its
``main()`` with its argv, working directory and environment; its output captured), and
putting back everything it changed in the process."""

from __future__ import annotations

import contextlib
import importlib
import io
import logging
import os
import site
import subprocess
import sys
import sysconfig
import traceback
import warnings
from collections.abc import Iterator
from pathlib import Path


def run_app_in_process(
    module: str, *overrides: str, cwd: Path, env: dict[str, str]
) -> subprocess.CompletedProcess:
    """`run_app` in this process: the app's ``main()`` with ``sys.argv`` set as the console
    script would, in ``cwd``, with ``env`` added to the environment and its stdout/stderr
    captured. Everything a run changes in the process is put back afterwards: the
    environment, working directory, logging, warning filters, signal handlers, Hydra's global
    state, ``sys.path`` and torch's thread count."""
    args = [f"hysteresis-lab-{module}", *overrides]
    stdout, stderr = io.StringIO(), io.StringIO()
    with _process_state_restored(cwd, env), contextlib.redirect_stdout(stdout), \
            contextlib.redirect_stderr(stderr):
        sys.argv = list(args)
        try:
            importlib.import_module(f"hysteresis_lab.cli.{module}").main()
            status = 0
        except SystemExit as exc:
            status = _exit_status(exc.code)
        except Exception:  # noqa: BLE001 - as the interpreter would: traceback, status 1
            traceback.print_exc()
            status = 1
    return subprocess.CompletedProcess(args, status, stdout.getvalue(), stderr.getvalue())


def _exit_status(code: object) -> int:
    """The process exit status ``sys.exit(code)`` gives."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    sys.stderr.write(f"{code}\n")
    return 1


@contextlib.contextmanager
def _process_state_restored(cwd: Path, env: dict[str, str]) -> Iterator[None]:
    """The block runs as a fresh interpreter's app would, in ``cwd`` with ``env`` added;
    afterwards the process is as before."""
    import torch
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    from hysteresis_lab.interrupts import stopping_on_signals

    root = logging.getLogger()
    saved_handlers, saved_level = list(root.handlers), root.level
    saved_loggers = {
        name: (logger.level, list(logger.handlers), logger.propagate, logger.disabled)
        for name, logger in logging.Logger.manager.loggerDict.items()
        if isinstance(logger, logging.Logger)
    }
    saved_environ, saved_argv, saved_cwd = dict(os.environ), list(sys.argv), os.getcwd()
    saved_threads, saved_path = torch.get_num_threads(), list(sys.path)
    os.environ.update(env)
    os.chdir(cwd)
    # packages installed since this process started (a test's `pip install -e <plugin>`), as
    # a fresh interpreter would see them: their .pth entries
    site.addsitedir(sysconfig.get_paths()["purelib"])
    root.handlers[:] = []  # a fresh interpreter's logging: no handler (pytest's are put back)
    root.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings(), stopping_on_signals():
            warnings.resetwarnings()  # a fresh interpreter's filters and display
            for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning,
                             ResourceWarning):
                warnings.simplefilter("ignore", category)
            warnings.showwarning = _show_warning
            yield
    finally:
        for handler in root.handlers:
            if handler not in saved_handlers:
                handler.close()
        root.handlers[:] = saved_handlers
        root.setLevel(saved_level)
        for name, (level, handlers, propagate, disabled) in saved_loggers.items():
            logger = logging.getLogger(name)
            logger.setLevel(level)
            logger.handlers[:] = handlers
            logger.propagate, logger.disabled = propagate, disabled
        os.environ.clear()
        os.environ.update(saved_environ)
        sys.argv, sys.path[:] = saved_argv, saved_path
        os.chdir(saved_cwd)
        torch.set_num_threads(saved_threads)
        GlobalHydra.instance().clear()  # as after a fresh interpreter's app: no Hydra set up
        HydraConfig.instance().cfg = None


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python's own warning display, to the stderr of the moment (the captured one)."""
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))
