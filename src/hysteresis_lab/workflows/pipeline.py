"""Train-and-evaluate runs of one model (the study's four: `hysteresis_lab.workflows.paper`).

`run_model` on a `RunConfig` (its configs made objects once, where the run starts) prepares
the data, reuses a finished fit or trains one, scores it and writes the run folder; each step
is its own function below.

Everything a run produces lands in its output folder: checkpoints, ``metrics.json``,
hysteresis-loop and residual figures, and TensorBoard event files (loss curves, figures,
final metrics as hparams).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.loggers import TensorBoardLogger
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab import fit_record
from hysteresis_lab.data.checks import warn_weak_excitation
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.factory import build_datamodule, build_splits
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.effects.registry import check_effects
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.evaluation.evaluate import Evaluation, evaluate_model, scoring_start
from hysteresis_lab.evaluation.plots import loops_figure, residuals_figure, save_figure
from hysteresis_lab.evaluation.predict import check_n_step
from hysteresis_lab.evaluation.report import metrics_document
from hysteresis_lab.fitting import (
    TrainResult,
    build_model,
    check_trainer_settings,
    fit,
)
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.augment import Baseline, augment_splits, context_to_dict, warn_unshown
from hysteresis_lab.models.interface import SystemModel
from hysteresis_lab.models.io import baseline_of, load_model, model_window, save_model
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.run_folder import RunFolder
from hysteresis_lab.workflows.grow import TrainStage, grow, growth_stages

log = logging.getLogger(__name__)



@dataclass
class RunResult:
    """What one trained model produced: its metrics document and validation MSE."""

    document: dict[str, Any]
    val_mse: float
    evaluation: Evaluation
    model: SystemModel
    window: WindowSpec
    improved: bool = True  # False: a warm-started refit kept its start (see training.fit)
    #: a warm-started refit's validation loss: {"start": x, "refit": x}
    refit_validation: dict[str, float] | None = None
    #: the metrics document of a refit that lost to its start (what it would have done)
    rejected_refit: dict[str, Any] | None = None


def plain_dict(cfg: Mapping[str, Any] | DictConfig) -> dict[str, Any]:
    """A resolved plain dict of a Hydra config node (or a copy of a mapping)."""
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    return dict(cfg)


@dataclass(frozen=True)
class RunSettings:
    """How one run trains and what it writes, beyond the model, data and trainer configs.

    ``refit``: with a warm start, ``"new_inputs"`` trains only the new input channels' weights
    (`NarxModule.train_new_inputs_only`), ``"full"`` every weight; the start is kept unless
    the refit beats it on validation by more than the share ``min_refit_gain``. ``reuse``: a
    fit that finished in the output folder with the same settings, data and start
    (`hysteresis_lab.fit_record`) is loaded and scored instead of trained. ``resume``: a
    network fit interrupted in the output folder with the same settings, data and start goes
    on from its last checkpoints (`RunFolder.FIT_IN_PROGRESS`); one with other settings is
    refused; without ``resume`` it starts afresh.
    """

    seed: int = 0
    use_tensorboard: bool = True
    n_steps: int | None = None
    plots: bool = True
    evaluate: bool = True
    refit: str = "full"
    min_refit_gain: float = 0.0
    reuse: bool = False
    resume: bool = True
    initial_state: str = "rest"


@dataclass(frozen=True)
class RunConfig:
    """One run, its configs as objects: the ``model`` (a `ModelSpec`), ``data`` (a
    `DataSpec`), ``trainer`` (`TrainerSettings`) and ``training`` (`TrainingSettings`, how a
    network trains), where it writes, and its `RunSettings`. Made once where a run starts
    (`RunConfig.build` from config mappings, `RunConfig.from_config` from a composed
    ``train`` config) and passed on as it is."""

    model: ModelSpec
    data: DataSpec
    trainer: TrainerSettings
    output_dir: Path
    settings: RunSettings = RunSettings()
    #: None: the model's own (`ModelSpec.training_settings`)
    training: TrainingSettings = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.training is None:
            object.__setattr__(self, "training", self.model.training_settings())

    @classmethod
    def build(
        cls,
        model: Mapping[str, Any] | ModelSpec,
        data: Mapping[str, Any] | DataSpec,
        trainer: Mapping[str, Any] | TrainerSettings,
        output_dir: Path | str,
        training: Mapping[str, Any] | TrainingSettings | None = None,
        **settings: Any,
    ) -> RunConfig:
        """A run of ``model`` on ``data``: each config turned into its object here, once
        (objects pass as they are); ``training``: the ``training`` config (its unset values:
        the model's own defaults) or settings; ``settings``: `RunSettings` by name."""
        spec = model if isinstance(model, ModelSpec) else ModelSpec.from_config(plain_dict(model))
        if not isinstance(training, TrainingSettings):
            training = spec.training_settings(plain_dict(training or {}))
        return cls(spec, DataSpec.from_config(data), TrainerSettings.from_config(trainer),
                   Path(output_dir), RunSettings(**settings), training)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], output_dir: Path) -> RunConfig:
        """The run of a composed ``train`` config (``model``, ``data``, ``trainer``,
        ``training``, ``seed``, ``logger``, ``n_step``, ``plots``, ``evaluate``)."""
        return cls.build(
            cfg["model"], cfg["data"], cfg["trainer"], output_dir, cfg.get("training"),
            seed=cfg["seed"],
            use_tensorboard=bool(cfg["logger"].get("enabled", True)),
            n_steps=cfg.get("n_step"),
            plots=cfg["plots"],
            evaluate=cfg.get("evaluate", True),
            initial_state=str((cfg.get("evaluation") or {}).get("initial_state", "rest")),
            # a sweep's trial starts afresh: a resumed sweep hands its folder (runs/<job>) to
            # another trial, whose interrupted predecessor it must not continue
            resume=(cfg.get("sweep_trial") or {}).get("number") is None,
        )

    @property
    def model_name(self) -> str:
        return self.model.name


def train_from_config(
    cfg: Mapping[str, Any],
    output_dir: Path,
    splits: DatasetSplits | None = None,
    callbacks: list[Any] | None = None,
) -> RunResult:
    """`run_model` on the run of a composed ``train`` config (`RunConfig.from_config`): what
    ``hysteresis-lab-train`` and `hysteresis_lab.api.train` run."""
    return run_model(RunConfig.from_config(cfg, Path(output_dir)), splits=splits,
                     callbacks=callbacks)


def run_model(
    config: RunConfig,
    splits: DatasetSplits | None = None,
    callbacks: list[Any] | None = None,
    warm_start: Any | None = None,
) -> RunResult:
    """Run ``config``: prepare the data (``splits``, else loaded from the data config),
    reuse a finished fit or train, then score and write the run folder.

    ``warm_start``: a fitted network of the same architecture whose inputs are the first of
    this model's (see `NarxModule.warm_start_from`); both training stages run from it, and
    it is kept when they do not beat it on validation (by more than the share
    `RunSettings.min_refit_gain`)."""
    if config.model.is_network:  # before any data or training work
        check_trainer_settings(config.trainer)
    config.output_dir.mkdir(parents=True, exist_ok=True)
    L.seed_everything(config.settings.seed, workers=True, verbose=False)
    splits, data, context, baseline = _run_data(config, splits)
    record_key, fit_key = _fit_keys(config, splits, warm_start, baseline)
    reused = _reuse_finished_fit(config, record_key, data)
    if reused is not None:
        return reused
    resume = _resume_interrupted_fit(config, fit_key)
    # this fit overwrites the folder's files: an older record must not vouch for them
    fit_record.forget(config.output_dir)
    try:
        result = _train_and_score(config, splits, data, context, warm_start, baseline,
                                  callbacks, record_key, resume)
    except Exception:  # an error, not an interruption: a rerun starts afresh
        RunFolder(config.output_dir).finish_fit()
        raise
    RunFolder(config.output_dir).finish_fit()
    return result


def _train_and_score(
    config: RunConfig,
    splits: DatasetSplits,
    data: DatasetSplits,
    context: Any,
    warm_start: Any | None,
    baseline: Baseline | None,
    callbacks: list[Any] | None,
    record_key: str | None,
    resume: bool,
) -> RunResult:
    """Build and fit the model (going on from an interrupted fit: ``resume``; a declared
    physical model grows from ``splits`` through its stages, `hysteresis_lab.workflows.grow`,
    each from the start), save it, then score it and write the run folder's documents
    (`RunSettings.evaluate`). A grown model does not resume: its stages train afresh."""
    settings = config.settings
    logger = _tensorboard_logger(config)
    if warm_start is None and len(growth_stages(config.model)) > 1:
        trained = grow(config.model, config.training, config.output_dir,
                       _stage_trainer(config, splits, baseline, callbacks))
        window = model_window(trained.model)
    else:
        datamodule, model = _build(config, data, context, config.model.effects, warm_start,
                                   baseline)
        trained = fit(
            model, datamodule, config.trainer, config.output_dir, logger=logger,
            callbacks=callbacks, keep_start_unless_beaten=warm_start is not None,
            min_gain=settings.min_refit_gain, resume=resume,
        )
        window = datamodule.window
    model_path = save_model(trained.model, RunFolder(config.output_dir).model_stem)
    log.info("saved %s", model_path)
    if not settings.evaluate:
        return _unscored_result(config, data, trained, window)
    return _score_and_report(config, data, trained, window, model_path, logger, record_key)


def _stage_trainer(
    config: RunConfig, splits: DatasetSplits, baseline: Baseline | None,
    callbacks: list[Any] | None,
) -> TrainStage:
    """Trains one growth stage (`hysteresis_lab.workflows.grow`) of ``config``'s model: its
    settings, in its folder, warm-started from the model it grows from (None: from the
    data), with that refit mode; the start is kept unless the refit beats it."""

    def train_stage(settings: Mapping[str, Any], training: TrainingSettings, folder: Path,
                    previous: Any | None, refit: str) -> TrainResult:
        stage = dataclasses.replace(
            config, model=config.model.with_settings(settings), training=training,
            output_dir=folder, settings=dataclasses.replace(config.settings, refit=refit))
        folder.mkdir(parents=True, exist_ok=True)
        data, context = augment_splits(splits, stage.model.effects)
        if baseline is not None:
            data = baseline.append_to_splits(data, splits)
        datamodule, model = _build(stage, data, context, stage.model.effects, previous,
                                   baseline)
        # every stage's curves under the run's TensorBoard folder, one run each
        logger = None if not config.settings.use_tensorboard else TensorBoardLogger(
            save_dir=str(config.output_dir / RunFolder.TENSORBOARD),
            name=str(folder.relative_to(config.output_dir)), version="",
            default_hp_metric=False)
        return fit(model, datamodule, config.trainer, folder,
                   logger=logger, callbacks=callbacks,
                   keep_start_unless_beaten=previous is not None,
                   min_gain=config.settings.min_refit_gain)

    return train_stage


def _resume_interrupted_fit(config: RunConfig, key: str) -> bool:
    """Whether the fit goes on from the last checkpoints of an interrupted one in the output
    folder (same fingerprint ``key``); marks this fit unfinished there until it is."""
    if not config.model.is_network:  # nothing to resume: it fits in one step
        return False
    folder = RunFolder(config.output_dir)
    interrupted = folder.read_fit_in_progress()
    resume = config.settings.resume and interrupted == key
    if interrupted is not None and interrupted != key and config.settings.resume:
        raise ConfigError(
            f"{config.output_dir} holds a training interrupted with other settings (model, "
            "data, trainer, seed or start differ). Fix: rerun it with its own settings to "
            f"resume it, use another folder (hydra.run.dir=...), or delete "
            f"{folder.fit_in_progress} to start over there."
        )
    folder.start_fit(key)
    return resume


def _run_data(
    config: RunConfig, splits: DatasetSplits | None
) -> tuple[DatasetSplits, DatasetSplits, Any, Baseline | None]:
    """The data set (``splits``, else built from the data config), the same with the effects'
    operator channels (and the free run of the model's ``baseline``, returned too) added,
    and the effects' feature context; checked for scoring when it will be."""
    effects = config.model.effects
    baseline = baseline_of(config.model)
    check_effects(effects)
    splits = splits or build_splits(config.data)
    warn_weak_excitation(splits, config.data.window)
    data, context = augment_splits(splits, effects)
    warn_unshown(effects, context, config.model.to_config())
    if baseline is not None:
        data = baseline.append_to_splits(data, splits)
    if config.settings.evaluate:
        _check_evaluation_settings(data, config.settings.n_steps, config.data.window)
    return splits, data, context, baseline


def _fit_record_key(
    config: RunConfig, splits: DatasetSplits, warm_start: Any | None,
    baseline: Baseline | None = None,
) -> str | None:
    """The fingerprint a finished fit of this run records, when the run may reuse one."""
    return _fit_keys(config, splits, warm_start, baseline)[0]


def _fit_keys(
    config: RunConfig, splits: DatasetSplits, warm_start: Any | None,
    baseline: Baseline | None = None,
) -> tuple[str | None, str]:
    """The fingerprint a finished fit of this run records, when the run may reuse one
    (else None), and the one an interrupted fit of it resumes under (display settings of
    the trainer aside)."""
    settings = config.settings
    whole = _fingerprinted(config, warm_start, baseline)
    resumed = _fingerprinted(config, warm_start, baseline, ignore=DISPLAY_SETTINGS)
    record = (fit_record.fingerprint(whole, splits, warm_start)
              if settings.reuse and settings.evaluate else None)
    return record, fit_record.fingerprint(resumed, splits, warm_start)


#: trainer settings that change what a fit shows, not what it computes: an interrupted fit
#: resumes with other values of them
DISPLAY_SETTINGS = ("enable_progress_bar", "enable_model_summary", "log_every_n_steps")


def _fingerprinted(
    config: RunConfig, warm_start: Any | None, baseline: Baseline | None = None,
    ignore: tuple[str, ...] = (),
) -> dict[str, Any]:
    """Every setting the fit depends on, as `fit_record.fingerprint` digests them (with the
    data and the start), but the trainer settings ``ignore`` names."""
    settings = config.settings
    trainer = {k: v for k, v in config.trainer.to_config().items() if k not in ignore}
    fingerprinted = {
        "model": config.model.to_config(), "data": config.data.to_config(),
        "trainer": trainer,
        "seed": settings.seed, "n_steps": settings.n_steps,
        "refit": settings.refit if warm_start is not None else None,
        "min_refit_gain": settings.min_refit_gain,
    }
    if config.model.is_network:
        fingerprinted["training"] = config.training.to_dict()
    if baseline is not None:  # only then: the records of runs without one stay valid
        fingerprinted["baseline"] = baseline.digest
    return fingerprinted


def _reuse_finished_fit(
    config: RunConfig, key: str | None, data: DatasetSplits
) -> RunResult | None:
    """The finished fit recorded under ``key`` in the run folder, its model loaded and scored
    again (the same weights give the same predictions; nothing is trained or rewritten);
    None when there is none, its model file cannot be loaded any more, or the run may not
    reuse one (no ``key``)."""
    output_dir, trainer = config.output_dir, config.trainer
    record = None if key is None else fit_record.finished_fit(output_dir, key)
    if record is None:
        return None
    try:
        model = load_model(output_dir / record["model_file"])
    except DataError as exc:
        log.warning("the fit in %s cannot be reused (%s): it trains again", output_dir, exc)
        return None
    log.info(
        "%s: reusing the finished fit there (same settings, data and start; %s). To train "
        "it again, delete that file or run with loop.resume=false (paper.resume=false)",
        output_dir, fit_record.FIT_RECORD,
    )
    folder = RunFolder(output_dir)
    document = folder.read_metrics()
    rejected_refit = folder.read_rejected_refit_metrics() if record["rejected"] else None
    window = model_window(model)
    evaluation = evaluate_model(
        model, data.test, window, n_init=data.n_init, n_steps=config.settings.n_steps,
        device=trainer.evaluation_device(), progress=trainer.shows_progress,
        initial_state=config.settings.initial_state,
    )
    return RunResult(
        document, record["val_mse"], evaluation, model, window, record["improved"],
        record["refit_validation"], rejected_refit,
    )


def _build(
    config: RunConfig,
    data: DatasetSplits,
    context: Any,
    effects: list[str],
    warm_start: Any | None,
    baseline: Baseline | None = None,
) -> tuple[WindowDataModule, SystemModel]:
    """The DataModule and the untrained model (started from ``warm_start`` when given; with
    the ``baseline`` whose free run it reads, saved with it)."""
    extra: dict[str, Any] = {"trained_on": _trained_on(data)}
    if effects:
        extra.update(feature_context=context_to_dict(context),
                     n_base_inputs=data.metadata["n_base_inputs"])
    if baseline is not None:  # its free run: the last channels, one per output
        extra.update(n_base_inputs=data.metadata["n_base_inputs"], baseline_channels=data.ny)
    datamodule = build_datamodule(
        config.data, config.model.layout, seed=config.settings.seed, splits=data
    )
    model = build_model(config.model, datamodule, config.training, **extra)
    if baseline is not None:
        model.baseline = baseline
    if warm_start is not None:
        model.warm_start_from(warm_start)
        if config.settings.refit == "new_inputs":
            model.train_new_inputs_only()
    return datamodule, model


def _tensorboard_logger(config: RunConfig) -> TensorBoardLogger | None:
    if not config.settings.use_tensorboard:
        return None
    return TensorBoardLogger(
        save_dir=str(config.output_dir), name=RunFolder.TENSORBOARD, version="",
        default_hp_metric=False,
    )


def _unscored_result(
    config: RunConfig, data: DatasetSplits, trained: TrainResult, window: WindowSpec
) -> RunResult:
    """A run with ``evaluate=False`` (a sweep trial): its validation loss and cost only."""
    document = {
        "model": config.model_name,
        "data": data.name,
        "val_mse_scaled": trained.val_mse,
        "train_seconds": trained.train_seconds,
    }
    RunFolder(config.output_dir).write_metrics(document)
    return RunResult(
        document, trained.val_mse, Evaluation(), trained.model, window, trained.improved,
        trained.refit_validation,
    )


def _score_and_report(
    config: RunConfig,
    data: DatasetSplits,
    trained: TrainResult,
    window: WindowSpec,
    model_path: Path,
    logger: TensorBoardLogger | None,
    record_key: str | None,
) -> RunResult:
    """Score the trained model on the test recordings; write metrics.json, figures, the fit
    record and the TensorBoard summary."""
    settings, output_dir = config.settings, config.output_dir
    folder = RunFolder(output_dir)
    evaluation = evaluate_model(
        trained.model, data.test, window, n_init=data.n_init, n_steps=settings.n_steps,
        device=config.trainer.evaluation_device(), progress=config.trainer.shows_progress,
        initial_state=settings.initial_state,
    )
    units = {"u": data.test[0].u_units, "y": data.test[0].y_units}
    rejected_refit = _keep_rejected_refit(config, data, trained, window, units)
    document = metrics_document(
        config.model_name,
        units,
        evaluation.metrics,
        trained.train_seconds,
        extra={"val_mse_scaled": trained.val_mse, "data": data.name, "model_path": str(model_path),
               "initial_state": settings.initial_state},
    )
    folder.write_metrics(document)
    if settings.plots:
        _write_figures(data, evaluation, folder, config.model_name, logger)
    if record_key is not None:
        _write_fit_record(output_dir, record_key, model_path, trained, rejected_refit is not None)
    if logger is not None:
        _log_summary(logger, config, data.name, document, trained.val_mse)
    log.info(
        "%s on %s: mean RMSE one-step %.4g %s, free-run %.4g %s (metrics.json in %s)",
        config.model_name,
        data.name,
        document["mean"]["rmse_one_step"],
        units["y"],
        document["mean"]["rmse_free_run"],
        units["y"],
        output_dir,
    )
    return RunResult(
        document, trained.val_mse, evaluation, trained.model, window, trained.improved,
        trained.refit_validation, rejected_refit,
    )


def _keep_rejected_refit(
    config: RunConfig,
    data: DatasetSplits,
    trained: TrainResult,
    window: WindowSpec,
    units: dict[str, str],
) -> dict[str, Any] | None:
    """A refit that lost to its start: score its own weights, save them and their metrics
    beside the kept model (`RunFolder`'s rejected-refit names; a warm-started refit's
    ``model.*`` holds the start it lost to)."""
    if trained.rejected_state is None:
        return None
    folder = RunFolder(config.output_dir)
    # the refit's own weights for the scoring and the save; the kept start's afterwards
    with _weights(trained.model, trained.rejected_state) as rejected:
        rejected_refit = _score_rejected_refit(
            rejected, trained, data, window, config.trainer, config.settings.n_steps, units,
            config.model_name, config.settings.initial_state,
        )
        log.info("saved %s", save_model(rejected, folder.rejected_refit_stem))
    folder.write_rejected_refit_metrics(rejected_refit)
    return rejected_refit


def _write_fit_record(
    output_dir: Path, key: str, model_path: Path, trained: TrainResult, rejected: bool
) -> None:
    """Record the finished fit (its files and what `RunResult` needs) for a later reuse."""
    files = [model_path.name, RunFolder.METRICS]
    files += [RunFolder.REJECTED_REFIT_METRICS] if rejected else []
    fit_record.write_record(output_dir, key, {
        "files": files, "model_file": model_path.name,
        "val_mse": trained.val_mse, "improved": trained.improved,
        "refit_validation": trained.refit_validation, "rejected": rejected,
    })


def _log_summary(
    logger: TensorBoardLogger,
    config: RunConfig,
    data_name: str,
    document: Mapping[str, Any],
    val_mse: float,
) -> None:
    """The run's settings and final scores as TensorBoard hparams."""
    hparams = {f"model/{k}": v for k, v in config.model.to_config().items() if _scalar(v)}
    if config.model.is_network:
        hparams.update({f"training/{k}": v for k, v in config.training.to_dict().items()
                        if _scalar(v)})
    hparams.update({"data": data_name, "seed": config.settings.seed})
    final = {f"test_mean/{k}": v for k, v in document["mean"].items()}
    final["val_mse_scaled"] = val_mse
    logger.log_hyperparams(hparams, final)
    logger.finalize("success")


def _trained_on(data: DatasetSplits) -> dict[str, Any]:
    """What a model keeps of its training data to refuse data it cannot score: the sampling
    rate (its lags span a fixed number of samples) and the physical units (its scaler works
    in them); and whether every recording starts from one shared unknown state, with the
    longest training recording's length for the burn-in to it, and whether the output
    integrates (only where the data set says so, so other models keep the settings they
    had)."""
    shared = {"shared_initial_state": True,
              "burn_in_samples": max(r.n_samples for r in data.train)} \
        if data.shared_initial_state else {}
    integrates = {"output_integrates": True} if data.output_integrates else {}
    return {"fs": data.fs, **{f"{k}_units": v for k, v in data.units.items()}, **shared,
            **integrates}


def _check_evaluation_settings(
    data: DatasetSplits, n_steps: int | None, window: WindowSpec
) -> None:
    """Fail before training, not after it, when the evaluation cannot run."""
    if not data.test:
        raise DataError(
            "has no test recordings to evaluate on.",
            source=f"data set '{data.name}'",
            fix="give some with data.test=[a.csv,b.csv], or train only with evaluate=false",
        )
    check_n_step(n_steps)
    start = scoring_start(window, data.n_init)
    for rec in data.test:
        if rec.n_samples <= start:
            raise DataError(
                f"has {rec.n_samples} samples, but scoring starts at sample {start + 1} (the "
                f"model's window na={window.na}, nb={window.nb}, nk={window.nk}, "
                f"n_init={data.n_init}): nothing would be left to score.",
                source=f"test recording '{rec.metadata.get('path', rec.name)}'",
                fix="use a longer test recording, or smaller data.window.na / nb (or n_init)",
            )


def _score_rejected_refit(
    model: torch.nn.Module,
    trained: TrainResult,
    data: DatasetSplits,
    window: WindowSpec,
    trainer: TrainerSettings,
    n_steps: int | None,
    units: dict[str, str],
    model_name: str,
    initial_state: str = "rest",
) -> dict[str, Any]:
    """Test metrics of a refit that lost to its start on validation (``model``, holding the
    refit's weights), so that a report can show what it would have done."""
    evaluation = evaluate_model(
        model.eval(),
        data.test,
        window,
        n_init=data.n_init,
        n_steps=n_steps,
        device=trainer.evaluation_device(),
        initial_state=initial_state,
    )
    return metrics_document(
        model_name,
        units,
        evaluation.metrics,
        trained.train_seconds,
        extra={"rejected_refit": True, "validation_loss": trained.refit_validation},
    )


@contextmanager
def _weights(model: torch.nn.Module, state: Mapping[str, torch.Tensor]) -> Iterator[Any]:
    """``model`` with the weights ``state`` for the duration of the block; its own after."""
    own = {k: v.detach().clone() for k, v in model.state_dict().items()}
    model.load_state_dict(state)
    try:
        yield model
    finally:
        model.load_state_dict(own)


def _write_figures(
    data: DatasetSplits,
    evaluation: Evaluation,
    folder: RunFolder,
    title: str,
    logger: TensorBoardLogger | None,
) -> None:
    figures = {
        "hysteresis_loops": loops_figure(data.test, evaluation.predictions, title=title),
        "residuals": residuals_figure(data.test, evaluation.predictions, title=title),
    }
    for name, fig in figures.items():
        save_figure(fig, folder.figure(name))
        if logger is not None:
            logger.experiment.add_figure(f"test/{name}", fig)


def _scalar(value: Any) -> bool:
    return isinstance(value, int | float | str | bool)
