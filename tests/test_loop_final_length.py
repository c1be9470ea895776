"""The loop's final refit on the whole identification record trains for the epochs the
folds' fits needed (their median best epoch), on every identification sample, and keeps
its last weights."""

from __future__ import annotations

import json
import math

import numpy as np

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import WindowSpec, make_windows
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.loop.data import loop_data
from hysteresis_lab.loop.driver import LoopSettings, run_loop
from hysteresis_lab.loop.length import final_length
from lowpass import clipped_lowpass

EPOCHS = 6
TRAINER = TrainerSettings(max_epochs=EPOCHS, accelerator="cpu", devices=1,
                          enable_progress_bar=False, enable_model_summary=False)
MODEL = {"name": "linear", "order": 2, "effects": [], "lr": 0.01}
DATA = DataSpec.from_config({"name": "lowpass", "scaling": {"mode": "standard"}})


def _splits() -> DatasetSplits:
    return DatasetSplits("lowpass", train=[clipped_lowpass(1200, 1, "train0")],
                         test=[clipped_lowpass(600, 9, "test")])


def _trained_epochs(folder) -> dict[str, int]:
    return json.loads((folder / "metrics.json").read_text())["trained_epochs"]


def test_the_final_refit_trains_the_folds_median_best_epoch(tmp_path):
    """Each fold's fit records the epoch its best checkpoint (on a random share of its
    training part) came from; the whole-record refit trains the median of those, not
    trainer.max_epochs, and the report says so and where it came from. Run again in its
    folder, the loop reuses it."""
    folder = tmp_path / "loop"
    report = run_loop(MODEL, DATA, TRAINER, _splits(), folder,
                      LoopSettings(max_rounds=0, folds=3), use_tensorboard=False, plots=False)
    best = [_trained_epochs(folder / "round_0" / f"fold_{j}")["simulation"] for j in range(3)]
    median = max(1, math.ceil(float(np.median(best))))
    assert median < EPOCHS, f"the folds' best epochs {best} do not test the length"
    length = report["rounds"][0]["fitted_on"]["training_length"]
    assert length["source"] == "folds' median best epoch"
    assert length["fold_best_epochs"] == {"simulation": best}
    assert length["epochs"] == {"simulation": median}
    assert _trained_epochs(folder / "round_0") == {"simulation": median}
    page = (folder / "loop_report.md").read_text()
    assert f"simulation {median} epoch" in page and "median best epoch" in page

    again = run_loop(MODEL, DATA, TRAINER, _splits(), folder,
                     LoopSettings(max_rounds=0, folds=3), use_tensorboard=False, plots=False)
    assert again["rounds"][0]["mean_rmse_free_run"] == report["rounds"][0]["mean_rmse_free_run"]
    assert again["rounds"][0]["fitted_on"] == report["rounds"][0]["fitted_on"]


def test_the_final_refit_uses_every_identification_sample(tmp_path):
    """The whole-record refit's data hold no validation share out of training: a window
    model trains on every window of every identification recording (with no validation
    recordings the data module would otherwise set a random tenth aside)."""
    splits = DatasetSplits("lowpass", train=[clipped_lowpass(900, 1, "a")],
                           val=[clipped_lowpass(700, 2, "b")],
                           test=[clipped_lowpass(600, 9, "test")])
    data = loop_data(splits, DATA, 3)
    window = WindowSpec(na=2, nb=2, nk=0)
    module = WindowDataModule(data.whole, window)
    module.setup()
    every = len(make_windows([*splits.train, *splits.val], window))
    assert len(module.train_windows) == every
    assert sum(r.n_samples for r in data.whole.train) == 1600
    # a fold chooses its epoch on a random share of its own training part: what it holds
    # out (which judges it) is neither trained on nor validated on
    for fold in data.folds:
        assert fold.fit.val == []
        trained = sum(r.n_samples for r in fold.fit.train)
        held = sum(s.stop - s.start for s in fold.held_out)
        assert trained + held == 1600


def test_the_length_is_the_median_within_one_and_the_configured_length():
    """The median best epoch, rounded up, at least 1 and at most the configured length; a
    fold without recorded epochs leaves the configured length."""
    configured = {"one_step": 10, "simulation": 10, "fine_tune": 5}
    docs = [{"trained_epochs": {"one_step": e, "fine_tune": f}}
            for e, f in ((3, 0), (8, 0), (4, 9))]
    length = final_length(docs, configured)
    assert length.epochs == {"one_step": 4, "fine_tune": 1}
    assert length.folds == {"one_step": [3, 8, 4], "fine_tune": [0, 0, 9]}
    assert list(length.epochs) == ["one_step", "fine_tune"]  # in training order, every run
    two = final_length([{"trained_epochs": {"simulation": e}} for e in (2, 5)], configured)
    assert two.epochs == {"simulation": 4}
    assert final_length([*docs[:2], None], configured).epochs == {}
    assert final_length([*docs[:2], {}], configured).to_dict()["source"] == "configured"
