"""Declared effects grown the way the loop grows a model.

A physical model declared with effects (``model=linear model.effects=[hysteresis,creep]``,
``model=greybox``) is not trained with every block at once. Like the loop, it starts from the
linear dynamics alone (least squares, then the simulation error), then adds each declared
effect's block, in the order the physics puts them, from where it changes nothing on the
warm model, and refits (`ModelContract.growth_stages`). Each refit runs at the loop's
learning rates (`REFIT_LR_FACTORS` of ``training.lr``, or ``training.refit_lr``); the one with the
lowest validation free-run loss goes on, and a refit that does not beat the model it grew
from keeps that model (its block stays, at no effect). ``model.grow=false`` trains every
declared block at once, from the start.

Every stage trains in ``<run>/grow/<k>_<label>/`` (a refit: one folder per learning rate);
the last stage's chosen model is the run's model, saved and scored in the run folder as any
other.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from hysteresis_lab.effects.base import MODEL_OUTPUT_BLOCKS
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import DivergedError
from hysteresis_lab.fitting import TrainResult
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec

log = logging.getLogger(__name__)

#: a refit runs at each of these multiples of ``training.lr`` (the loop's default too)
REFIT_LR_FACTORS = (0.1, 1.0)
#: the model setting that switches growing off (``model.grow=false``)
SETTING = "grow"
#: the folder under the run folder where the stages before the last are written
STAGES_FOLDER = "grow"


@dataclasses.dataclass(frozen=True)
class Stage:
    """One growth stage: its ``label`` (``linear`` or the effect it adds), the model
    ``settings`` it trains with and the effect it adds (None: the first stage)."""

    label: str
    settings: Mapping[str, Any]
    added: str | None


def growth_stages(spec: ModelSpec) -> list[Stage]:
    """The stages a declared model grows through (the class's ``growth_stages``); a single
    stage (trained as declared) when ``model.grow`` is false."""
    if not spec.settings.get(SETTING, True):
        return [Stage("declared", dict(spec.settings), None)]
    return [Stage(label, settings, added) for label, settings, added
            in spec.cls.growth_stages(dict(spec.settings))]


def refit_mode(added: str | None, model_cls: type, refit: str = "new_inputs") -> str:
    """How a warm-started model that adds ``added`` refits: ``refit`` (``"new_inputs"``:
    only the new block's parameters), except for an effect that enters through the input
    block (it changes what the fitted dynamics see) or acts on the output (the gain a fit
    lowered to meet a clipped output comes back under the clip) or one the model class names
    in ``whole_refit_effects`` (a dead zone ahead of linear dynamics, a restoring force in
    their feedback): the whole model refits (``"full"``)."""
    if refit != "new_inputs" or added is None:
        return refit
    block = get_effect(added).block
    if block in ("input", *MODEL_OUTPUT_BLOCKS):
        log.info("'%s' acts on the model's %s: the whole model refits", added, block)
        return "full"
    if added in model_cls.whole_refit_effects:
        log.info("'%s' changes what %s's dynamics were fitted to: the whole model refits",
                 added, model_cls.__name__)
        return "full"
    return refit


def refit_rates(training: TrainingSettings,
                factors: Sequence[float] = REFIT_LR_FACTORS) -> list[float]:
    """The learning rates a refit runs at: ``training.refit_lr`` if set, else ``factors``
    of ``training.lr``."""
    if training.refit_lr is not None:
        return [float(training.refit_lr)]
    return [factor * float(training.lr) for factor in factors]


def kept_loss(result: TrainResult) -> float:
    """The validation loss of the model a refit kept (its own or its start's)."""
    losses = result.refit_validation
    if not losses:
        return float(result.val_mse)
    return float(losses["refit"] if result.improved else losses["start"])


#: trains one stage: (model settings, training settings, its folder, the model it grows
#: from or None, refit mode) -> the trained result
TrainStage = Callable[[Mapping[str, Any], TrainingSettings, Path, Any | None, str], TrainResult]


def grow(spec: ModelSpec, training: TrainingSettings, output_dir: Path,
         train_stage: TrainStage) -> TrainResult:
    """Train ``spec`` through its `growth_stages` with ``train_stage`` (each stage with the
    ``training`` settings, a refit at its rate); the last stage's
    result (with the best refit rate) is returned, its start's rejected weights dropped (a
    declared block kept at no effect is the declared model, not a rejected refit)."""
    stages = growth_stages(spec)
    previous: TrainResult | None = None
    for number, stage in enumerate(stages):
        last = number == len(stages) - 1
        folder = output_dir / STAGES_FOLDER / f"{number}_{stage.label}"
        if previous is None:
            log.info("growing %s: stage %d of %d, %s", spec.name, number + 1, len(stages),
                     stage.label)
            previous = train_stage(stage.settings, training, folder, None, "full")
            continue
        rates = refit_rates(training)
        mode = refit_mode(stage.added, spec.cls)
        candidates = []
        for rate in rates:
            log.info("growing %s: stage %d of %d, + %s (refit %s at learning rate %.3g)",
                     spec.name, number + 1, len(stages), stage.label, mode, rate)
            try:
                candidates.append(train_stage(stage.settings, training.with_changes(refit_lr=rate),
                                              folder / f"refit_lr_{rate:.3g}", previous.model,
                                              mode))
            except DivergedError as exc:
                log.warning("growing %s: the refit with %s at learning rate %.3g diverged: "
                            "not a candidate (%s)", spec.name, stage.label, rate, exc)
        if not candidates:
            raise DivergedError(
                f"every refit that grew {stage.label} on the fitted {spec.name} model diverged "
                f"(learning rates {refit_rates(training)}). Fix: a smaller "
                "training.refit_lr, or model.grow=false (every declared block trained at once)."
            )
        chosen = min(candidates, key=kept_loss)
        log.info("growing %s: + %s %s (validation loss %.4e)", spec.name, stage.label,
                 "refitted" if chosen.improved else "kept at no effect: no refit beat the "
                 "model it grew from", kept_loss(chosen))
        previous = chosen
        if last:
            previous.rejected_state = None
    assert previous is not None
    return previous
