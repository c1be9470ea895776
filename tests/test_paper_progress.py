"""``experiment=paper`` on a CPU: the worker processes' progress reaches the terminal as one
labelled line per update (model, epoch, time left), not as interleaved Lightning bars."""

from __future__ import annotations

import re

import pytest

from helpers import run_app

MODELS = ("ffnn", "lstm", "cnn", "svm")
NETWORKS = ("ffnn", "lstm", "cnn")


@pytest.mark.slow
def test_paper_workers_report_one_labelled_progress_display(tmp_path):
    proc = run_app(
        "train",
        "experiment=paper",
        "paper.workers=2",
        "trainer.max_epochs=2",
        "logger=none",
        "plots=false",
        "+data.splits.n_train=2000",
        "+data.splits.test_frequencies=[1,50]",
        "+data.splits.max_test_samples=1000",
        "paper.models.svm.n_components=50",
        f"hydra.run.dir={tmp_path}",
        cwd=tmp_path,
        timeout=900,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output[-3000:]
    for key in MODELS:
        assert f"[{key}] started" in output and f"[{key}] done in" in output, key
    for key in NETWORKS:  # the last epoch is always reported, on one line with the time left
        last_epoch = rf"\[{key}\] epoch 2/2, (\d+ min )?\d+ s elapsed, ~0 s left\b"
        assert re.search(last_epoch, output), (key, output[-3000:])
    # no worker's Lightning progress bar, model summary or device lines on the terminal
    for noise in ("Epoch 0:", "it/s]", "| Name", "Total params", "GPU available"):
        assert noise not in output, noise
    # each worker's full log is still in its own train.log
    for key in NETWORKS:
        log = (tmp_path / key / "train.log").read_text()
        assert "GPU available" in log and f"[{key}]" in log
