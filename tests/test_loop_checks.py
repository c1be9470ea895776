"""A loop run's refits scored on sines between the test frequencies
(hysteresis_lab.analysis.loop_checks, printed by experiments/refit_choice.py)."""

from __future__ import annotations

import json

import pytest

from helpers import run_app
from hysteresis_lab.analysis.loop_checks import check_splits, refit_choices
from hysteresis_lab.errors import ConfigError

#: a small simulator run: a short multisine, two short test sines
SMALL_DEFAULT = ["data=default", "+data.splits.n_train=4000", "+data.splits.max_test_samples=3000",
                 "+data.splits.test_frequencies=[10,50]"]


@pytest.mark.slow
def test_refit_choice_scores_the_start_and_every_refit(tmp_path):
    """Every refit is rejected (no refit takes 99 % off): the check scores the start and each
    rate's own saved weights on the check sines and names the one they prefer."""
    run = tmp_path / "loop"
    proc = run_app("loop", *SMALL_DEFAULT, "model=ffnn", "loop.max_rounds=1",
                   "loop.min_refit_gain=0.99", "trainer.max_epochs=2", "model.simulation_epochs=1",
                   "trainer.enable_progress_bar=false", "logger=none", f"hydra.run.dir={run}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    rounds = json.loads((run / "loop_report.json").read_text())["rounds"]
    # the simulator's hysteresis is undeclared: round 0 finds it (and more), so there are
    # refits to score, each rejected by the 99 % rule
    assert rounds[0]["added"] == "hysteresis"
    significant = [d["effect"] for d in rounds[0]["diagnosis"] if d["significant"]]
    assert [r["rejected"] for r in rounds[1:]] == significant
    results = refit_choices(run, [20.0, 70.0])
    assert len(results) == len(significant) >= 1
    assert [r["round"] for r in results] == list(range(1, len(rounds)))
    for result, entry in zip(results, rounds[1:], strict=True):
        start, *refits = result["candidates"]
        assert start["refit_lr"] is None and start["kept"]  # every refit was rejected
        assert result["loop_keeps"] is None
        assert [c["refit_lr"] for c in refits] == [c["refit_lr"] for c in entry["refit_candidates"]]
        assert all(c["model"].name == "rejected_refit_model.ckpt" for c in refits)
        for candidate in result["candidates"]:
            assert list(candidate["check_rmse"]) == ["sine_20Hz", "sine_70Hz"]
        # the refits' own weights, not the start's they lost to
        assert all(c["check_rmse"] != start["check_rmse"] for c in refits)
        best = min(result["candidates"], key=lambda c: c["check_mean"])
        assert result["check_prefers"] == best["refit_lr"]


def test_refit_choice_refuses_training_sines_and_measured_data():
    simulator = {"effects": {}, "splits": {
        "_target_": "hysteresis_lab.sim.default_dataset.make_default_dataset",
        "train_sines": [30.0]}}
    with pytest.raises(ConfigError, match="training sines"):
        check_splits(simulator, [30.0, 70.0])
    with pytest.raises(ConfigError, match="simulator"):
        check_splits({"splits": {}}, [30.0])
