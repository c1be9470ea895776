"""What the command-line apps show on the terminal: one progress display, each line once,
the libraries' known noise left out; the run's full log still goes to its ``<app>.log``.

Nothing here runs on import: the console apps call `filter_library_warnings` from their entry
point and run their task inside `terminal` (after Hydra has set up logging).
"""

from __future__ import annotations

import logging
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext

#: ``log.info(..., extra=SUMMARY)``: a line the terminal shows also where it shows only a
#: summary (`terminal` with ``summary_only``: the loop's one line per round)
SUMMARY = {"summary": True}

#: library warnings that say nothing a user of this package can act on (message regexes)
NOISE_WARNINGS = (
    # Lightning's own use of a torch API it has not caught up with
    r"`isinstance\(treespec, LeafSpec\)` is deprecated",
    # short recordings have fewer batches than Lightning's logging interval: the epoch's
    # losses are logged all the same
    r"The number of training batches \(\d+\) is smaller than the logging interval",
    # outputs/optuna/best exists only after a finished sweep (experiment=best_<study>); until
    # then its search-path entry is empty, which is normal
    r"provider=hydra\.searchpath in main, path=outputs/optuna/best is not",
)

#: Lightning's info lines that are advertisements or never apply here (message prefixes)
NOISE_LOG_LINES = (
    "💡 Tip:",  # litlogger / litmodels advertisements
    "TPU available:",
    "HPU available:",
    "IPU available:",
    "`Trainer.fit` stopped: `max_epochs=",  # the normal end; the epoch display shows it
    "LOCAL_RANK:",  # CUDA_VISIBLE_DEVICES of a one-device fit
    # advice to call torch.set_float32_matmul_precision, which no setting here reaches
    "You are using a CUDA device",
)

#: the loggers Lightning gives their own console handler on import
LIGHTNING_LOGGERS = ("lightning", "lightning.pytorch", "lightning.fabric")


def filter_library_warnings() -> None:
    """Hide the library warnings of `NOISE_WARNINGS` (every other warning still shows)."""
    for message in NOISE_WARNINGS:
        warnings.filterwarnings("ignore", message=message)


class _DropNoise(logging.Filter):
    """Drops Lightning's lines of `NOISE_LOG_LINES`."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(NOISE_LOG_LINES)


#: the start of Lightning's line on the devices a fit uses
DEVICE_LINE = "GPU available:"


class _SummaryOnly(logging.Filter):
    """Passes warnings, errors, the lines logged with `SUMMARY` and the first of Lightning's
    device lines (whether the fits use a GPU)."""

    def __init__(self) -> None:
        super().__init__()
        self.device_shown = False

    def filter(self, record: logging.LogRecord) -> bool:
        if not self.device_shown and str(record.msg).startswith(DEVICE_LINE):
            self.device_shown = True
            return True
        return record.levelno >= logging.WARNING or bool(getattr(record, "summary", False))


def console_handlers() -> list[logging.Handler]:
    """The root logger's handlers that write to the terminal (Hydra's ``console``)."""
    return [
        handler for handler in logging.getLogger().handlers
        if isinstance(handler, logging.StreamHandler)
        and getattr(handler, "stream", None) in (sys.stdout, sys.stderr)
    ]


def log_file() -> str | None:
    """The file the root logger writes the full log to (Hydra's ``<app>.log``), if any."""
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            return handler.baseFilename
    return None


def route_lightning_logging() -> None:
    """Lightning's lines reach the terminal once, through the root logger's handlers (Hydra's
    console and log file), not also through the console handler Lightning adds on import."""
    import lightning  # noqa: F401  (its import adds the handler this removes)

    for name in LIGHTNING_LOGGERS:
        logger = logging.getLogger(name)
        for handler in [h for h in logger.handlers if not isinstance(h, logging.FileHandler)]:
            logger.removeHandler(handler)
        logger.propagate = True


@contextmanager
def terminal(summary_only: bool = False) -> Iterator[None]:
    """Run a console app's task with a tidy terminal: Lightning's lines once and without its
    noise, log lines written above a progress bar instead of into it; with ``summary_only``
    the terminal shows only warnings, errors, the lines logged with `SUMMARY` and the first
    device line (the log file keeps everything). Warnings become log lines (``py.warnings``)
    while it runs."""
    from tqdm.contrib.logging import logging_redirect_tqdm

    route_lightning_logging()
    added: list[tuple[logging.Handler, logging.Filter]] = []
    for handler in logging.getLogger().handlers:
        added.append((handler, _DropNoise()))
    if summary_only:
        added += [(handler, _SummaryOnly()) for handler in console_handlers()]
    for handler, log_filter in added:
        handler.addFilter(log_filter)
    logging.captureWarnings(True)  # warnings that pass the filters: log lines, above the bar
    # (no console handler, e.g. hydra/job_logging=disabled: nothing to redirect, none added)
    redirect = logging_redirect_tqdm() if console_handlers() else nullcontext()
    try:
        with redirect:
            yield
    finally:
        logging.captureWarnings(False)
        for handler, log_filter in added:
            handler.removeFilter(log_filter)
