"""Declared effects grown the way the loop grows a model.

A physical model declared with effects (``model=linear model.effects=[hysteresis,creep]``,
``model=greybox``) is not trained with every block at once. Like the loop, it starts from the
linear dynamics alone (least squares, then the simulation error), then adds each declared
effect's block, in the order the physics puts them, from where it changes nothing on the
warm model, and refits (`ModelContract.growth_stages`). Each refit runs at the loop's
learning rates (`REFIT_LR_FACTORS` of ``training.lr``, or ``training.refit_lr``); the one with the
lowest validation free-run loss goes on, and a refit that does not beat the model it grew
from keeps that model (its block stays, at no effect).

``model.grow`` says which paths run: ``best`` (the default) grows the model and also trains
every declared block at once from the start, and keeps the one with the lower validation
free-run loss (which path started a model decides its accuracy on some plants, and neither
path is the better one on every plant); ``true`` only grows; ``false`` only trains at once.

A setting the model's class reads off the data (``settings_from_data``: the grey-box's
``model.hysteresis=auto``) is settled first; where the data leave several candidates, each
is fitted in ``<run>/grow/candidates/<setting>/`` and the lowest validation loss kept.

Trained with Adam, the kept model (a warm-started refit's too: the loop's) is then polished
(``model.polish``, on by default): refined by full-batch L-BFGS in ``<run>/grow/polish/``
with the settings the class gives it (``polish_settings``: the grey-box frees its Bouc–Wen
exponent there) and kept where it lowers the validation free-run loss. Adam brings the few
parameters of a physical model near their optimum; the second-order steps land on it (the
grey-box on zoo plant 0, a Bouc–Wen cell of exponent 1.56: 156 σ before, 7.4 σ after,
`docs/results/zoo.md`). While growing, each stage before the last is polished too, with its
own settings, in ``<run>/grow/<k>_<label>/polish/``: every block is added to a polished
model, as the loop adds it.

Every stage trains in ``<run>/grow/<k>_<label>/`` (a refit: one folder per learning rate),
the fit at once in ``<run>/grow/at_once/``; the chosen model is the run's model, saved and
scored in the run folder as any other.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from lightning.pytorch.loggers import TensorBoardLogger

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.effects.base import MODEL_OUTPUT_BLOCKS
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import DivergedError
from hysteresis_lab.fitting import TrainResult, beats_by, fit_run
from hysteresis_lab.models.augment import ModelData
from hysteresis_lab.models.io import model_window
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.run_config import RunConfig
from hysteresis_lab.run_folder import RunFolder

log = logging.getLogger(__name__)

#: a refit runs at each of these multiples of ``training.lr`` (the loop's default too)
REFIT_LR_FACTORS = (0.1, 1.0)
#: the loop's refit rates, one after the other, where the refit ends with the L-BFGS polish
#: (`polishes_fits`): the second only where the refit at the first does not pass the folds
#: (zoo plants 0-6: the lower rate won 3 of 17 refit rounds, and decided one, plant 4's
#: hysteresis, kept at 0.1x and rejected at 1x)
POLISHED_REFIT_LR_FACTORS = (1.0, 0.1)
#: the model setting that says which paths run (``model.grow``, see the module docstring)
SETTING = "grow"
#: its values: grow and train at once, the lower validation loss kept; grow; train at once
GROW_MODES = ("best", True, False)
#: the folder under the run folder where the stages before the last are written
STAGES_FOLDER = "grow"
#: the folder (under `STAGES_FOLDER`) of the fit at once that ``model.grow=best`` compares
AT_ONCE_FOLDER = "at_once"
#: the folder (under `STAGES_FOLDER`) of each candidate setting the data left open
CANDIDATES_FOLDER = "candidates"
#: the model setting that ends a fit with the L-BFGS polish (``model.polish``), its folder
POLISH_SETTING = "polish"
POLISH_FOLDER = "polish"
#: a growth stage's polish is kept only where it lowers the validation loss by this share:
#: one that barely moves it leaves the next block a sharper start to grow from (zoo plant 6,
#: the grey-box: a polish equal to four digits, then no asymmetry refit beat it: 64.5 σ
#: without the stage's polish, 93.6 σ with it)
STAGE_POLISH_GAIN = 0.01


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
    if spec.settings.get(SETTING, True) is False:
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
    if training.optimizer == "lbfgs":
        return [float(training.lr)]  # the line search sets the step: one refit
    if training.refit_lr is not None:
        return [float(training.refit_lr)]
    return [factor * float(training.lr) for factor in factors]


def kept_loss(result: TrainResult) -> float:
    """The validation loss of the model a refit kept (its own or its start's)."""
    losses = result.refit_validation
    if not losses:
        return float(result.val_mse)
    return float(losses["refit"] if result.improved else losses["start"])


def train_model(
    config: RunConfig,
    data: ModelData,
    warm_start: Any | None = None,
    logger: TensorBoardLogger | None = None,
    callbacks: list[Any] | None = None,
    resume: bool = False,
    first_stages: dict[str, TrainResult] | None = None,
) -> tuple[TrainResult, WindowSpec]:
    """The run's fitted model and its window: a declared physical model grows through its
    stages (`grow`, its first stage taken from ``first_stages`` where fitted before), each
    from the start, and does not resume; any other fits once
    (`hysteresis_lab.fitting.fit_run`, going on from an interrupted fit: ``resume``)."""
    choices: dict[str, Any] = {}
    if warm_start is None:
        candidates, choices = settings_from_data(config.model, data)
        if len(candidates) > 1:
            return _best_candidate(config, data, candidates, choices, callbacks)
        config = dataclasses.replace(config, model=config.model.with_settings(candidates[0]))
    if warm_start is not None or len(growth_stages(config.model)) == 1:
        trained, window = fit_run(config, data, warm_start, logger, callbacks, resume)
    else:
        trained = grow(config, data, callbacks, first_stages)
        if config.model.settings.get(SETTING, "best") == "best":
            trained = _better_of_grown_and_at_once(config, data, trained, callbacks)
        window = model_window(trained.model)
    if polishes(config):
        trained = _polished(config, data, trained, callbacks)
        window = model_window(trained.model)
    if choices:
        trained.model.data_choices = choices
    return trained, window


def polishes(config: RunConfig) -> bool:
    """Whether ``config``'s fit ends with the L-BFGS polish (`polishes_fits`)."""
    return polishes_fits(config.model.settings, config.training)


def polishes_fits(model_settings: Mapping[str, Any], training: TrainingSettings) -> bool:
    """Whether a model with ``model_settings`` trained with ``training`` ends each fit with
    the L-BFGS polish: a physical model (``model.polish``, on by default) trained with Adam."""
    return bool(model_settings.get(POLISH_SETTING, False)) and training.optimizer == "adam"


def _polished(config: RunConfig, data: ModelData, fitted: TrainResult,
              callbacks: list[Any] | None, stage: Stage | None = None,
              folder: Path | None = None) -> TrainResult:
    """``fitted`` refined by full-batch L-BFGS in ``<run>/grow/polish`` (the model class's
    `polish_settings`: the grey-box frees its Bouc–Wen exponent there), kept where it lowers
    the validation free-run loss. Adam brings a physical model near its optimum; a
    second-order step on its few parameters lands on it. A polish that diverges is none.
    A growth ``stage`` before the last is polished with its own settings in ``folder``."""
    name = config.model.name
    if stage is None:
        folder = config.output_dir / STAGES_FOLDER / POLISH_FOLDER
        settings = config.model.cls.polish_settings(config.model.settings)
        log.info("%s: the fitted model polished by L-BFGS", name)
    else:
        assert folder is not None
        settings = dict(stage.settings)
        name = f"growing {name}: {stage.label}"
        log.info("%s polished by L-BFGS before the next block is added", name)
    # the polish keeps its best weights, even after a fit that kept its last (a loop's)
    config = dataclasses.replace(config, settings=dataclasses.replace(config.settings,
                                                                      keep_last=False))
    try:
        polished = _fit_stage(config, data, settings, config.training.with_changes(
            optimizer="lbfgs"), folder, fitted.model, "full", callbacks)
    except DivergedError as exc:
        log.warning("%s: the polish diverged; the fitted model stays (%s)", name, exc)
        return fitted
    kept = kept_after_polish(fitted, polished, config.settings.min_refit_gain)
    if stage is not None and not beats_by(kept_loss(kept), kept_loss(fitted), STAGE_POLISH_GAIN):
        kept = fitted  # a stage's polish that barely moves the loss only sharpens the start
    log.info("%s: validation free-run loss %.4e before the polish, %.4e after: the %s model "
             "is kept", name, kept_loss(fitted), kept_loss(polished),
             "polished" if kept is not fitted else "fitted")
    return kept


def kept_after_polish(fitted: TrainResult, polished: TrainResult, min_gain: float) -> TrainResult:
    """The fit to keep: ``polished`` where it lowers ``fitted``'s validation loss, with
    ``fitted``'s training epochs (the Adam stages': a loop's final refit trains for the
    folds' epochs) and both fits' seconds. A warm-started fit (a refit, which keeps its start
    unless it beats it by the share ``min_gain``) takes the polish only where the polished
    model beats that start by as much, and reports its loss against that start."""
    before, after = kept_loss(fitted), kept_loss(polished)
    if not (polished.improved and after < before):
        return fitted
    start = None if fitted.refit_validation is None else fitted.refit_validation["start"]
    if start is not None and not beats_by(after, start, min_gain):
        return fitted  # a refit's start stays unless beaten, polished or not
    seconds = fitted.train_seconds + polished.train_seconds
    refit = None if start is None else {"start": float(start), "refit": after}
    return dataclasses.replace(polished, train_seconds=seconds, epochs=dict(fitted.epochs),
                               refit_validation=refit, improved=True, rejected_state=None)


def settings_from_data(
    spec: ModelSpec, data: ModelData
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The model settings its class reads off the measured data (a class method
    ``settings_from_data``, e.g. the grey-box's ``hysteresis=auto``): the candidates (one:
    the data chose; several: each is fitted, the lowest validation loss kept) and what the
    data showed; without that method, the settings as they are."""
    choose = getattr(spec.cls, "settings_from_data", None)
    if choose is None:
        return [dict(spec.settings)], {}
    return choose(spec.settings, data.measured)


def _best_candidate(
    config: RunConfig, data: ModelData, candidates: Sequence[Mapping[str, Any]],
    choices: dict[str, Any], callbacks: list[Any] | None,
) -> tuple[TrainResult, WindowSpec]:
    """Each candidate's settings fitted (`train_model`) in ``grow/candidates/<setting>``, the
    one with the lowest validation free-run loss kept (its training time: all of theirs);
    ``choices`` records the losses. A first growth stage they share is fitted once."""
    fits = []
    first_stages: dict[str, TrainResult] = {}
    for settings in candidates:
        label = ",".join(f"{k}={v}" for k, v in settings.items()
                         if config.model.settings.get(k) != v)
        folder = config.output_dir / STAGES_FOLDER / CANDIDATES_FOLDER / label
        log.info("%s: fitting the candidate %s", config.model.name, label)
        candidate = dataclasses.replace(config, model=config.model.with_settings(settings),
                                        output_dir=folder)
        fits.append((label, *train_model(candidate, data, callbacks=callbacks,
                                         first_stages=first_stages)))
    losses = {label: kept_loss(trained) for label, trained, _ in fits}
    label, trained, window = min(fits, key=lambda fit: losses[fit[0]])
    log.info("%s: validation free-run loss %s: %s kept", config.model.name,
             ", ".join(f"{k} {v:.4e}" for k, v in losses.items()), label)
    trained.model.data_choices = {**choices, "candidates_validation_loss": losses,
                                  "kept": label}
    seconds = sum(fit[1].train_seconds for fit in fits)  # the run took every candidate's
    return dataclasses.replace(trained, train_seconds=seconds), window


def _better_of_grown_and_at_once(
    config: RunConfig, data: ModelData, grown: TrainResult, callbacks: list[Any] | None
) -> TrainResult:
    """``grown``, or the declared model trained at once from the start where its validation
    free-run loss is lower (``model.grow=best``); a fit at once that diverges is none."""
    name = config.model.name
    log.info("growing %s: the declared model trained at once too, to compare", name)
    folder = config.output_dir / STAGES_FOLDER / AT_ONCE_FOLDER
    try:
        at_once = _fit_stage(config, data, config.model.settings, config.training, folder,
                             None, "full", callbacks)
    except DivergedError as exc:
        log.warning("growing %s: the fit at once diverged; the grown model stays (%s)", name,
                    exc)
        return grown
    better = at_once if float(at_once.val_mse) < kept_loss(grown) else grown
    log.info("growing %s: validation free-run loss grown %.4e, at once %.4e: the %s model is "
             "kept", name, kept_loss(grown), float(at_once.val_mse),
             "grown" if better is grown else "at-once")
    return better


def grow(config: RunConfig, data: ModelData, callbacks: list[Any] | None = None,
         first_stages: dict[str, TrainResult] | None = None) -> TrainResult:
    """Train ``config``'s model through its `growth_stages` (`_grow_stage`), every stage in
    its folder under the run folder; the last stage's result (with the best refit rate) is
    returned, its start's rejected weights dropped (a declared block kept at no effect is
    the declared model, not a rejected refit). ``first_stages`` (settings -> fit) holds first
    stages fitted before: one with the same settings is reused (a copy), a new one is added."""
    stages = growth_stages(config.model)
    previous: TrainResult | None = None
    for number, stage in enumerate(stages):
        position = f"stage {number + 1} of {len(stages)}"
        key = _settings_key(stage.settings) if number == 0 and first_stages is not None else None
        if key is not None and key in first_stages:
            log.info("growing %s: %s, %s: the same fit as an earlier candidate's, reused",
                     config.model.name, position, stage.label)
            previous = _copied(first_stages[key])
            continue
        folder = config.output_dir / STAGES_FOLDER / f"{number}_{stage.label}"
        previous = _grow_stage(config, data, stage, folder, previous, callbacks, position)
        if number < len(stages) - 1 and polishes(config):  # as the loop's rounds: each
            # block is added to a polished model (the last stage: `train_model` polishes it)
            previous = _polished(config, data, previous, callbacks, stage,
                                 folder / POLISH_FOLDER)
        if key is not None:
            first_stages[key] = _copied(previous)
    assert previous is not None
    previous.rejected_state = None
    return previous


def _settings_key(settings: Mapping[str, Any]) -> str:
    """A stage's model settings as a key: equal settings, the same fit."""
    return repr(sorted((str(k), repr(v)) for k, v in settings.items()))


def _copied(result: TrainResult) -> TrainResult:
    """``result`` with its own copy of the model (a later stage must not change the one
    another candidate grows from)."""
    return dataclasses.replace(result, model=copy.deepcopy(result.model))


def _grow_stage(
    config: RunConfig, data: ModelData, stage: Stage, folder: Path,
    previous: TrainResult | None, callbacks: list[Any] | None, position: str,
) -> TrainResult:
    """One growth stage (at ``position``): the first trained from the data; a later one
    refitted from the model it grows from (``previous``) at each of its `_stage_fits`, the
    refit that keeps the lowest validation loss going on (one that diverged is no
    candidate)."""
    name = config.model.name
    candidates = []
    for training, stage_folder, mode, label in _stage_fits(config, stage, folder, previous):
        log.info("growing %s: %s, %s", name, position, label)
        try:
            candidates.append(_fit_stage(config, data, stage.settings, training, stage_folder,
                                         previous and previous.model, mode, callbacks))
        except DivergedError as exc:
            if previous is None:
                raise
            log.warning("growing %s: the refit with %s at learning rate %.3g diverged: "
                        "not a candidate (%s)", name, stage.label, training.refit_lr, exc)
    if previous is None:
        return candidates[0]
    if not candidates:
        raise DivergedError(
            f"every refit that grew {stage.label} on the fitted {name} model diverged "
            f"(learning rates {refit_rates(config.training)}). Fix: a smaller "
            "training.refit_lr, or model.grow=false (every declared block trained at once)."
        )
    chosen = min(candidates, key=kept_loss)
    log.info("growing %s: + %s %s (validation loss %.4e)", name, stage.label,
             "refitted" if chosen.improved else "kept at no effect: no refit beat the "
             "model it grew from", kept_loss(chosen))
    return chosen


def _stage_fits(
    config: RunConfig, stage: Stage, folder: Path, previous: TrainResult | None
) -> list[tuple[TrainingSettings, Path, str, str]]:
    """The fits of one growth stage: its training settings, folder, refit mode (see
    `refit_mode`) and label. The first stage fits once, in ``folder``; a later one refits
    at each of the `refit_rates`, in ``folder/refit_lr_<rate>``."""
    training = config.training
    if previous is None:
        return [(training, folder, "full", stage.label)]
    rates = refit_rates(training)
    mode = refit_mode(stage.added, config.model.cls)
    return [(training.with_changes(refit_lr=rate), folder / f"refit_lr_{rate:.3g}", mode,
             f"+ {stage.label} (refit {mode} at learning rate {rate:.3g})") for rate in rates]


def _fit_stage(
    config: RunConfig, data: ModelData, settings: Mapping[str, Any],
    training: TrainingSettings, folder: Path, previous: Any | None, refit: str,
    callbacks: list[Any] | None,
) -> TrainResult:
    """One growth stage of ``config``'s model fitted: its model settings and ``training``
    settings, in its ``folder``, warm-started from the model it grows from (``previous``;
    None: from the data) with the ``refit`` mode; the start is kept unless the refit beats
    it. Its curves go under the run's TensorBoard folder, one run each."""
    stage = config.for_stage(settings, training, folder, refit)
    folder.mkdir(parents=True, exist_ok=True)
    logger = None if not config.settings.use_tensorboard else TensorBoardLogger(
        save_dir=str(config.output_dir / RunFolder.TENSORBOARD),
        name=str(folder.relative_to(config.output_dir)), version="", default_hp_metric=False)
    stage_data = data.with_effects(stage.model.effects)
    return fit_run(stage, stage_data, previous, logger, callbacks)[0]
