"""A stopped loop, run again in its folder, reuses every fit that finished there."""

from __future__ import annotations

import json
import os
import signal
import time

import numpy as np
import pytest
import torch

from helpers import data_overrides, popen_app, run_app, small_dataset
from hysteresis_lab import fit_record
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.models.ffnn import FFNN
from loop_notebook import check_loop_notebook

REUSED = "reusing the finished fit"
FOLDS = 2  # loop.folds: the fewest, for a short test


def _loop_args(tmp_path):
    train, tests = small_dataset(tmp_path, effects={"creep": {"enabled": True}})
    return [
        *data_overrides(train, tests),
        "model=ffnn",
        "loop.max_rounds=1",
        f"loop.folds={FOLDS}",
        "loop.refit_lr_factors=[1.0]",  # one refit rate
        "trainer.max_epochs=3",
        "trainer.enable_progress_bar=false",
        "logger=none",
        "plots=false",  # no figures: the report alone (and the loop is faster)
    ]


def _loop_in(run_dir, *args):
    """Run the loop in ``run_dir``: the process, and the lines it added to the folder's
    ``loop.log`` (each fit's own lines go there; the terminal shows one line per round)."""
    log = run_dir / "loop.log"
    start = log.stat().st_size if log.exists() else 0
    proc = run_app("loop", *args, f"hydra.run.dir={run_dir}")
    return proc, log.read_bytes()[start:].decode() if log.exists() else ""


def _kill_when(path, proc, timeout=300.0):
    """SIGKILL ``proc`` (and its children) as soon as ``path`` exists."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, proc.stdout.read()[-3000:]
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


@pytest.mark.slow
def test_a_killed_loop_resumes_without_retraining_its_finished_fits(tmp_path):
    args = _loop_args(tmp_path)
    whole = run_app("loop", *args, f"hydra.run.dir={tmp_path}/whole")
    assert whole.returncode == 0, whole.stderr[-3000:]
    expected = json.loads((tmp_path / "whole" / "loop_report.json").read_text())
    assert len(expected["rounds"]) == 2  # a refit ran after round 0: the kill lands between
    assert expected["plots"] is False
    check_loop_notebook(tmp_path / "whole")  # plots=false: no figure drawn or linked

    run_dir = tmp_path / "killed"
    killed = popen_app("loop", *args, f"hydra.run.dir={run_dir}")
    _kill_when(run_dir / "round_0" / fit_record.FIT_RECORD, killed)
    assert not (run_dir / "loop_report.json").exists()
    round_0_model = run_dir / "round_0" / "model.ckpt"
    written = round_0_model.stat().st_mtime_ns

    resumed, output = _loop_in(run_dir, *args)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    # round 0 only (each fold's fit, then the whole record's): the refits had not finished
    assert output.count(REUSED) == FOLDS + 1
    assert round_0_model.stat().st_mtime_ns == written  # not trained again
    # the refits started from the reloaded round-0 network: the same report to the digit
    assert json.loads((run_dir / "loop_report.json").read_text()) == expected

    again, output = _loop_in(run_dir, *args)
    assert again.returncode == 0, again.stderr[-3000:]
    fits = list(run_dir.rglob(fit_record.FIT_RECORD))
    kept = not expected["rounds"][1].get("rejected")  # a kept refit is refitted on the whole
    assert len(fits) == FOLDS + 1 + FOLDS + kept  # round 0; the refit on each fold
    assert output.count(REUSED) == len(fits)  # nothing trains
    assert json.loads((run_dir / "loop_report.json").read_text()) == expected

    round_0_model.write_bytes(round_0_model.read_bytes()[:100])  # damaged since
    damaged, output = _loop_in(run_dir, *args)
    assert damaged.returncode == 0, damaged.stderr[-3000:]
    assert "cannot be reused" in damaged.stdout + damaged.stderr  # a warning: on the terminal
    assert "cannot be reused" in output and "checkpoint is corrupt" in output
    # all but round 0's whole-record fit, trained again to the same weights
    assert output.count(REUSED) == len(fits) - 1
    assert json.loads((run_dir / "loop_report.json").read_text()) == expected

    other, output = _loop_in(run_dir, *args, "trainer.max_epochs=2")
    assert other.returncode == 0, other.stderr[-3000:]
    assert REUSED not in output  # other settings: every fit trains
    assert round_0_model.stat().st_mtime_ns != written

    # a run that does not resume overwrites the fits: no older record may vouch for them
    fresh, output = _loop_in(run_dir, *args, "loop.resume=false")
    assert fresh.returncode == 0, fresh.stderr[-3000:]
    assert REUSED not in output
    assert not list(run_dir.rglob(fit_record.FIT_RECORD))


def test_the_fingerprint_changes_with_settings_data_and_start():
    u = np.random.default_rng(0).standard_normal((50, 1))

    def splits(scale=1.0):
        rec = Recording(u=u, y=scale * np.ones((50, 1)), fs=100.0, name="r")
        return DatasetSplits(name="d", train=[rec], test=[rec])

    data = splits()
    start = FFNN(nu=1, ny=1)
    key = fit_record.fingerprint({"lr": 1e-3}, data, start)
    assert key == fit_record.fingerprint({"lr": 1e-3}, data, start)
    assert key != fit_record.fingerprint({"lr": 1e-4}, data, start)
    assert key != fit_record.fingerprint({"lr": 1e-3}, splits(2.0), start)
    assert key != fit_record.fingerprint({"lr": 1e-3}, data, None)
    moved = FFNN(nu=1, ny=1)
    moved.load_state_dict(start.state_dict())
    assert fit_record.fingerprint({"lr": 1e-3}, data, moved) == key  # the weights count
    with torch.no_grad():
        next(moved.parameters())[0, 0] += 1e-6
    assert fit_record.fingerprint({"lr": 1e-3}, data, moved) != key
