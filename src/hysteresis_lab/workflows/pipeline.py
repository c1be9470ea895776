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
from hysteresis_lab.data.factory import build_datamodule, build_splits
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.effects.registry import check_effects
from hysteresis_lab.errors import DataError
from hysteresis_lab.evaluation.evaluate import Evaluation, Scoring
from hysteresis_lab.evaluation.plots import loops_figure, residuals_figure, save_figure
from hysteresis_lab.evaluation.report import metrics_document
from hysteresis_lab.fitting import (
    TrainResult,
    build_model,
    check_trainer_settings,
    fit,
)
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.augment import Baseline, ModelData, feature_context
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
    improved: bool = True  # False: a warm-started refit kept its start (see fitting.fit)
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
    #: how the run scores its model: the ``n_step`` and ``evaluation`` settings, simulated on
    #: the trainer's device, with its progress bars
    scoring: Scoring = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        if self.training is None:
            object.__setattr__(self, "training", self.model.training_settings())
        settings, trainer = self.settings, self.trainer
        object.__setattr__(self, "scoring", Scoring(
            settings.n_steps, settings.initial_state, trainer.evaluation_device(),
            trainer.shows_progress))

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
    data = prepare_data(config, splits)
    keys = FitKeys.of(config, data, warm_start)
    reused = _reuse_finished_fit(config, keys.record, data.inputs)
    if reused is not None:
        return reused
    # a network fit may go on from an interrupted one; the others fit in one step
    resume = config.model.is_network and RunFolder(config.output_dir).claim_fit(
        keys.resume, config.settings.resume)
    # this fit overwrites the folder's files: an older record must not vouch for them
    fit_record.forget(config.output_dir)
    try:
        result = _train_and_score(config, data, warm_start, callbacks, keys.record, resume)
    except Exception:  # an error, not an interruption: a rerun starts afresh
        RunFolder(config.output_dir).finish_fit()
        raise
    RunFolder(config.output_dir).finish_fit()
    return result


def prepare_data(config: RunConfig, splits: DatasetSplits | None = None) -> ModelData:
    """The run's data, in one step: the data set (``splits``, else loaded from the data
    config) checked for what it can show, with the extra input channels the model reads
    (its effects' operators, its baseline's free run); checked for scoring when it will be
    scored."""
    model, window = config.model, config.data.window
    baseline = baseline_of(model)
    check_effects(model.effects)
    measured = splits or build_splits(config.data)
    warn_weak_excitation(measured, window)
    data = ModelData.of(measured, model.effects, baseline, model.to_config())
    if config.settings.evaluate:
        config.scoring.check(data.inputs, window)
    return data


def _train_and_score(
    config: RunConfig,
    data: ModelData,
    warm_start: Any | None,
    callbacks: list[Any] | None,
    record_key: str | None,
    resume: bool,
) -> RunResult:
    """Fit the model (`_train`), save it, then score it and write the run folder's
    documents (`RunSettings.evaluate`)."""
    logger = _tensorboard_logger(config)
    trained, window = _train(config, data, warm_start, callbacks, logger, resume)
    model_path = save_model(trained.model, RunFolder(config.output_dir).model_stem)
    log.info("saved %s", model_path)
    if not config.settings.evaluate:
        return _unscored_result(config, data.inputs, trained, window)
    return _score_and_report(config, data.inputs, trained, window, model_path, logger,
                             record_key)


def _train(
    config: RunConfig,
    data: ModelData,
    warm_start: Any | None,
    callbacks: list[Any] | None,
    logger: TensorBoardLogger | None,
    resume: bool,
) -> tuple[TrainResult, WindowSpec]:
    """The fitted model and its window: a declared physical model grows through its stages
    (`hysteresis_lab.workflows.grow`), each from the start, and does not resume; any other
    fits once (going on from an interrupted fit: ``resume``)."""
    if warm_start is None and len(growth_stages(config.model)) > 1:
        trained = grow(config.model, config.training, config.output_dir,
                       _stage_trainer(config, data, callbacks))
        return trained, model_window(trained.model)
    return _fit(config, data, warm_start, logger, callbacks, resume)


def _fit(
    config: RunConfig,
    data: ModelData,
    warm_start: Any | None,
    logger: TensorBoardLogger | None,
    callbacks: list[Any] | None,
    resume: bool = False,
) -> tuple[TrainResult, WindowSpec]:
    """Build the DataModule of ``data``'s inputs and the untrained model (started from
    ``warm_start`` when given; with the baseline whose free run it reads, saved with it),
    and fit it in the output folder; the start is kept unless the fit beats it."""
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
    )
    return trained, datamodule.window


def _stage_trainer(
    config: RunConfig, data: ModelData, callbacks: list[Any] | None
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
        # every stage's curves under the run's TensorBoard folder, one run each
        logger = None if not config.settings.use_tensorboard else TensorBoardLogger(
            save_dir=str(config.output_dir / RunFolder.TENSORBOARD),
            name=str(folder.relative_to(config.output_dir)), version="",
            default_hp_metric=False)
        return _fit(stage, data.with_effects(stage.model.effects), previous, logger,
                    callbacks)[0]

    return train_stage


#: trainer settings that change what a fit shows, not what it computes: an interrupted fit
#: resumes with other values of them
DISPLAY_SETTINGS = ("enable_progress_bar", "enable_model_summary", "log_every_n_steps")


@dataclass(frozen=True)
class FitKeys:
    """The fingerprints of a run's fit (`fit_record.fingerprint`): ``record``, what a
    finished fit records, when the run may reuse one (else None); ``resume``, what an
    interrupted fit of it resumes under (display settings of the trainer aside)."""

    record: str | None
    resume: str

    @classmethod
    def of(cls, config: RunConfig, data: ModelData, warm_start: Any | None) -> FitKeys:
        """The keys of ``config``'s fit on ``data`` from ``warm_start``."""
        settings = config.settings
        whole = _fingerprinted(config, warm_start, data.baseline)
        resumed = _fingerprinted(config, warm_start, data.baseline, ignore=DISPLAY_SETTINGS)
        reusable = settings.reuse and settings.evaluate
        record = fit_record.fingerprint(whole, data.measured, warm_start) if reusable else None
        return cls(record, fit_record.fingerprint(resumed, data.measured, warm_start))


def _fit_record_key(
    config: RunConfig, splits: DatasetSplits, warm_start: Any | None,
    baseline: Baseline | None = None,
) -> str | None:
    """The fingerprint a finished fit of this run on ``splits`` records, when the run may
    reuse one."""
    data = ModelData(splits, splits, feature_context(splits.train), baseline=baseline)
    return FitKeys.of(config, data, warm_start).record


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
    output_dir = config.output_dir
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
    return RunResult(
        document, record["val_mse"], config.scoring.evaluate(model, data, window), model,
        window,        record["improved"], record["refit_validation"], rejected_refit,
    )


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
    evaluation = config.scoring.evaluate(trained.model, data, window)
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
            rejected, trained, data, window, config.scoring, units, config.model_name)
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


def _score_rejected_refit(
    model: torch.nn.Module,
    trained: TrainResult,
    data: DatasetSplits,
    window: WindowSpec,
    scoring: Scoring,
    units: dict[str, str],
    model_name: str,
) -> dict[str, Any]:
    """Test metrics of a refit that lost to its start on validation (``model``, holding the
    refit's weights, scored without a progress bar), so that a report can show what it
    would have done."""
    quiet = dataclasses.replace(scoring, progress=False)
    evaluation = quiet.evaluate(model.eval(), data, window)
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
