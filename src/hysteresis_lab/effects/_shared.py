"""Helpers the built-in effects share: operators per input channel, time constants in words,
and the base of the effects read from the model's own output."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hysteresis_lab.effects.base import Effect, FeatureContext


def seconds(taus: np.ndarray) -> str:
    """Time constants as ``0.1, 1 s``."""
    return ", ".join(f"{t:.3g}" for t in taus) + " s"


def per_input(u: np.ndarray, make: Callable[[np.ndarray, int], np.ndarray]) -> np.ndarray:
    """``make(channel, index)`` of every input channel of ``u`` (N, nu), side by side."""
    return np.column_stack([make(u[:, i], i) for i in range(u.shape[1])])


class ReadFromModelOutput(Effect):
    """An effect with no input operators whose evidence is the model's own free-run output
    (`Effect.output_evidence`), placed on its training range."""

    def features(self, u: np.ndarray, ctx: FeatureContext) -> np.ndarray:
        return np.zeros((len(u), 0))

    @staticmethod
    def _on_range(y_model: np.ndarray, span: tuple[float, float]) -> tuple[np.ndarray, float,
                                                                            float]:
        """The output as a 1-D array, the range's low end and its width."""
        low, high = span
        return np.asarray(y_model, dtype=float).reshape(-1), low, max(high - low, 1e-12)
