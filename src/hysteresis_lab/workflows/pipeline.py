"""Train-and-evaluate runs of one model (the study's four: `hysteresis_lab.workflows.paper`).

`run_model` on a `RunConfig` (its configs made objects once, where the run starts) prepares
the data, then reuses a finished fit, or trains one (`hysteresis_lab.workflows.grow.train_model`)
and saves, scores and writes it (`hysteresis_lab.workflows.run_report.report_run`); each step
is one call.

Everything a run produces lands in its output folder: checkpoints, ``metrics.json``,
hysteresis-loop and residual figures, and TensorBoard event files (loss curves, figures,
final metrics as hparams).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
from lightning.pytorch.loggers import TensorBoardLogger

from hysteresis_lab import fit_record
from hysteresis_lab.data.checks import warn_weak_excitation
from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.registry import check_effects
from hysteresis_lab.fitting import check_trainer_settings
from hysteresis_lab.models.augment import Baseline, ModelData, feature_context
from hysteresis_lab.models.io import baseline_of
from hysteresis_lab.run_config import RunConfig, RunResult, RunSettings, plain_dict
from hysteresis_lab.run_folder import RunFolder
from hysteresis_lab.workflows.grow import train_model
from hysteresis_lab.workflows.run_report import report_run, reuse_finished_fit

__all__ = ["RunConfig", "RunResult", "RunSettings", "plain_dict", "prepare_data", "run_model",
           "train_from_config"]


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
    reused = reuse_finished_fit(config, keys.record, data.inputs)
    if reused is not None:
        return reused
    return _train_and_report(config, data, warm_start, callbacks, keys)


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


def _train_and_report(
    config: RunConfig,
    data: ModelData,
    warm_start: Any | None,
    callbacks: list[Any] | None,
    keys: FitKeys,
) -> RunResult:
    """Train the model (`train_model`), then save, score and write it (`report_run`), the
    run folder marked as holding an unfinished fit meanwhile (`RunFolder.claim_fit`)."""
    logger = _tensorboard_logger(config)
    # this fit overwrites the folder's files: an older record must not vouch for them
    fit_record.forget(config.output_dir)
    folder = RunFolder(config.output_dir)
    # a network fit may go on from an interrupted one; the others fit in one step
    resume = config.model.is_network and folder.claim_fit(keys.resume, config.settings.resume)
    try:
        trained, window = train_model(config, data, warm_start, logger, callbacks, resume)
        result = report_run(config, data.inputs, trained, window, logger, keys.record)
    except Exception:  # an error, not an interruption: a rerun starts afresh
        folder.finish_fit()
        raise
    folder.finish_fit()
    return result


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
    if settings.keep_last:  # only then: the records of runs without it stay valid
        fingerprinted["keep_last"] = True
    if baseline is not None:  # only then: the records of runs without one stay valid
        fingerprinted["baseline"] = baseline.digest
    return fingerprinted


def _tensorboard_logger(config: RunConfig) -> TensorBoardLogger | None:
    if not config.settings.use_tensorboard:
        return None
    return TensorBoardLogger(
        save_dir=str(config.output_dir), name=RunFolder.TENSORBOARD, version="",
        default_hp_metric=False,
    )
