"""A run's results in its run folder (`RunFolder`): a trained model saved, scored and written
in one step (`report_run`: ``model.*``, ``metrics.json``, the figures, a losing refit's own
model and scores beside the kept one, the fit record and the TensorBoard summary), or a
finished fit recorded there (`hysteresis_lab.fit_record`) loaded and scored again
(`reuse_finished_fit`)."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch.loggers import TensorBoardLogger

from hysteresis_lab import fit_record
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import DataError
from hysteresis_lab.evaluation.evaluate import Evaluation, Scoring
from hysteresis_lab.evaluation.plots import loops_figure, residuals_figure, save_figure
from hysteresis_lab.evaluation.report import metrics_document
from hysteresis_lab.fitting import TrainResult
from hysteresis_lab.models.io import load_model, model_window, save_model
from hysteresis_lab.run_config import RunConfig, RunResult
from hysteresis_lab.run_folder import RunFolder

log = logging.getLogger(__name__)


def report_run(
    config: RunConfig,
    data: DatasetSplits,
    trained: TrainResult,
    window: WindowSpec,
    logger: TensorBoardLogger | None,
    record_key: str | None,
) -> RunResult:
    """Save the trained model in the run folder; score it on ``data``'s test recordings and
    write its documents (`RunSettings.evaluate`; else its validation loss and cost only);
    with ``record_key``, record the finished fit for a later reuse."""
    folder = RunFolder(config.output_dir)
    model_path = save_model(trained.model, folder.model_stem)
    log.info("saved %s", model_path)
    if not config.settings.evaluate:  # a sweep trial: its validation loss and cost only
        document = {"model": config.model_name, "data": data.name,
                    "val_mse_scaled": trained.val_mse, "train_seconds": trained.train_seconds}
        folder.write_metrics(document)
        return RunResult(document, trained.val_mse, Evaluation(), trained.model, window,
                         trained.improved, trained.refit_validation)
    return _score_and_write(config, data, trained, window, model_path, logger, record_key)


def reuse_finished_fit(
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
        window, record["improved"], record["refit_validation"], rejected_refit,
    )


def _score_and_write(
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
               "initial_state": settings.initial_state, "trained_epochs": trained.epochs,
               **_data_choices(trained.model)},
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


def _data_choices(model: Any) -> dict[str, Any]:
    """The settings the model's class read off the data and why
    (`hysteresis_lab.workflows.grow.settings_from_data`), for ``metrics.json``."""
    choices = getattr(model, "data_choices", None)
    return {"chosen_from_data": choices} if choices else {}


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
    """Record the finished fit (its files and what `RunResult` needs) for a later reuse. Its
    resume state goes first (`RunFolder.finish_fit`): a process stopped between the two
    leaves either nothing to reuse or a record with nothing to resume (a record beside a
    finished stage's ``last.ckpt`` had a rerun that could not reuse the model "resume" that
    stage: nothing left to train, the free-run fine-tuning's weights lost)."""
    RunFolder(output_dir).finish_fit()
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
