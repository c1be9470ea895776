"""Project-wide exception types: every user-facing failure says what is wrong and how to fix it."""

from __future__ import annotations


class HysteresisLabError(Exception):
    """Base class of every error this package raises on purpose."""


class DataError(HysteresisLabError, ValueError):
    """Input data is unusable (NaNs, wrong shapes, missing columns, ...).

    The message names the source (file or recording), the problem and the fix.
    """

    def __init__(self, problem: str, *, source: str | None = None, fix: str | None = None):
        self.problem = problem
        self.source = source
        self.fix = fix
        parts = [f"{source}: {problem}" if source else problem]
        if fix:
            parts.append(f"Fix: {fix}")
        super().__init__(" ".join(parts))


class ConfigError(HysteresisLabError, ValueError):
    """A configuration value or override is invalid."""


class DivergedError(HysteresisLabError, RuntimeError):
    """Training produced only non-finite losses (a diverging free run, a too-large step)."""
