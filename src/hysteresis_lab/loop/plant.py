"""The effects whose physics fits a declared kind of plant (``data.plant``).

Where the diagnosis cannot tell effects apart (their scores within ``loop.confounded_margin``
of each other, `hysteresis_lab.loop.driver.confounded`), the loop names first the one that
fits the plant: a piezo positioner's residual that a tank's rim explains as well as
hysteresis is named hysteresis. Undeclared (``data.plant=null``): no preference, the scores
alone order them. The folds still refit every confounded effect and keep the best.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from hysteresis_lab.loop.diagnosis.ranking import EffectScore

#: per kind of plant (`hysteresis_lab.data.spec.PLANT_KINDS`), the effects its physics has
PLANT_EFFECTS: dict[str, tuple[str, ...]] = {
    # a piezo stack or mirror: a hysteretic, creeping actuator (its loop may be asymmetric),
    # its modes, its amplifier (clipping, a dead band) and a lever's or flexure's play
    "positioner": ("hysteresis", "creep", "rate", "asymmetry", "resonance", "saturation",
                   "dead_zone", "backlash", "drift"),
    # a storage with an outflow law and a rim, fed by a pump
    "tank": ("nonlinear_feedback", "overflow", "saturation"),
    # a cart or a drive moved by a force: friction, play in its transmission, its drive
    "motion": ("friction", "backlash", "dead_zone", "saturation", "resonance"),
    # a mass on a nonlinear (hysteretic or hardening) spring
    "oscillator": ("hysteresis", "nonlinear_feedback", "resonance"),
}


def fits_plant(effect: str, plant: str | None) -> bool:
    """Whether ``effect``'s physics belongs to a plant of kind ``plant`` (None: no kind
    declared, so none is preferred)."""
    return plant is not None and effect in PLANT_EFFECTS.get(plant, ())


def prefer_plant(effects: Sequence[str], plant: str | None) -> list[str]:
    """``effects`` (tied on the evidence, best first) with those that fit ``plant`` first,
    each part in its given order; unchanged where no plant is declared."""
    return sorted(effects, key=lambda e: not fits_plant(e, plant))


def with_plant_prior(diagnosis: Sequence[EffectScore], plant: str | None, alpha: float,
                     min_score: float) -> list[EffectScore]:
    """``diagnosis`` with each effect that fits the declared ``plant`` significant where it
    reaches ``min_score`` at the significance level ``alpha`` (``loop.plant_alpha``, the
    prior the declared kind gives its own physics; at 1 reaching ``min_score`` is enough, and
    the folds alone judge its refit); best first again. Unchanged where no plant is
    declared."""
    if plant is None:
        return list(diagnosis)
    level = ("the folds judge it" if alpha >= 1.0
             else f"significant at loop.plant_alpha={alpha:g}")
    note = f" ({level}: its physics fits data.plant={plant})"
    marked = [
        dataclasses.replace(d, significant=True, evidence=d.evidence + note)
        if (not d.significant and d.tested and fits_plant(d.effect, plant)
            and d.score >= min_score and d.p_value <= alpha) else d
        for d in diagnosis
    ]
    return sorted(marked, key=lambda d: (-d.significant, -d.score))
