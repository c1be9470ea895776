"""Build a registered model for a DataModule and fit it (Lightning nets, scikit-learn SVM).

A network trains in stages decided by its `TrainingSettings` (the ``training`` config): the
one-step error, the free-run error alone, or a one-step stage fine-tuned on the free-run
error; a warm-started refit keeps its start unless it beats it on validation."""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import time
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import (
    Checkpoint,
    EarlyStopping,
    LearningRateMonitor,
    ModelCheckpoint,
)
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities.exceptions import MisconfigurationException, SIGTERMException

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.factory import build_datamodule
from hysteresis_lab.data.segments import simulation_data
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError, DivergedError
from hysteresis_lab.interrupts import RunInterrupted, raise_if_stopped, signals_deferred
from hysteresis_lab.lightning_trainer import TrainerSettings, build_trainer
from hysteresis_lab.models.augment import SETTING as BASELINE_SETTING
from hysteresis_lab.models.augment import ModelData
from hysteresis_lab.models.interface import SystemModel
from hysteresis_lab.models.settings import TRAINING_SETTINGS, Stage, TrainingSettings
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.run_config import RunConfig
from hysteresis_lab.run_folder import RunFolder

log = logging.getLogger(__name__)


@dataclass
class TrainResult:
    """A fitted model, its validation MSE (scaled units: the sweep objective) and cost."""

    model: SystemModel
    val_mse: float
    train_seconds: float
    checkpoint: Path | None = None
    #: False when a warm-started refit did not beat its start and the start was kept
    improved: bool = True
    #: a warm-started refit's validation loss: {"start": x, "refit": x} (selection loss)
    refit_validation: dict[str, float] | None = None
    #: the refit's own weights when it lost to its start (kept for reporting what it did)
    rejected_state: dict[str, torch.Tensor] | None = None
    #: per training stage (`Stage`: "one_step", "simulation", "fine_tune"), the epochs the
    #: kept weights trained: the best checkpoint's epoch + 1, 0 where the stage kept its
    #: start, the stage's whole length with ``keep_last``
    epochs: dict[str, int] = field(default_factory=dict)


def fit_run(
    config: RunConfig,
    data: ModelData,
    warm_start: Any | None = None,
    logger: TensorBoardLogger | None = None,
    callbacks: list[Any] | None = None,
    resume: bool = False,
) -> tuple[TrainResult, WindowSpec]:
    """Fit ``config``'s model on ``data``'s inputs in its output folder, and its window: the
    DataModule and the untrained model (started from ``warm_start`` when given; with the
    baseline whose free run it reads, saved with it), then `fit`; the start is kept unless
    the fit beats it, and ``resume`` goes on from an interrupted fit."""
    datamodule = build_datamodule(
        config.data, config.model.layout, seed=config.settings.seed, splits=data.inputs
    )
    model = build_model(config.model, datamodule, config.training, **data.derived_settings())
    if data.baseline is not None:
        model.baseline = data.baseline
    if warm_start is not None:
        model.warm_start_from(warm_start)
        if config.settings.refit == "new_inputs":
            model.train_new_inputs_only()
    trained = fit(
        model, datamodule, config.trainer, config.output_dir, logger=logger,
        callbacks=callbacks, keep_start_unless_beaten=warm_start is not None,
        min_gain=config.settings.min_refit_gain, resume=resume,
        keep_last=config.settings.keep_last,
    )
    return trained, datamodule.window


def build_model(
    model: ModelSpec | Mapping[str, Any], datamodule: WindowDataModule,
    training: TrainingSettings | None = None, **extra: Any,
) -> SystemModel:
    """Instantiate the registered model of a `ModelSpec` (a ``model`` config, in scripts and
    tests) for the DataModule's data; a network with the ``training`` settings (default: its
    own, `ModelSpec.training_settings`).

    ``extra`` passes values the pipeline derives (e.g. the effects' ``feature_context``);
    those the model does not take (``n_base_inputs`` for the SVM) are left out.
    """
    spec = model if isinstance(model, ModelSpec) else ModelSpec.from_config(model)
    name, cls, params = spec.name, spec.cls, dict(spec.settings)
    params.pop(BASELINE_SETTING, None)  # the pipeline gives the model its baseline's channels
    keys = cls.settings_keys()
    extra = {k: v for k, v in extra.items() if k in keys}
    accepted = keys - DERIVED_PARAMETERS - set(TRAINING_SETTINGS)
    unknown = sorted(set(params) - accepted)
    if unknown:
        raise ConfigError(
            f"model '{name}' has no parameter(s) {unknown}. Valid: {sorted(accepted)}. "
            f"Fix: remove the override or correct its spelling (e.g. "
            f"model.{sorted(accepted)[0]}=...)."
        )
    if cls.is_network:
        params.update((training or spec.training_settings()).to_dict())
    window = datamodule.window
    return cls(
        nu=datamodule.nu,
        ny=datamodule.ny,
        na=window.na,
        nb=window.nb,
        nk=window.nk,
        scaler=datamodule.scaler.to_dict(),
        **params,
        **extra,
    )


def fit(
    model: Any,
    datamodule: WindowDataModule,
    settings: TrainerSettings,
    output_dir: Path,
    logger: TensorBoardLogger | None = None,
    callbacks: list[Any] | None = None,
    one_step: bool = True,
    keep_start_unless_beaten: bool = False,
    min_gain: float = 0.0,
    resume: bool = False,
    keep_last: bool = False,
) -> TrainResult:
    """Fit ``model``; nets keep the checkpoint with the best validation loss.

    ``one_step=False`` skips the one-step stage when the model fine-tunes on the free-run
    error anyway (``objective="simulation"`` with ``simulation_epochs``).
    ``keep_start_unless_beaten`` (a warm-started refit): the weights ``model`` starts with
    are kept unless training beats them on the validation free-run loss (one-step MSE with
    the one-step objective) by more than the share ``min_gain``.
    ``resume``: each stage goes on from its ``last.ckpt`` in ``output_dir`` (an interrupted
    fit of the same model and settings); without it, or without that file, the stage starts
    afresh and the checkpoints an earlier fit left in its folder are deleted first.
    ``keep_last``: every stage trains its whole length and keeps its last weights (no
    checkpoint chosen on validation, no early stop, the start never put back): a length
    chosen elsewhere (the loop's folds) on data that hold nothing out.
    """
    if model.is_network:
        _check_max_epochs(settings)
    start = (
        {k: v.detach().clone() for k, v in model.state_dict().items()}
        if keep_start_unless_beaten and model.is_network and not keep_last
        else None
    )
    result = _fit(model, datamodule, settings, output_dir, logger, callbacks, one_step, resume,
                  keep_last)
    if start is not None:
        _keep_start_unless_beaten(result, start, datamodule, settings, min_gain)
    return result


def beats_by(loss: float, other: float, min_gain: float) -> bool:
    """Whether ``loss`` is below ``other`` by more than the share ``min_gain`` of it (the
    rule by which a refit, polished or not, replaces the model it started from)."""
    return loss < (1.0 - min_gain) * other


def _keep_start_unless_beaten(
    result: TrainResult,
    start: dict[str, torch.Tensor],
    datamodule: WindowDataModule,
    settings: TrainerSettings,
    min_gain: float,
) -> None:
    """Put the starting weights back when the trained ones do not beat them on validation by
    more than the share ``min_gain``; records the verdict and both losses in ``result``."""
    model = result.model
    trained = {k: v.detach().clone() for k, v in model.state_dict().items()}
    losses = {}
    for name, weights in (("refit", trained), ("start", start)):  # the start's stay loaded
        model.load_state_dict(weights)
        losses[name] = _selection_loss(model, datamodule, settings)
    trained_loss, start_loss = losses["refit"], losses["start"]
    result.refit_validation = {"start": start_loss, "refit": trained_loss}
    result.improved = beats_by(trained_loss, start_loss, min_gain)
    if result.improved:
        model.load_state_dict(trained)
        log.info("refit: validation loss %.4e -> %.4e (scaled)", start_loss, trained_loss)
        return
    result.rejected_state = trained
    result.epochs = dict.fromkeys(result.epochs, 0)  # the start's weights trained none
    log.info(
        "refit did not beat the model it started from on validation (%.4e vs %.4e, scaled): "
        "kept that model",
        trained_loss,
        start_loss,
    )


def _selection_loss(
    model: L.LightningModule, datamodule: WindowDataModule, settings: TrainerSettings
) -> float:
    """Validation free-run MSE over ``horizon`` segments (objective "simulation"), or the
    one-step MSE."""
    steps = model.simulation_horizon
    if steps == 0:
        return datamodule.validation_mse(model.predict_scaled)
    model.simulation_mode = True
    try:
        segments = simulation_data(datamodule, model, steps)
        trainer = build_trainer(settings, logger=False, enable_checkpointing=False)
        return float(trainer.validate(model, datamodule=segments, verbose=False)[0]["val_loss"])
    finally:
        model.simulation_mode = False


def stage_lr(model: L.LightningModule, stage: Stage) -> float:
    """The learning rate of a training ``stage`` of ``model``: its `TrainingSettings` decide
    (`TrainingSettings.stage_lr`); a warm start that added entries (`new_entries`, set by
    ``warm_start_from``) counts as a refit."""
    refit = bool(model.new_entries)
    return model.training_settings.stage_lr(stage, refit=refit)


def _fit(
    model: Any,
    datamodule: WindowDataModule,
    settings: TrainerSettings,
    output_dir: Path,
    logger: TensorBoardLogger | None,
    callbacks: list[Any] | None,
    one_step: bool,
    resume: bool = False,
    keep_last: bool = False,
) -> TrainResult:
    """`fit` without the comparison with the starting weights."""
    datamodule.setup()
    start = time.perf_counter()
    if not model.is_network:
        x, target = datamodule.scale_windows(datamodule.train_windows)
        model.fit(x, target)
        val_mse = datamodule.validation_mse(model.predict_scaled)
        return TrainResult(model, val_mse, time.perf_counter() - start)
    return _fit_network(model, datamodule, settings, output_dir, logger, callbacks, one_step,
                        resume, start, keep_last)


def _fit_network(
    model: L.LightningModule,
    datamodule: WindowDataModule,
    settings: TrainerSettings,
    output_dir: Path,
    logger: TensorBoardLogger | None,
    callbacks: list[Any] | None,
    one_step: bool,
    resume: bool,
    start: float,
    keep_last: bool = False,
) -> TrainResult:
    """A network's stages, from its starting values read off the data: the free-run error
    alone, or the one-step error fine-tuned on the free run (`_fit_one_step_and_fine_tune`)."""
    _initialise_from_data(model, datamodule)
    steps = model.simulation_horizon
    fine_tune_epochs = model.training_settings.simulation_epochs
    if steps > 0 and fine_tune_epochs is not None and model.simulation_trained:
        log.info("%s trains on the free-run error alone: simulation_epochs=%s (a one-step stage "
                 "first) does not apply to it", type(model).__name__, fine_tune_epochs)
        fine_tune_epochs = None
    if steps > 0 and fine_tune_epochs is None:  # the free-run error is the only objective
        best, _, val_mse, trained = _fit_free_run(
            model, datamodule, settings, output_dir, logger, "simulation", steps,
            int(settings.max_epochs), callbacks, RunFolder.CHECKPOINTS,
            starting_checkpoint=None, keep_start=True, finite_start=True, resume=resume,
            keep_last=keep_last,
        )
        epochs = {"simulation": trained}
        detail = f" (validation free-run MSE {val_mse:.4e}, scaled)"
    else:
        best, val_mse, epochs = _fit_one_step_and_fine_tune(
            model, datamodule, settings, output_dir, logger, callbacks, one_step, resume,
            fine_tune_epochs, keep_last)
        detail = ""
    model.stage_lr = None
    seconds = time.perf_counter() - start
    log.info("trained in %.1f s%s", seconds, detail)
    return TrainResult(model.eval(), val_mse, seconds, best, epochs=epochs)


def _fit_one_step_and_fine_tune(
    model: L.LightningModule,
    datamodule: WindowDataModule,
    settings: TrainerSettings,
    output_dir: Path,
    logger: TensorBoardLogger | None,
    callbacks: list[Any] | None,
    one_step: bool,
    resume: bool,
    fine_tune_epochs: int | None,
    keep_last: bool = False,
) -> tuple[Path | None, float, dict[str, int]]:
    """The one-step stage, then (with a free-run horizon) free-run fine-tuning from its best
    checkpoint; ``one_step=False`` fine-tunes the (warm-started) weights directly and falls
    back to both stages when that does not beat them. The kept checkpoint, its loss and
    each stage's epochs (`TrainResult.epochs`)."""
    steps = model.simulation_horizon
    stages = (model, datamodule, settings, output_dir, logger, "fine_tune", steps)
    if not one_step and steps > 0:
        best, improved, val_mse, tuned = _fit_free_run(
            *stages, int(fine_tune_epochs), None, RunFolder.FREE_RUN_CHECKPOINTS,
            starting_checkpoint=None, keep_start=True, resume=resume, keep_last=keep_last,
        )
        if improved:
            return best, val_mse, {"one_step": 0, "fine_tune": tuned}
        # the new inputs were not learned: refit from the warm start
        log.info("refitting the warm-started network on the one-step error first")
        resume = False  # the free-run folder holds that first stage's checkpoints
    best, val_mse, trained = _fit_one_step(model, datamodule, settings, output_dir, logger,
                                           callbacks, resume, keep_last)
    epochs = {"one_step": trained}
    if steps > 0:
        best, _, val_mse, epochs["fine_tune"] = _fit_free_run(
            *stages, int(fine_tune_epochs), None, RunFolder.FREE_RUN_CHECKPOINTS,
            starting_checkpoint=best, keep_start=True, resume=resume, keep_last=keep_last,
        )
    return best, val_mse, epochs


def _initialise_from_data(model: L.LightningModule, datamodule: WindowDataModule) -> None:
    """Starting values read off the training recordings
    (`ModelContract.initialise_from_recordings`: e.g. SUBNET's linear start, the linear
    model's ARX fit, the grey-box's mode); not for a warm-started refit (`warm_started`, even
    with nothing new: the warm start's weights stay)."""
    if not model.warm_started:
        model.initialise_from_recordings(datamodule.splits.train)


def _fit_one_step(
    model: L.LightningModule,
    datamodule: WindowDataModule,
    settings: TrainerSettings,
    output_dir: Path,
    logger: TensorBoardLogger | None,
    callbacks: list[Any] | None,
    resume: bool = False,
    keep_last: bool = False,
) -> tuple[Path | None, float, int]:
    """The study's training on the one-step error; the best checkpoint's path, its loss and
    the epochs it trained (``keep_last``: the last epoch's)."""
    last, checkpoint, all_callbacks = _stage_callbacks(output_dir / RunFolder.CHECKPOINTS,
                                                       resume, callbacks)
    model.stage_lr = stage_lr(model, "one_step")
    if logger is not None:
        all_callbacks.append(LearningRateMonitor(logging_interval="epoch"))
    trainer = build_trainer(
        settings, all_callbacks, module=model,
        logger=logger if logger is not None else False, default_root_dir=str(output_dir),
    )
    best, val_mse, epochs = _train_keeping_best(trainer, model, datamodule, last, checkpoint,
                                                keep_last=keep_last)
    log.info("best validation MSE %.4e (scaled); checkpoint %s", val_mse, best)
    return best, val_mse, epochs


def _stage_callbacks(
    directory: Path, resume: bool, callbacks: list[Any] | None
) -> tuple[Path | None, ModelCheckpoint, list[Any]]:
    """A stage's start (`_stage_start`) and checkpoints in ``directory``: the ``last.ckpt``
    it resumes from (or None), its best checkpoint's callback, and every callback it runs
    (the best checkpoint, the last epoch's, a stop when asked, then ``callbacks``)."""
    last = _stage_start(directory, resume)
    checkpoint = _best_checkpoint(directory)
    return last, checkpoint, [checkpoint, _LastEpoch(directory), _StopWhenAsked(),
                              *(callbacks or [])]


def _train_keeping_best(
    trainer: L.Trainer,
    model: L.LightningModule,
    data: L.LightningDataModule,
    last: Path | None,
    checkpoint: ModelCheckpoint,
    diverged_ok: bool = False,
    keep_last: bool = False,
) -> tuple[Path | None, float, int]:
    """Train ``model`` on ``data`` (going on from the ``last`` checkpoint when given) and load
    its best checkpoint's weights (`_restore_best`; ``keep_last``: keep the last epoch's);
    ``diverged_ok``: a `DivergedError` ends the training with a warning (the best epoch
    before it is kept, with ``keep_last`` too). The kept checkpoint, its validation loss and
    its epochs."""
    diverged = False
    try:
        with _resuming(last):
            trainer.fit(model, datamodule=data, ckpt_path=last)
    except DivergedError as exc:
        if not diverged_ok:
            raise
        log.warning("free-run fine-tuning diverged (%s)", exc)
        diverged = True
    if keep_last and not diverged:
        loss = trainer.callback_metrics.get("val_loss")
        return None, float(loss) if loss is not None else float("nan"), trainer.current_epoch
    return _restore_best(model, checkpoint)


def check_trainer_settings(settings: TrainerSettings) -> None:
    """Fail before any data or training work when the ``trainer`` settings cannot train a
    network: a training length that trains nothing or never stops, settings Lightning refuses
    (an unknown argument, a precision or accelerator this machine lacks) or more than one
    device (a model here trains, and is scored, in one process on one device)."""
    _check_max_epochs(settings)
    quiet = ("enable_progress_bar", "logger", "enable_checkpointing", "enable_model_summary")
    try:
        with _lightning_info_muted():  # the real fit logs the device lines once
            trainer = build_trainer(settings, **dict.fromkeys(quiet, False))
    except (MisconfigurationException, ModuleNotFoundError, TypeError, ValueError) as exc:
        raise ConfigError(
            f"Lightning refused the trainer settings: {str(exc).rstrip('.! ')}. Fix: correct "
            "the trainer.* override (trainer.accelerator=auto takes a GPU when there is one, "
            "else the CPU)."
        ) from exc
    if trainer.num_devices > 1 or trainer.num_nodes > 1:
        raise ConfigError(
            f"trainer.devices={settings.devices!r} gives {trainer.num_devices} "
            f"devices on {trainer.num_nodes} node(s); a model here trains on one device (the "
            "paper run trains several models side by side instead). Fix: trainer.devices=1, or "
            "trainer.devices=[<index>] to pick one GPU."
        )


@contextlib.contextmanager
def _lightning_info_muted() -> Iterator[None]:
    """Hold back Lightning's info lines (devices found, tips) while a Trainer is only built
    to check its settings."""
    lightning_log = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    level = lightning_log.level
    lightning_log.setLevel(logging.WARNING)
    try:
        yield
    finally:
        lightning_log.setLevel(level)


def _check_max_epochs(settings: TrainerSettings) -> None:
    """A network must train at least one epoch and must stop."""
    epochs = settings.max_epochs
    if epochs is None or int(epochs) < 1:
        raise ConfigError(
            f"trainer.max_epochs={epochs} must be a whole number >= 1 (0 trains nothing, -1 "
            "never stops). Fix: e.g. trainer.max_epochs=100 (the study's)."
        )


def _best_checkpoint(directory: Path) -> ModelCheckpoint:
    """Keeps the one checkpoint with the lowest ``val_loss``."""
    return _CheckpointWrittenWhole(
        dirpath=directory,
        filename="best-{epoch:03d}-{val_loss:.3e}",
        monitor="val_loss",
        mode="min",
        save_top_k=1,
        save_last=False,
    )


class _LastEpoch(Checkpoint):
    """Writes the training state after every epoch to ``last.ckpt`` in ``directory``, what an
    interrupted fit resumes from (`RunFolder.finish_fit` deletes it). A `Checkpoint`, so that
    Lightning calls it after the best checkpoint's callback and early stopping, whose state it
    keeps; the file is replaced whole, and a stop signal waits for it
    (Lightning's own ``save_last`` writes only epochs that improved)."""

    def __init__(self, directory: Path) -> None:
        self.path = Path(directory) / RunFolder.LAST_CHECKPOINT

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        partial = self.path.with_name(RunFolder.PARTIAL_CHECKPOINT)
        with signals_deferred():
            trainer.save_checkpoint(partial, weights_only=False)  # a whole resumable state
            os.replace(partial, self.path)


class _CheckpointWrittenWhole(ModelCheckpoint):
    """A `ModelCheckpoint` that a stop signal does not interrupt while it writes (and
    deletes the best it replaces): an interrupted run keeps whole checkpoints, and no best
    beside the new one."""

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        with signals_deferred():
            super().on_train_epoch_end(trainer, pl_module)

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        with signals_deferred():
            super().on_validation_end(trainer, pl_module)


def _stage_start(directory: Path, resume: bool) -> Path | None:
    """The ``last.ckpt`` a stage resumes from (``resume`` and the file there); else None,
    after deleting the checkpoints an earlier fit left in ``directory`` (they are not this
    fit's, and would stay beside its best)."""
    last = directory / RunFolder.LAST_CHECKPOINT
    if resume and last.is_file():
        log.info("resuming the interrupted training from %s", last)
        return last
    for stale in directory.glob("*.ckpt"):
        stale.unlink()
    return None


@contextlib.contextmanager
def _resuming(last: Path | None) -> Iterator[None]:
    """A stage's training: Lightning's warning that the checkpoint folder is not empty is no
    news when it resumes from the ``last`` checkpoint there; Lightning's own stop on SIGTERM
    (an exit with status 0, where `RunInterrupted` got lost) is a `RunInterrupted`."""
    with warnings.catch_warnings():
        if last is not None:
            warnings.filterwarnings("ignore", message=r"Checkpoint directory .* not empty")
        try:
            yield
        except SIGTERMException:
            raise RunInterrupted(signal.SIGTERM) from None


class _StopWhenAsked(L.Callback):
    """Stops training at the next batch when a stop signal's exception got lost
    (`raise_if_stopped`)."""

    def on_train_batch_end(self, *args: Any) -> None:
        raise_if_stopped()

    def on_validation_batch_end(self, *args: Any) -> None:
        raise_if_stopped()


class _StayStopped(L.Callback):
    """A stage resumed after early stopping had ended it trains no further epoch (Lightning
    does not keep ``should_stop`` in a checkpoint, only the early stopping's state)."""

    def __init__(self, early_stopping: EarlyStopping) -> None:
        self.early_stopping = early_stopping

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.early_stopping.stopped_epoch > 0:
            trainer.should_stop = True


def _restore_best(
    model: L.LightningModule, checkpoint: ModelCheckpoint
) -> tuple[Path | None, float, int]:
    """Load the weights of the best checkpoint; its path, validation loss and the epochs it
    trained (its 0-based epoch + 1; 0 without one). Other best
    checkpoints beside it are deleted: a fit resumed from a ``last.ckpt`` written before the
    interrupted fit's last best does not know that best, which would stay beside the new."""
    best = checkpoint.best_model_path
    epochs = 0
    if best:
        for stale in Path(best).parent.glob("best-*.ckpt"):
            if stale.name != Path(best).name:
                stale.unlink()
        saved = torch.load(best, map_location=model.device, weights_only=True)
        model.load_state_dict(saved["state_dict"])
        epochs = int(saved.get("epoch", -1)) + 1
    score = checkpoint.best_model_score
    loss = float(score) if score is not None else float("nan")
    return (Path(best) if best else None), loss, epochs


def _fit_free_run(
    model: L.LightningModule,
    datamodule: WindowDataModule,
    settings: TrainerSettings,
    output_dir: Path,
    logger: TensorBoardLogger | None,
    lr_stage: Stage,
    steps: int,
    epochs: int,
    callbacks: list[Any] | None,
    folder: str,
    starting_checkpoint: Path | None,
    keep_start: bool,
    finite_start: bool = False,
    resume: bool = False,
    keep_last: bool = False,
) -> tuple[Path | None, bool, float, int]:
    """Simulation-error training: minimise the free-run MSE over ``steps``-sample segments.

    Runs ``epochs`` epochs from the current weights at the learning rate of ``lr_stage``
    (``"simulation"`` or ``"fine_tune"``, `stage_lr`) and keeps the
    checkpoint with the best validation free-run loss (model selection on the free run;
    ``training.patience`` epochs without a better one stop it early). ``keep_start``: the
    starting weights are a candidate too (a fitted network, or a model started from the
    data): when no epoch beat them on that loss, they stay and ``starting_checkpoint`` and
    False are returned. ``finite_start``: an initial model whose free run is not finite is
    an error (the model trains from it alone). ``resume``: go on from the stage's
    ``last.ckpt`` when there is one (see `fit`); ``keep_last``: all ``epochs``, the last
    weights kept (see `fit`) unless the training diverged. Returns the checkpoint, whether
    training improved on the start, the validation free-run MSE (scaled) of the weights kept
    and the epochs they trained (0: the start).
    """
    last, checkpoint, all_callbacks = _stage_callbacks(output_dir / folder, resume, callbacks)
    model.stage_lr = stage_lr(model, lr_stage)
    segments = simulation_data(datamodule, model, steps)
    patience = model.training_settings.patience
    if patience and not keep_last:
        early_stopping = EarlyStopping(monitor="val_loss", mode="min", patience=patience)
        all_callbacks += [early_stopping, _StayStopped(early_stopping)]
    # feedback through many steps: keep updates bounded
    clip = 1.0 if settings.gradient_clip_val is None else settings.gradient_clip_val
    stage_settings = settings.with_changes(max_epochs=epochs, gradient_clip_val=clip)
    starting_weights = {k: v.detach().clone() for k, v in model.state_dict().items()}
    model.simulation_mode = True
    try:
        version = "" if folder == RunFolder.CHECKPOINTS else "free_run"
        stage_logger = (
            TensorBoardLogger(save_dir=logger.save_dir, name=logger.name, version=version)
            if logger is not None
            else False
        )
        if stage_logger:
            all_callbacks.append(LearningRateMonitor(logging_interval="epoch"))
        trainer = build_trainer(stage_settings, all_callbacks, module=model,
                                logger=stage_logger, default_root_dir=str(output_dir))
        starting_loss = float(
            trainer.validate(model, datamodule=segments, verbose=False)[0]["val_loss"]
        )
        if not np.isfinite(starting_loss) and finite_start:
            raise DivergedError(
                "the initial model's free run is not finite on the validation segments (an "
                "unstable initial model). Fix: a shorter training.horizon, or check the data "
                "scaling (data.scaling) and the model's initial settings."
            )
        best, val_free_run, trained = _train_keeping_best(
            trainer, model, segments, last, checkpoint, diverged_ok=not finite_start,
            keep_last=keep_last)
    finally:
        model.simulation_mode = False
    # the last epoch's weights stand unless the training diverged (then its best epoch, or
    # the start, is kept as without keep_last)
    kept_last = keep_last and best is None and np.isfinite(val_free_run)
    if keep_start and not kept_last and not val_free_run < starting_loss:
        model.load_state_dict(starting_weights)
        log.info(
            "free-run fine-tuning did not beat the starting weights on validation (%.4e vs "
            "%.4e, scaled): kept them",
            val_free_run,
            starting_loss,
        )
        return starting_checkpoint, False, starting_loss, 0
    log.info(
        "free-run training: validation free-run MSE %.4e -> %.4e (scaled) over %s",
        starting_loss,
        val_free_run,
        "whole recordings" if model.whole_recordings else f"{steps} steps",
    )
    return best, True, val_free_run, trained


#: model parameters that come from the data, never from the config
DERIVED_PARAMETERS = {"self", "nu", "ny", "na", "nb", "nk", "scaler", "feature_context",
                      "n_base_inputs", "trained_on", "baseline_channels"}

