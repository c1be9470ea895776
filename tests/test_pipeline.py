"""`pipeline.run_model` on a `RunConfig`: one run's steps, in process."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import replace
from pathlib import Path

import pytest

import hysteresis_lab as hl
from hysteresis_lab import fit_record
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.run_folder import RunFolder
from hysteresis_lab.workflows.pipeline import (
    RunConfig,
    RunSettings,
    _fit_record_key,
    plain_dict,
    run_model,
)
from narx import CONFIGS, TRAINER, narx_data

DATA = {"window": {"na": 2, "nb": 2, "nk": 1}, "scaling": {"mode": "standard"}}


def test_a_run_scores_writes_its_folder_and_is_reused_with_the_same_settings(tmp_path, caplog):
    splits = narx_data(600)
    settings = RunSettings(seed=3, use_tensorboard=False, plots=False, reuse=True)
    config = RunConfig.build(dict(CONFIGS["ffnn"]), DATA, TRAINER.with_changes(max_epochs=2),
                             tmp_path / "run", **dataclasses.asdict(settings))
    result = run_model(config, splits=splits)
    folder = RunFolder(tmp_path / "run")
    written = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert written == result.document == folder.read_metrics()
    assert set(written["tests"]) == {"sine1.0", "sine3.0"}
    assert folder.model_file() == tmp_path / "run" / "model.ckpt"
    assert (tmp_path / "run" / fit_record.FIT_RECORD).is_file() and folder.fit_record.is_file()
    # the same run built again from its objects: its finished fit is found and scored again
    saved = (tmp_path / "run" / "model.ckpt").stat().st_mtime_ns
    caplog.set_level("INFO", logger="hysteresis_lab.workflows.run_report")
    again = run_model(RunConfig(config.model, DataSpec.from_config(DATA), config.trainer,
                                tmp_path / "run", settings, config.training), splits=splits)
    assert again.document == result.document and again.val_mse == result.val_mse
    assert "reusing the finished fit" in caplog.text
    assert (tmp_path / "run" / "model.ckpt").stat().st_mtime_ns == saved


class _Killed(BaseException):
    """A process stopped where it stands: no ``except Exception`` clean-up runs."""


def test_a_run_stopped_once_its_fit_is_recorded_leaves_nothing_to_resume(tmp_path, monkeypatch):
    """Stopped right after the fit record is written, a run leaves no ``last.ckpt`` or
    unfinished-fit mark beside it: a rerun that cannot load the recorded model trains afresh
    to the same model, not "resumes" a finished stage (nothing left to train, its weights
    lost)."""
    splits = narx_data(600)
    settings = RunSettings(seed=3, use_tensorboard=False, plots=False, reuse=True, resume=True)
    trainer = TRAINER.with_changes(max_epochs=2)

    def config(name):
        return RunConfig.build(dict(CONFIGS["ffnn"]), DATA, trainer, tmp_path / name,
                               **dataclasses.asdict(settings))

    expected = run_model(config("whole"), splits=splits).document
    written = fit_record.write_record

    def write_then_stop(*args, **kwargs):
        written(*args, **kwargs)
        raise _Killed

    monkeypatch.setattr(fit_record, "write_record", write_then_stop)
    with pytest.raises(_Killed):
        run_model(config("stopped"), splits=splits)
    monkeypatch.undo()
    folder = RunFolder(tmp_path / "stopped")
    assert folder.fit_record.is_file()
    assert folder.last_checkpoints() == [] and not folder.fit_in_progress.exists()
    model = folder.model_file()
    model.write_bytes(model.read_bytes()[:100])  # damaged since: the record cannot be reused
    again = run_model(config("stopped"), splits=splits).document
    assert again["tests"] == expected["tests"]


def test_a_run_without_evaluation_reports_its_validation_loss_only(tmp_path):
    config = RunConfig.build(dict(CONFIGS["svm"]), DATA, TRAINER, tmp_path,
                             use_tensorboard=False, evaluate=False)
    result = run_model(config, splits=narx_data(600))
    assert set(result.document) == {"model", "data", "val_mse_scaled", "train_seconds"}
    assert result.document["val_mse_scaled"] == result.val_mse < 1.0
    assert not result.evaluation.predictions


def test_a_losing_refit_is_set_aside_under_the_run_folders_rejected_names(tmp_path):
    config = RunConfig.build(dict(CONFIGS["svm"]), DATA, TRAINER, tmp_path / "run",
                             use_tensorboard=False, plots=False)
    run_model(config, splits=narx_data(600))
    folder = RunFolder(tmp_path / "run")
    model_file, scores = folder.model_file(), folder.read_metrics()
    assert model_file is not None and model_file.suffix == ".skops"
    aside = folder.set_model_aside_as_rejected(model_file)
    assert aside == folder.rejected_refit_model_file()
    assert aside == tmp_path / "run" / "rejected_refit_model.skops"
    assert folder.model_file() is None and not folder.metrics.exists()
    assert folder.read_rejected_refit_metrics() == scores


def test_a_fit_record_of_the_dict_configs_is_recognised_from_the_typed_ones():
    """Fit records fingerprint the ``data`` and ``trainer`` configs; the run holds them as a
    `DataSpec` and `TrainerSettings` now, whose ``to_config`` must give the same digest as
    the resolved config dicts the runs hashed before (else a resumed run would refit)."""
    cfg = hl.compose("experiment=paper", "trainer.max_epochs=2", "+trainer.num_sanity_val_steps=0")
    splits = narx_data(600)
    model = dict(CONFIGS["ffnn"])
    settings = RunSettings(seed=1, reuse=True)
    data, trainer = plain_dict(cfg.data), plain_dict(cfg.trainer)
    as_dicts = {"model": model, "data": data, "trainer": trainer, "seed": 1, "n_steps": None,
                "refit": None, "min_refit_gain": 0.0, "training": TrainingSettings().to_dict()}
    config = RunConfig(ModelSpec.from_config(model), DataSpec.from_config(cfg.data),
                       TrainerSettings.from_config(cfg.trainer), Path("unused"), settings)
    assert isinstance(config.trainer, TrainerSettings) and isinstance(config.data, DataSpec)
    assert _fit_record_key(config, splits, None) == fit_record.fingerprint(as_dicts, splits, None)
    # a paper worker turns Lightning's progress bar and summary off in its settings
    quiet = config.trainer.with_changes(enable_progress_bar=False, enable_model_summary=False)
    in_worker = {**trainer, "enable_progress_bar": False, "enable_model_summary": False}
    assert _fit_record_key(replace(config, trainer=quiet), splits, None) == fit_record.fingerprint(
        {**as_dicts, "trainer": in_worker}, splits, None)
    # ...and another setting is another fit
    other = replace(config, trainer=config.trainer.with_changes(max_epochs=3))
    assert _fit_record_key(other, splits, None) != _fit_record_key(config, splits, None)
