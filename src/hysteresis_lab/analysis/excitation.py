"""How hard the test recordings drive an effect's operators, against the identification data.

A refit learns an added effect's weights from the training data. Where the test recordings
drive the effect's operators far beyond anything those data showed (amplifier clipping
identified inside the linear range, play operators of wide thresholds under a multisine that
rarely turns at full amplitude), the refit learns the effect from data that show little of
it, and a small gain says more about the data than about the effect. The loop reports this
ratio for every effect it adds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import get_effect

#: above this ratio the report says the identification data show little of the effect
UNDER_EXCITED_RATIO = 2.0


@dataclass(frozen=True)
class Excitation:
    """Per operator channel of an effect: RMS about the mean on the tests over the same on
    the identification data (None: the operator moves on the tests but never moved there)."""

    effect: str
    ratios: dict[str, float | None]

    @property
    def worst(self) -> tuple[str, float | None]:
        """The channel the tests drive hardest beyond the identification data."""
        return max(self.ratios.items(), key=lambda item: np.inf if item[1] is None else item[1])

    def reading(self) -> str:
        """One line for the report."""
        channel, ratio = self.worst
        if ratio is not None and ratio <= UNDER_EXCITED_RATIO:
            return (
                f"the tests drive no operator of '{self.effect}' more than {ratio:.2g}x as "
                f"hard (RMS) as the identification data ({channel})"
            )
        if ratio is None:
            return (
                f"'{channel}' never moves in the identification data but does on the tests: "
                f"the refit cannot learn '{self.effect}' there; identification data that "
                "drive it as the tests do would"
            )
        return (
            f"'{channel}' moves {ratio:.3g}x less (RMS) in the identification data than on "
            f"the tests: the refit learns '{self.effect}' from data that show little of it; "
            "identification data that drive it as the tests do would show more"
        )

    def to_dict(self) -> dict[str, object]:
        channel, ratio = self.worst
        return {
            "effect": self.effect,
            "worst_channel": channel,
            "worst_ratio": ratio,
            "ratios": self.ratios,
            "reading": self.reading(),
        }


def operator_excitation(
    effect: str,
    identification: Sequence[Recording],
    tests: Sequence[Recording],
    ctx: FeatureContext,
) -> Excitation:
    """Compare how much ``effect``'s operators move on ``tests`` and on ``identification``."""
    operator = get_effect(effect)

    def spread(recordings: Sequence[Recording]) -> np.ndarray:
        values = np.concatenate([operator.features(r.u, ctx) for r in recordings])
        return np.sqrt(np.mean((values - values.mean(axis=0)) ** 2, axis=0))

    train, test = spread(identification), spread(tests)
    ratios: dict[str, float | None] = {}
    for j, (on_train, on_test) in enumerate(zip(train, test, strict=True)):
        if on_train > 0:
            ratios[f"{effect}_{j}"] = float(on_test / on_train)
        else:  # never moved while identifying: None if the tests move it, else no contrast
            ratios[f"{effect}_{j}"] = None if on_test > 0 else 1.0
    return Excitation(effect, ratios)
