"""The loop's choices are cross-validated on folds of the identification record, and what
the folds chose is refitted on all of it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.loop.crossval import FoldsCheck, HeldOut, diverges, keep_refit
from hysteresis_lab.loop.data import cross_validation_folds, loop_data
from hysteresis_lab.loop.driver import LoopSettings, run_loop
from hysteresis_lab.workflows.pipeline import RunConfig, run_model
from lowpass import clipped_lowpass

TRAINER = TrainerSettings(max_epochs=3, accelerator="cpu", devices=1, enable_progress_bar=False,
                          enable_model_summary=False)


def _splits(n_train: int = 1200, train: int = 1) -> DatasetSplits:
    records = [clipped_lowpass(n_train, 1 + i, f"train{i}") for i in range(train)]
    return DatasetSplits("lowpass", train=records, test=[clipped_lowpass(600, 9, "test")])


def _fold(losses: list[float], diverging: tuple[str, ...] = ()) -> FoldsCheck:
    """Three folds of 100 held-out samples each with these losses."""
    return FoldsCheck([HeldOut(loss, {}, list(diverging) if j == 0 else [], [], 100)
                       for j, loss in enumerate(losses)])


def test_a_fold_that_diverges_vetoes_a_refit():
    """Better everywhere it is scored, but its free run leaves the output range on one
    fold: the refit does not stand."""
    standing = _fold([1.0, 1.0, 1.0])
    kept, reason = keep_refit(_fold([0.2, 0.2, 0.2], diverging=("train0",)), standing, 0.0)
    assert not kept and "diverges on train0 (fold 0)" in reason
    assert keep_refit(_fold([0.2, 0.2, 0.2]), standing, 0.0)[0]
    trained_badly = FoldsCheck([None, *_fold([0.2, 0.2]).folds])  # a fold's fit diverged
    assert not keep_refit(trained_badly, _fold([1.0, 1.0, 1.0]), 0.0)[0]


def test_an_effect_that_helps_one_held_out_stretch_and_hurts_the_others_is_not_kept():
    """One fold's loss falls a lot and pulls the pooled loss below the standing model's; the
    two other folds get worse: no majority, the refit is dropped."""
    standing = _fold([1.0, 1.0, 1.0])
    one_sided = _fold([0.1, 1.2, 1.2])
    assert one_sided.loss < standing.loss  # the pooled loss alone would keep it
    kept, reason = keep_refit(one_sided, standing, 0.0)
    assert not kept and "lower on 1 of 3 folds (no majority)" in reason
    assert keep_refit(_fold([0.8, 0.9, 1.2]), standing, 0.0)[0]  # two of three, pooled lower
    assert not keep_refit(_fold([0.9, 0.95, 1.3]), standing, 0.0)[0]  # pooled higher


def test_a_refit_that_beats_the_standing_model_but_not_the_start_is_not_kept():
    """Each kept round beat the one before on a majority of folds, yet a chain of them can
    end worse than the start on most folds: the refit must beat the start too."""
    start = _fold([1.0, 1.0, 1.0])
    standing = _fold([0.2, 1.05, 1.05])  # kept: pooled lower, better on one ... (a majority
    refit = _fold([0.15, 1.02, 1.02])  # of two folds over the start fails here)
    assert keep_refit(refit, standing, 0.0)[0]
    kept, reason = keep_refit(refit, standing, 0.0, start=start)
    assert not kept and "against the start" in reason
    assert keep_refit(_fold([0.15, 0.9, 1.02]), standing, 0.0, start=start)[0]


def test_the_pooled_loss_weighs_folds_by_their_held_out_samples():
    check = FoldsCheck([HeldOut(1.0, {}, [], [], 300), HeldOut(0.0, {}, [], [], 100)])
    assert check.loss == pytest.approx(0.75)
    assert FoldsCheck([None, HeldOut(0.0, {}, [], [], 100)]).loss == float("inf")


def test_a_free_run_that_leaves_the_output_range_diverges():
    y = np.sin(np.linspace(0, 10, 200))[:, None]
    assert not diverges(y, 1.5 * y)
    assert diverges(y, y + 30.0)
    assert diverges(y, np.where(np.arange(200)[:, None] == 5, np.nan, y))


def test_one_recording_is_cut_into_contiguous_blocks_each_held_out_once():
    fit = _splits(n_train=1200)
    folds = cross_validation_folds(fit, 3)
    assert [(s.start, s.stop) for f in folds for s in f.held_out] == [
        (0, 400), (400, 800), (800, 1200)]
    assert all(s.recording.n_samples == 1200 for f in folds for s in f.held_out)  # end to end
    middle = folds[1].fit.train
    assert [r.name for r in middle] == ["train0[0:400]", "train0[800:1200]"]
    assert np.array_equal(middle[1].y, fit.train[0].y[800:])
    for fold in folds:  # every fold trains on the rest, and on nothing it holds out
        assert sum(r.n_samples for r in fold.fit.train) == 800
    with pytest.raises(DataError, match="loop.folds"):
        cross_validation_folds(_splits(n_train=100), 3)
    with pytest.raises(ConfigError, match="at least 2"):
        cross_validation_folds(fit, 1)


def test_several_recordings_are_held_out_whole():
    folds = cross_validation_folds(_splits(n_train=300, train=4), 2)
    assert [[s.describe() for s in f.held_out] for f in folds] == [
        ["train0", "train2"], ["train1", "train3"]]
    assert [[r.name for r in f.fit.train] for f in folds] == [
        ["train1", "train3"], ["train0", "train2"]]


def test_the_identification_record_is_the_training_and_validation_recordings():
    splits = dataclasses.replace(_splits(), val=[clipped_lowpass(900, 5, "val")])
    data = loop_data(splits, DataSpec.from_config({}), folds=2)
    assert [r.name for r in data.fit.train] == ["train0", "val"] and not data.fit.val
    assert data.diagnosis == data.validation
    assert data.roles()["folds"] == ["train0", "val"]
    with pytest.raises(ConfigError, match="an identification recording"):
        loop_data(splits, DataSpec.from_config({"diagnose": ["val"]}), folds=2)


def test_the_result_is_refitted_on_every_identification_sample(tmp_path):
    """The round's model (reported, saved) is the fit on the whole identification record:
    it scores exactly as that fit does, and not as any fold's."""
    splits = _splits(n_train=1200)
    model = {"name": "linear", "order": 2, "effects": [], "lr": 0.01}
    data_spec = DataSpec.from_config({"name": "lowpass", "scaling": {"mode": "standard"}})
    report = run_loop(model, data_spec, TRAINER, splits, tmp_path / "loop",
                      LoopSettings(max_rounds=0, folds=3), use_tensorboard=False, plots=False)
    start = report["rounds"][0]
    fitted = start["fitted_on"]
    assert (fitted["samples"], fitted["recordings"]) == (1200, ["train0"])
    assert start["chosen_on"]["folds"] == 3
    assert start["chosen_on"]["samples"] == [800, 800, 800]
    data = {"name": "lowpass", "scaling": {"mode": "standard"}}
    length = fitted["training_length"]["epochs"]["simulation"]

    def fit_on(fit: DatasetSplits, folder: str, keep_last: bool = False) -> float:
        config = RunConfig.build(model, data, TRAINER.with_changes(max_epochs=length),
                                 tmp_path / folder, seed=0, use_tensorboard=False, plots=False)
        config = dataclasses.replace(
            config, settings=dataclasses.replace(config.settings, keep_last=keep_last))
        return run_model(config, splits=fit).document["mean"]["rmse_free_run"]

    whole = loop_data(splits, data_spec, 3).whole
    assert start["mean_rmse_free_run"] == pytest.approx(fit_on(whole, "whole", True), rel=1e-9)
    fold = loop_data(splits, data_spec, 3).folds[0].fit
    assert start["mean_rmse_free_run"] != pytest.approx(fit_on(fold, "fold"), rel=1e-6)


def test_two_confounded_effects_are_both_refitted_and_the_folds_keep_the_better(tmp_path):
    """The clipped low-pass's residual names overflow and other significant effects within
    the margin: each is refitted on every fold, the report lists each with its folds' numbers,
    and the round keeps the one with the lowest pooled held-out loss."""
    model = {"name": "linear", "order": 2, "effects": [], "lr": 0.01}
    data_spec = DataSpec.from_config({"name": "lowpass", "scaling": {"mode": "standard"}})
    settings = LoopSettings(max_rounds=1, folds=3, refit_lr_factors=(1.0,),
                            confounded_margin=0.99, max_alternatives=2, alpha=0.2)
    report = run_loop(model, data_spec, TRAINER, _splits(n_train=1500), tmp_path, settings,
                      use_tensorboard=False, plots=False)
    start, refit = report["rounds"][:2]
    assert len(start["alternatives"]) == 1
    compared = refit["compared"]
    assert [c["effect"] for c in compared] != [] and len(compared) == 2
    assert {c["effect"] for c in compared} == {start["added"], *start["alternatives"]}
    assert compared[0]["held_out_loss"] <= compared[1]["held_out_loss"]
    assert refit["decision"]["effect"] == compared[0]["effect"]
    for c in compared:  # each fitted on every fold, in its own folder
        assert len(c["fold_losses"]) == 3 and all(np.isfinite(c["fold_losses"]))
        assert list((tmp_path / "round_1" / c["effect"]).rglob("fold_2"))
    # every refit candidate names the effect it adds: the alternatives' are told apart
    assert {c["effect"] for c in refit["refit_candidates"]} == {c["effect"] for c in compared}
    page = (tmp_path / "loop_report.md").read_text()
    assert "each refitted on the folds" in page


def test_confounded_effects_are_those_within_the_margin_of_the_top_score():
    from hysteresis_lab.loop.diagnosis.ranking import EffectScore
    from hysteresis_lab.loop.driver import confounded

    scores = [EffectScore("overflow", 0.95, 1e-6, True, ""),
              EffectScore("saturation", 0.88, 1e-6, True, ""),
              EffectScore("rate", 0.80, 1e-6, True, ""),
              EffectScore("creep", 0.50, 1e-6, True, ""),
              EffectScore("dead_zone", 0.90, 0.5, False, "")]
    assert confounded(scores, scores[0], set(), 0.2, 3) == ["overflow", "saturation", "rate"]
    assert confounded(scores, scores[0], {"saturation"}, 0.1, 3) == ["overflow"]
    assert confounded(scores, scores[0], set(), 0.2, 2) == ["overflow", "saturation"]
