"""Shared plumbing of the Hydra command-line apps: config location and error reporting."""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable
from typing import TypeVar

from omegaconf import DictConfig

from hysteresis_lab.cli._overrides import check_override_types
from hysteresis_lab.errors import HysteresisLabError

log = logging.getLogger("hysteresis_lab")

T = TypeVar("T")


#: the packaged Hydra configs (src/hysteresis_lab/conf), found in any install (wheel, sdist,
#: editable) through the import system
CONFIG_PATH = "pkg://hysteresis_lab.conf"


def report_errors(task: Callable[..., T]) -> Callable[..., T]:
    """Check the overrides' types (`check_override_types`), then run ``task``; turn a
    `HysteresisLabError` into one logged line and exit status 2 (no traceback)."""

    @functools.wraps(task)
    def wrapper(*args, **kwargs):
        try:
            if args and isinstance(args[0], DictConfig):
                check_override_types(args[0])
            return task(*args, **kwargs)
        except HysteresisLabError as exc:
            log.error("%s", exc)
            sys.exit(2)

    return wrapper
