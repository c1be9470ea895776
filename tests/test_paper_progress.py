"""``experiment=paper`` on a CPU: the worker processes' progress reaches the terminal as one
labelled line per update (model, epoch, time left), not as interleaved Lightning bars."""

from __future__ import annotations

import os
import re
import signal
import time
from pathlib import Path

import pytest

from helpers import popen_app, run_app

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


def _worker_pids(parent: int) -> list[int]:
    """The pool's worker processes of the app ``parent`` (not multiprocessing's tracker)."""
    children = Path(f"/proc/{parent}/task/{parent}/children").read_text().split()
    pids = []
    for pid in map(int, children):
        command = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
        if b"spawn_main" in command and b"resource_tracker" not in command:
            pids.append(pid)
    return pids


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads /proc (Linux)")
def test_a_stopped_paper_run_starts_no_further_model_in_its_workers(tmp_path):
    proc = popen_app(
        "train", "experiment=paper", "paper.workers=2", "trainer.max_epochs=200",
        "~paper.models.svm", "~paper.models.greybox", "logger=none", "plots=false",
        "+data.splits.n_train=2000", "+data.splits.test_frequencies=[1,50]",
        "+data.splits.max_test_samples=1000", f"hydra.run.dir={tmp_path}", cwd=tmp_path,
    )
    deadline = time.monotonic() + 600
    # both workers are busy: two jobs have opened their train.log and lstm has trained an epoch
    lstm_checkpoint = tmp_path / "lstm" / "checkpoints" / "last.ckpt"
    while not (len(_started_jobs(tmp_path)) >= 2 and lstm_checkpoint.exists()):
        assert proc.poll() is None, proc.stdout.read()[-3000:]
        assert time.monotonic() < deadline, "the two workers never both started a job"
        time.sleep(0.05)
    started_before_stop = _started_jobs(tmp_path)
    workers = _worker_pids(proc.pid)
    assert len(workers) == 2
    os.kill(proc.pid, signal.SIGTERM)  # `kill` of the app: the parent stops its workers
    output, _ = proc.communicate(timeout=300)
    assert proc.returncode == 143, output[-3000:]
    # a job's train.log opens as it starts (its "started" line reaches the terminal through
    # a queue that a stop may cut short, so the files are the evidence): no new job was taken
    assert _started_jobs(tmp_path) == started_before_stop, output[-3000:]
    for key in set(NETWORKS) - started_before_stop:
        assert f"[{key}] started" not in output


def _started_jobs(run_dir: Path) -> set[str]:
    """The paper run's jobs that have started: each opens ``<model>/train.log`` first."""
    return {key for key in NETWORKS if (run_dir / key / "train.log").exists()}
