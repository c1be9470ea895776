"""`pipeline.run_model` on a `RunConfig`: one run's steps, in process."""

from __future__ import annotations

import json

from hysteresis_lab import fit_record
from hysteresis_lab.run_folder import RunFolder
from hysteresis_lab.workflows.pipeline import RunConfig, RunSettings, run_model, train_and_evaluate
from narx import CONFIGS, TRAINER, narx_data

DATA = {"window": {"na": 2, "nb": 2, "nk": 1}, "scaling": {"mode": "standard"}}


def test_a_run_scores_writes_its_folder_and_is_reused_with_the_same_settings(tmp_path, caplog):
    splits = narx_data(600)
    settings = RunSettings(seed=3, use_tensorboard=False, plots=False, reuse=True)
    config = RunConfig(dict(CONFIGS["ffnn"]), DATA, {**TRAINER, "max_epochs": 2},
                       tmp_path / "run", settings)
    result = run_model(config, splits=splits)
    folder = RunFolder(tmp_path / "run")
    written = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert written == result.document == folder.read_metrics()
    assert set(written["tests"]) == {"sine1.0", "sine3.0"}
    assert folder.model_file() == tmp_path / "run" / "model.ckpt"
    assert (tmp_path / "run" / fit_record.FIT_RECORD).is_file() and folder.fit_record.is_file()
    # the keyword form is the same run: its finished fit is found and scored again
    saved = (tmp_path / "run" / "model.ckpt").stat().st_mtime_ns
    caplog.set_level("INFO", logger="hysteresis_lab.workflows.pipeline")
    again = train_and_evaluate(
        dict(CONFIGS["ffnn"]), DATA, {**TRAINER, "max_epochs": 2}, tmp_path / "run", seed=3,
        splits=splits, use_tensorboard=False, plots=False, reuse=True,
    )
    assert again.document == result.document and again.val_mse == result.val_mse
    assert "reusing the finished fit" in caplog.text
    assert (tmp_path / "run" / "model.ckpt").stat().st_mtime_ns == saved


def test_a_run_without_evaluation_reports_its_validation_loss_only(tmp_path):
    config = RunConfig(dict(CONFIGS["svm"]), DATA, TRAINER, tmp_path,
                       RunSettings(use_tensorboard=False, evaluate=False))
    result = run_model(config, splits=narx_data(600))
    assert set(result.document) == {"model", "data", "val_mse_scaled", "train_seconds"}
    assert result.document["val_mse_scaled"] == result.val_mse < 1.0
    assert not result.evaluation.predictions


def test_a_losing_refit_is_set_aside_under_the_run_folders_rejected_names(tmp_path):
    config = RunConfig(dict(CONFIGS["svm"]), DATA, TRAINER, tmp_path / "run",
                       RunSettings(use_tensorboard=False, plots=False))
    run_model(config, splits=narx_data(600))
    folder = RunFolder(tmp_path / "run")
    model_file, scores = folder.model_file(), folder.read_metrics()
    assert model_file is not None and model_file.suffix == ".skops"
    aside = folder.set_model_aside_as_rejected(model_file)
    assert aside == folder.rejected_refit_model_file()
    assert aside == tmp_path / "run" / "rejected_refit_model.skops"
    assert folder.model_file() is None and not folder.metrics.exists()
    assert folder.read_rejected_refit_metrics() == scores
