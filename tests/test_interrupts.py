"""Stopping a run: SIGINT / SIGTERM end it with status 130 / 143 and one line; a rerun in its
folder resumes the training from its last epoch (or refuses other settings); a run folder in
use by another process is refused."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import lightning as L
import pytest

from helpers import data_overrides, popen_app, run_app, small_dataset
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.interrupts import RunInterrupted, signals_deferred, stopping_on_signals
from hysteresis_lab.run_folder import RunFolder
from hysteresis_lab.run_lock import hold_run_folder
from hysteresis_lab.workflows.pipeline import RunConfig, run_model
from narx import TRAINER, narx_data

DATA = DataSpec.from_config({"window": {"na": 4, "nb": 4, "nk": 1},
                             "scaling": {"mode": "standard"}})
FFNN = {"name": "ffnn", "num_layers": 2, "neurons": 16}
QUIET = ["trainer.enable_progress_bar=false", "trainer.enable_model_summary=false",
         "logger=none", "plots=false"]


class _StopAfter(L.Callback):
    """A SIGTERM's effect once ``epochs`` epochs are done (their last.ckpt written)."""

    def __init__(self, epochs: int) -> None:
        self.epochs = epochs

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.current_epoch == self.epochs:
            raise RunInterrupted(signal.SIGTERM)


class _CountEpochs(L.Callback):
    def __init__(self) -> None:
        self.trained = 0

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.trained += 1


def _train(folder: Path, epochs: int, callbacks: list, **settings):
    config = RunConfig.build(FFNN, DATA, TRAINER.with_changes(max_epochs=epochs), folder,
                             use_tensorboard=False, plots=False, **settings)
    return run_model(config, splits=narx_data(600), callbacks=callbacks)


def _checkpoints(folder: Path) -> list[str]:
    return sorted(path.name for path in (folder / RunFolder.CHECKPOINTS).glob("*.ckpt"))


def test_a_rerun_resumes_an_interrupted_training_from_its_last_epoch(tmp_path):
    with pytest.raises(RunInterrupted):
        _train(tmp_path, 5, [_StopAfter(3)])
    folder = RunFolder(tmp_path)
    assert folder.last_checkpoints() and folder.fit_in_progress.is_file()
    assert folder.model_file() is None

    counted = _CountEpochs()
    _train(tmp_path, 5, [counted])
    assert counted.trained == 2  # epochs 4 and 5: the first three were kept
    assert folder.model_file() is not None and folder.metrics.is_file()
    # one best checkpoint, and nothing left to resume
    assert len(_checkpoints(tmp_path)) == 1 and _checkpoints(tmp_path)[0].startswith("best-")
    assert not folder.fit_in_progress.exists()


def test_a_best_checkpoint_the_resumed_state_did_not_know_is_not_left_beside_the_new(tmp_path):
    """A stop can land after an epoch's best checkpoint and before its ``last.ckpt``: the
    resumed fit's checkpoint state does not know that best, which must not stay."""
    with pytest.raises(RunInterrupted):
        _train(tmp_path, 5, [_StopAfter(3)])
    (best,) = [name for name in _checkpoints(tmp_path) if name.startswith("best-")]
    directory = tmp_path / RunFolder.CHECKPOINTS
    shutil.copy(directory / best, directory / "best-epoch=002-val_loss=1.000e-09.ckpt")
    _train(tmp_path, 5, [])
    assert len(_checkpoints(tmp_path)) == 1


def test_a_rerun_with_other_settings_is_refused_and_one_without_resume_starts_over(tmp_path):
    with pytest.raises(RunInterrupted):
        _train(tmp_path, 5, [_StopAfter(2)])
    stale = _checkpoints(tmp_path)
    with pytest.raises(ConfigError, match="interrupted with other settings.*Fix: "):
        _train(tmp_path, 3, [])

    counted = _CountEpochs()
    _train(tmp_path, 3, [counted], resume=False)
    assert counted.trained == 3
    fresh = _checkpoints(tmp_path)
    assert len(fresh) == 1 and not set(fresh) & set(stale)  # the interrupted run's are gone


class _Frozen(L.Callback):
    """Learning rate 0: the validation loss never improves, so early stopping (patience 1)
    ends the stage after its second epoch."""

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        for group in trainer.optimizers[0].param_groups:
            group["lr"] = 0.0


class _StopAtTheEnd(L.Callback):
    def on_fit_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        raise RunInterrupted(signal.SIGINT)


def test_a_stage_that_early_stopping_ended_trains_no_further_epoch_when_resumed(tmp_path):
    free_run = {"objective": "simulation", "horizon": 20, "patience": 1}

    def train(callbacks):
        config = RunConfig.build(FFNN, DATA, TRAINER.with_changes(max_epochs=10), tmp_path,
                                 free_run, use_tensorboard=False, plots=False)
        return run_model(config, splits=narx_data(600), callbacks=callbacks)

    first = _CountEpochs()
    with pytest.raises(RunInterrupted):
        train([_Frozen(), first, _StopAtTheEnd()])
    assert first.trained == 2  # stopped early, then interrupted before the fit was saved
    resumed = _CountEpochs()
    train([_Frozen(), resumed])
    assert resumed.trained == 0 and RunFolder(tmp_path).model_file() is not None


class _Fail(L.Callback):
    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.current_epoch == 2:
            raise RuntimeError("a bug")


def test_a_fit_that_failed_leaves_nothing_to_resume(tmp_path):
    with pytest.raises(RuntimeError, match="a bug"):
        _train(tmp_path, 5, [_Fail()])
    folder = RunFolder(tmp_path)
    assert not folder.fit_in_progress.exists() and not folder.last_checkpoints()
    _train(tmp_path, 3, [])  # other settings: not refused, nothing to resume
    assert len(_checkpoints(tmp_path)) == 1


def test_a_run_folder_is_held_by_one_process_at_a_time(tmp_path):
    in_use = rf"in use by another run \(process {os.getpid()}\).*Fix: "
    with hold_run_folder(tmp_path), pytest.raises(ConfigError, match=in_use), \
            hold_run_folder(tmp_path):
        pass
    with hold_run_folder(tmp_path):  # released at the end of the block
        pass


def test_a_killed_runs_lock_does_not_block_the_next_run(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from hysteresis_lab.run_lock import "
         "hold_run_folder as h\nwith h(sys.argv[1]):\n print('held', flush=True); time.sleep(60)",
         str(tmp_path)],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError, match=f"process {holder.pid}"), hold_run_folder(tmp_path):
            pass
    finally:
        holder.kill()
        holder.wait()
    assert RunFolder(tmp_path).lock.is_file()  # left behind, and no obstacle
    with hold_run_folder(tmp_path):
        pass


@pytest.mark.parametrize(("signum", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_stop_signal_raises_run_interrupted_with_the_shells_status(signum, status):
    with stopping_on_signals(), pytest.raises(RunInterrupted) as stopped:
        os.kill(os.getpid(), signum)
        time.sleep(5)  # the handler runs at once; this never ends normally
    assert stopped.value.exit_status == status and stopped.value.name == signum.name


class _LoseASignal:
    """``signum`` arrives in its ``__del__``, whose exceptions Python ignores (as a data
    loader's, shutting down its workers)."""

    def __init__(self, signum: int) -> None:
        self.signum = signum

    def __del__(self) -> None:
        os.kill(os.getpid(), self.signum)
        time.sleep(0.2)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_whose_exception_was_lost_stops_the_training_at_its_next_batch(tmp_path, signum):
    class LoseOneAfterTheSecondEpoch(L.Callback):
        def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
            if trainer.current_epoch == 1:
                _LoseASignal(signum)  # collected at once: the RunInterrupted it raised is lost

    counted = _CountEpochs()
    with stopping_on_signals(), pytest.raises(RunInterrupted):
        _train(tmp_path, 5, [LoseOneAfterTheSecondEpoch(), counted])
    assert counted.trained <= 3  # stopped at the third epoch (its first batch) at the latest


def test_a_signal_inside_a_deferred_block_acts_at_its_end():
    finished = False
    with stopping_on_signals(), pytest.raises(RunInterrupted) as stopped:
        with signals_deferred():  # a checkpoint being written
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.2)
            finished = True
        time.sleep(5)
    assert finished and stopped.value.exit_status == 143


@pytest.fixture(scope="module")
def csv_data(tmp_path_factory) -> tuple[Path, list[Path]]:
    return small_dataset(tmp_path_factory.mktemp("interrupt_data"), n_train=1500)


def _signal_when(path: Path, proc: subprocess.Popen, signum: int, timeout: float = 300.0) -> str:
    """Send ``signum`` to the app as soon as ``path`` exists; its output and status."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, proc.stdout.read()[-3000:]
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.02)
    proc.send_signal(signum)
    output, _ = proc.communicate(timeout=120)
    return output


def _stop_lines(output: str, name: str) -> list[str]:
    return [line for line in output.splitlines() if f"stopped by {name}" in line]


@pytest.mark.slow
def test_sigterm_stops_training_with_143_and_the_rerun_resumes_it(csv_data, tmp_path):
    args = [*data_overrides(*csv_data), "model=ffnn", "trainer.max_epochs=100", *QUIET,
            f"hydra.run.dir={tmp_path}"]
    proc = popen_app("train", *args)
    output = _signal_when(tmp_path / "checkpoints" / "last.ckpt", proc, signal.SIGTERM)
    assert proc.returncode == 143, output[-3000:]
    assert "Traceback" not in output
    (line,) = _stop_lines(output, "SIGTERM")
    assert "checkpoints/last.ckpt" in line and f"hydra.run.dir={tmp_path}" in line
    assert not (tmp_path / "model.ckpt").exists()

    rerun = run_app("train", *args, "trainer.log_every_n_steps=5")  # display only
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert "resuming the interrupted training from" in rerun.stdout + rerun.stderr
    assert (tmp_path / "model.ckpt").is_file() and (tmp_path / "metrics.json").is_file()
    assert len(_checkpoints(tmp_path)) == 1  # the new best only


@pytest.mark.slow
def test_ctrl_c_stops_the_loop_with_130_and_one_line(csv_data, tmp_path):
    args = [*data_overrides(*csv_data), "model=ffnn", "loop.max_rounds=1",
            "trainer.max_epochs=100", *QUIET, f"hydra.run.dir={tmp_path}"]
    proc = popen_app("loop", *args)
    output = _signal_when(tmp_path / "round_0" / "checkpoints" / "last.ckpt", proc,
                          signal.SIGINT)
    assert proc.returncode == 130, output[-3000:]
    assert "Traceback" not in output
    (line,) = _stop_lines(output, "SIGINT")
    assert "round_0/checkpoints/last.ckpt" in line


@pytest.mark.slow
def test_a_run_folder_in_use_is_refused_with_one_line(csv_data, tmp_path):
    with hold_run_folder(tmp_path):
        proc = run_app("train", *data_overrides(*csv_data), "trainer.max_epochs=1", *QUIET,
                       f"hydra.run.dir={tmp_path}")
    output = proc.stdout + proc.stderr
    assert proc.returncode == 2, output[-3000:]
    assert "is in use by another run" in output and "Traceback" not in output
    assert not (tmp_path / "checkpoints").exists()
