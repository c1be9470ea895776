"""Test helpers: small simulated CSV data sets and running the console apps (in this process or
a subprocess)."""

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

from hysteresis_lab.data.readers import write_csv
from hysteresis_lab.signals import multisine, sine
from hysteresis_lab.sim.positioner import simulate_recording

REPO = Path(__file__).resolve().parents[1]
FAST_EFFECTS = {"creep": {"enabled": False}}


def small_dataset(
    directory: Path, n_train: int = 3000, fs: float = 2000.0, effects: dict | None = None
) -> tuple[Path, list[Path]]:
    """A multisine training CSV and two sine test CSVs (t,u,y), simulated at ``fs``."""
    effects = effects if effects is not None else FAST_EFFECTS
    cfg = {**effects, "mode1": {"frequency_hz": 300.0}}
    train = simulate_recording(
        multisine(n_train, fs=fs, n_components=50, f_max=50.0, seed=1),
        fs,
        cfg,
        seed=1,
        name="train",
    )
    tests = [
        simulate_recording(sine(f, fs=fs, n_periods=2), fs, cfg, seed=2, name=f"sine_{f:g}")
        for f in (5.0, 20.0)
    ]
    train_path = write_csv(train, directory / "train.csv")
    test_paths = [write_csv(rec, directory / f"{rec.name}.csv") for rec in tests]
    return train_path, test_paths


def data_overrides(train: Path, tests: list[Path]) -> list[str]:
    return ["data=csv", f"data.train={train}", f"data.test=[{','.join(map(str, tests))}]"]


def run_app(
    module: str,
    *overrides: str,
    cwd: Path | None = None,
    env: dict | None = None,
    timeout: float = 600,
    subprocess_only: bool = False,
) -> subprocess.CompletedProcess:
    """Run the console app ``hysteresis_lab.cli.<module>`` with ``overrides``; capture its
    output and exit status.

    In this test process (`run_app_in_process`: no 8 s of ``import lightning`` per call),
    unless ``subprocess_only`` or ``env`` sets ``PYTHONPATH`` (a plugin on the path), which
    need a fresh interpreter: then ``python -m hysteresis_lab.cli.<module>``."""
    env = {"HYDRA_FULL_ERROR": "0", **(env or {})}
    if subprocess_only or "PYTHONPATH" in env:
        return subprocess.run(
            [sys.executable, "-m", f"hysteresis_lab.cli.{module}", *overrides],
            cwd=cwd or REPO,
            capture_output=True,
            text=True,
            timeout=timeout,
            env={**os.environ, **env},
        )
    return run_app_in_process(module, *overrides, cwd=cwd or REPO, env=env)


def run_app_in_process(
    module: str, *overrides: str, cwd: Path, env: dict[str, str]
) -> subprocess.CompletedProcess:
    """`run_app` in this process: the app's ``main()`` with ``sys.argv`` set as the console
    script would, in ``cwd``, with ``env`` added to the environment and its stdout/stderr
    captured. Everything a run changes in the process is put back afterwards: the
    environment, working directory, logging, warning filters, signal handlers, Hydra's
    singletons, ``sys.path`` and torch's thread count."""
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


def popen_app(
    module: str, *overrides: str, cwd: Path | None = None, env: dict | None = None
) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", f"hysteresis_lab.cli.{module}", *overrides],
        cwd=cwd or REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(env or {})},
        start_new_session=True,
    )


def sweep_args(results: Path, n_trials: int, *extra: str, search: str = "ffnn") -> list[str]:
    """A small tuning sweep (``-m hparams_search=<search>``) writing under ``results``."""
    return [
        "-m",
        f"hparams_search={search}",
        f"hydra.sweeper.results_dir={results}",
        f"hydra.sweeper.n_trials={n_trials}",
        "hydra.sweeper.n_startup_trials=2",
        "trainer.max_epochs=2",
        "trainer.enable_progress_bar=false",
        f"hydra.sweep.dir={results}/runs",
        "model.neurons=range(8,33)",
        *extra,
    ]
