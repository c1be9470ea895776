"""Checks of a loop run against the simulator (hysteresis_lab.loop.checks, printed by
experiments/refit_choice.py and experiments/effect_ceiling.py): the refits scored on sines
between the test frequencies, and an effect's share of the free-run error."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from hysteresis_lab.cli.loop import run_fresh_loop
from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.evaluate import scoring_start
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.loop.checks import (
    ceiling,
    check_splits,
    refit_choices,
    round_model,
    run_data_config,
)
from hysteresis_lab.models.augment import for_model
from hysteresis_lab.models.io import load_model
from hysteresis_lab.sim.positioner import Positioner

#: a small simulator run: a short multisine, two short test sines
SMALL_DEFAULT = ["data=default", "+data.splits.n_train=4000", "+data.splits.max_test_samples=3000",
                 "+data.splits.test_frequencies=[10,50]"]


@pytest.fixture(scope="module")
def loop_run(tmp_path_factory) -> Path:
    """A one-round FFNN loop on the small simulator whose every refit is rejected (no refit
    takes 99 % off), run by `run_fresh_loop` into a folder holding an older run's file."""
    run = tmp_path_factory.mktemp("loop_checks") / "loop"
    run.mkdir()
    (run / "stale.txt").write_text("an older run's file")
    report, seconds = run_fresh_loop(
        [*SMALL_DEFAULT, "model=ffnn", "loop.max_rounds=1", "loop.min_refit_gain=0.99",
         "trainer.max_epochs=2", "model.simulation_epochs=1",
         "trainer.enable_progress_bar=false", "logger=none", "plots=false"], run)
    assert not (run / "stale.txt").exists()  # a fresh folder: no fit of an older run reused
    assert report == json.loads((run / "loop_report.json").read_text()) and seconds > 0
    return run


def test_a_loop_run_that_fails_says_why(tmp_path):
    with pytest.raises(RuntimeError,
                       match="(?s)model=transformer failed:.*unknown model 'transformer'"):
        run_fresh_loop(["model=transformer"], tmp_path / "loop")


def test_the_commit_stamp_marks_changed_code_but_not_the_measured_tables(tmp_path):
    assert commit_stamp(tmp_path) == "unknown"  # not a git checkout
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    (tmp_path / "docs" / "results").mkdir(parents=True)
    (tmp_path / "src").mkdir()
    for path in ("src/code.py", "docs/results/table.md", "README.md"):
        (tmp_path / path).write_text("one\n")
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "."], check=True)
    subprocess.run([*git, "commit", "-qm", "first"], check=True)
    head = subprocess.run([*git, "rev-parse", "--short", "HEAD"], check=True,
                          capture_output=True, text=True).stdout.strip()
    assert commit_stamp(tmp_path) == head
    (tmp_path / "docs" / "results" / "table.md").write_text("two\n")  # what the scripts write
    assert commit_stamp(tmp_path) == head
    (tmp_path / "README.md").write_text("two\n")
    assert commit_stamp(tmp_path) == f"{head}+dirty"
    assert commit_stamp(tmp_path, ("src",)) == head  # only src/ counts here
    (tmp_path / "src" / "code.py").write_text("two\n")
    assert commit_stamp(tmp_path, ("src",)) == f"{head}+dirty"


@pytest.mark.slow
def test_refit_choice_scores_the_start_and_every_refit(loop_run):
    """The check scores the start and each rate's own saved weights on the check sines and
    names the one they prefer."""
    run = loop_run
    rounds = json.loads((run / "loop_report.json").read_text())["rounds"]
    # the simulator's hysteresis is undeclared: round 0 finds it (and more), so there are
    # refits to score, each rejected by the 99 % rule
    assert rounds[0]["added"] == "hysteresis"
    # (a significant effect the network cannot carry, the output's overflow, gets no round)
    held_back = {h["effect"] for h in rounds[0].get("not_added_under_excited", [])}
    significant = [d["effect"] for d in rounds[0]["diagnosis"] if d["significant"]
                   and d["effect"] not in [*rounds[0].get("not_carried", []), *held_back]]
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


@pytest.mark.slow
def test_ceiling_scores_round_0_and_the_effects_own_output(loop_run):
    """Round 0's free-run RMSE as the loop scored it; the simulator's hysteresis (undeclared)
    acts on every test; its size and share of the residual are those of its own output."""
    scored = json.loads((loop_run / "round_0" / "metrics.json").read_text())["tests"]
    rows = ceiling(loop_run, "hysteresis", 0, clip_input=50.0)
    assert [row["test"] for row in rows] == list(scored) == ["sine_10Hz", "sine_50Hz"]
    # the round's residual e and the hysteresis' own output d, rebuilt here: d from the
    # simulator run noise-free with the block on and off on each test input
    data_cfg = run_data_config(loop_run)
    splits = build_splits(data_cfg)
    model = load_model(round_model(loop_run, 0))
    predictions = free_run(model, for_model(model, splits.test), model.window)
    skip = scoring_start(model.window, splits.n_init)
    quiet = {**data_cfg["effects"], "noise": {"enabled": False},
             "quantisation": {"enabled": False}}
    switched = [{**quiet, "hysteresis": {**quiet["hysteresis"], "enabled": on}}
                for on in (True, False)]
    for row, rec, prediction in zip(rows, splits.test, predictions, strict=True):
        assert row["rmse_free_run"] == pytest.approx(scored[row["test"]]["rmse_free_run"],
                                                     rel=1e-5)
        on, off = (Positioner(effects).simulate(rec.u[:, 0], rec.fs) for effects in switched)
        d = on - off
        assert row["effect_size_um"] == pytest.approx(np.sqrt(np.mean(d**2)), rel=1e-6)
        assert row["effect_size_um"] > 0.05  # the hysteresis acts on this test
        e, d = (rec.y - prediction)[skip:, 0], d[skip:]
        e, d = e - e.mean(), d - d.mean()
        assert row["effect_rms"] == pytest.approx(np.sqrt(np.mean(d**2)), rel=1e-6)
        # subtracting the best multiple of d cuts the residual by max_cut_pct, and the
        # correlation's sign is that multiple's
        best = (e @ d) / (d @ d)
        cut = 1 - np.linalg.norm(e - best * d) / np.linalg.norm(e)
        assert row["max_cut_pct"] == pytest.approx(100 * cut, rel=1e-6, abs=1e-9)
        assert np.sign(row["corr"]) == np.sign(best) != 0
        # the same model on inputs clipped at 50 V (of 100 V) is scored, and differs
        assert row["rmse_clipped_input"] != row["rmse_free_run"]
    with pytest.raises(ConfigError, match="unknown simulator block"):
        ceiling(loop_run, "no_such_block", 0)


def test_refit_choice_refuses_training_sines_and_measured_data():
    simulator = {"effects": {}, "splits": {
        "_target_": "hysteresis_lab.sim.default_dataset.make_default_dataset",
        "train_sines": [30.0], "val_sines": [3.2]}}
    with pytest.raises(ConfigError, match=r"\[30.0\] Hz are training or validation sines"):
        check_splits(simulator, [30.0, 70.0])
    with pytest.raises(ConfigError, match=r"\[3.2\] Hz are training or validation sines"):
        check_splits(simulator, [3.2, 70.0])
    with pytest.raises(ConfigError, match="simulator"):
        check_splits({"splits": {}}, [30.0])
