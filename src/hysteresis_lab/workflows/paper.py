"""The study's experiment: every architecture on one data set, then Table 2 and Figure 1.

The study's four (FFNN, LSTM, CNN, SVM) are joined by this project's physical grey-box model,
a fifth column of Table 2 and a fifth curve of Figure 1 labelled as beyond the study
(`column_label`); ``experiment=paper ~paper.models.greybox`` leaves it out.

On a CPU the networks are small, so one training process cannot keep every core busy (two
threads train an LSTM only ~1.4x faster than one). ``workers="auto"`` therefore trains the
models in parallel processes, one per core up to the number of models, each with its share of
the threads; with a GPU they train one after the other on it. Worker processes train without
Lightning's progress bars and summaries: they report their epochs (and the time left) to the
parent, which logs one line per update labelled with the model; each worker's full log is in
``<model>/train.log``.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch

from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.plots import loops_figure, save_figure
from hysteresis_lab.evaluation.report import write_json, write_table2
from hysteresis_lab.fitting import check_trainer_settings
from hysteresis_lab.interrupts import RunInterrupted, stopping_on_signals
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.workflows.pipeline import RunConfig, run_model

log = logging.getLogger(__name__)

LOG_FORMAT = "[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"
PROGRESS_EVERY_S = 10.0  # a worker reports its epoch progress at most this often

#: the study's architectures; any other model of ``paper.models`` is this project's own
STUDY_MODELS = ("ffnn", "lstm", "cnn", "svm")
#: the name a model beyond the study goes by in Table 2 and Figure 1
DISPLAY_NAMES = {"greybox": "grey-box"}
FIGURE1_TITLE = "Free-run simulation: measured (black) and predicted displacement against voltage"


@dataclass
class PaperEntry:
    """What one architecture contributes to the tables and the figure (picklable)."""

    document: dict[str, Any]
    free_run: dict[str, np.ndarray]


@dataclass
class _Job:
    """One model's run (its configs as objects, `RunConfig`) on the shared ``splits``."""

    key: str
    config: RunConfig
    splits: DatasetSplits
    threads: int | None = None


def available_cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def plan_workers(
    n_models: int, trainer: TrainerSettings, workers: int | str = "auto"
) -> tuple[int, int | None]:
    """``(processes, torch threads per process)``; threads None means torch's default."""
    if workers == "auto":
        if trainer.evaluation_device() != "cpu":
            return 1, None
        workers = min(n_models, available_cores())
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise ConfigError(f"paper.workers={workers!r} is invalid. Fix: 'auto' or an integer >= 1.")
    workers = min(workers, n_models)
    if workers == 1:
        return 1, None
    return workers, max(1, available_cores() // workers)


def _run_job(job: _Job, callbacks: list[Any] | None = None) -> PaperEntry:
    if job.threads is not None:
        torch.set_num_threads(job.threads)
    result = run_model(job.config, splits=job.splits, callbacks=callbacks)
    free_run = {name: p["free_run"] for name, p in result.evaluation.predictions.items()}
    return PaperEntry(result.document, free_run)


class EpochReporter(L.Callback):
    """Sends a worker's training progress (epoch, time left) to the parent's ``queue`` as
    ``(model key, message)``: at most one message per ``every_s`` seconds, and the last epoch."""

    def __init__(self, key: str, queue: Any, every_s: float = PROGRESS_EVERY_S) -> None:
        self.key, self.queue, self.every_s = key, queue, every_s
        self.started = self.last = 0.0
        self.first = 0  # the epoch training (re)started at: a resumed fit's are done

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.started = time.monotonic()
        self.last = -self.every_s
        self.first = trainer.current_epoch

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        done, total = trainer.current_epoch + 1, trainer.max_epochs
        now = time.monotonic()
        if now - self.last < self.every_s and done < total:
            return
        self.last = now
        elapsed = now - self.started
        left = elapsed / max(done - self.first, 1) * (total - done)
        val = trainer.callback_metrics.get("val_loss")
        message = f"epoch {done}/{total}, {_duration(elapsed)} elapsed, ~{_duration(left)} left"
        if val is not None:
            message += f", val_loss {float(val):.4g}"
        self.queue.put((self.key, message))


def _duration(seconds: float) -> str:
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes} min {secs:02d} s" if minutes else f"{secs} s"


class _QueueLogHandler(logging.Handler):
    """Forwards a worker's milestones to the parent's progress display: the run report's
    lines (saved, reused, the model's mean scores) and every warning or error of this
    package."""

    def __init__(self, key: str, queue: Any) -> None:
        super().__init__(logging.INFO)
        self.key, self.queue = key, queue

    def filter(self, record: logging.LogRecord) -> bool:
        return (record.levelno >= logging.WARNING
                or record.name == "hysteresis_lab.workflows.run_report")

    def emit(self, record: logging.LogRecord) -> None:
        level = "" if record.levelno < logging.WARNING else f"{record.levelname}: "
        self.queue.put((self.key, level + record.getMessage()))


_progress_queue: Any = None  # the parent's progress queue, in a worker process
#: the stop signal a worker process received (it then starts no further job)
_worker_stopped_by: int | None = None


def _init_worker(queue: Any) -> None:
    """Worker process start: keep the parent's progress queue; leave Ctrl-C (sent to the
    whole process group) to the parent, which stops the workers (`_stop_workers`)."""
    global _progress_queue
    _progress_queue = queue
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run_job_in_worker(job: _Job) -> PaperEntry:
    """Entry point of a worker process: the full log goes to the model's own train.log only;
    Lightning's progress bar and model summary are off; the epoch progress, the pipeline's
    milestones and any warning go to the parent through the queue (one labelled line each)."""
    global _worker_stopped_by
    if _worker_stopped_by is not None:  # the pool hands a stopped worker the next job
        raise RunInterrupted(_worker_stopped_by)
    output_dir = job.config.output_dir
    output_dir.mkdir(parents=True, exist_ok=True)
    job = replace(job, config=replace(job.config, trainer=job.config.trainer.with_changes(
        enable_progress_bar=False, enable_model_summary=False,
    )))
    formatter = logging.Formatter(LOG_FORMAT.replace("%(message)s", f"[{job.key}] %(message)s"))
    handlers: list[logging.Handler] = [logging.FileHandler(output_dir / "train.log")]
    root = logging.getLogger()
    root.setLevel(logging.INFO)
    for handler in handlers:
        handler.setFormatter(formatter)
        root.addHandler(handler)
    # Lightning prints its device lines through its own console handler when imported
    # before any logging was set up (as in a fresh worker): route them to train.log instead
    for name in ("lightning", "lightning.pytorch", "lightning.fabric"):
        lightning_log = logging.getLogger(name)
        for handler in list(lightning_log.handlers):
            lightning_log.removeHandler(handler)
        lightning_log.propagate = True
    logging.captureWarnings(True)  # library warnings: train.log, not the shared terminal
    started = time.monotonic()
    queue = _progress_queue
    package_log = logging.getLogger("hysteresis_lab")
    forward = _QueueLogHandler(job.key, queue) if queue is not None else None
    if forward is not None:
        package_log.addHandler(forward)
    try:
        if queue is not None:
            queue.put((job.key, f"started (log: {output_dir / 'train.log'})"))
        reporter = [EpochReporter(job.key, queue)] if queue is not None else None
        try:
            with stopping_on_signals((signal.SIGTERM,)):  # the job stops where the parent asks
                entry = _run_job(job, reporter)
        except RunInterrupted as stop:
            _worker_stopped_by = stop.signum
            raise
        if queue is not None:
            queue.put((job.key, f"done in {_duration(time.monotonic() - started)}"))
        return entry
    finally:  # a worker process runs several jobs: each logs only to its own file
        for handler in [*handlers, forward]:
            if handler is not None:
                root.removeHandler(handler)
                package_log.removeHandler(handler)
                handler.close()


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Cancel the jobs not started; stop the running ones (SIGTERM: each worker's fit keeps
    its last whole checkpoint) and wait for their workers to end."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=60)


def _relay_progress(queue: Any) -> None:
    """Log the workers' progress messages, one labelled line each, until ``None`` arrives."""
    for item in iter(queue.get, None):
        key, message = item
        log.info("[%s] %s", key, message)


def column_label(key: str) -> str:
    """A model's name in Table 2 and Figure 1: the study's as they are, any other marked as
    beyond the study (``grey-box (this project, beyond the study)``)."""
    if key in STUDY_MODELS:
        return key
    return f"{DISPLAY_NAMES.get(key, key)} (this project, beyond the study)"


def figure1(recordings: list[Any], free_run: Mapping[str, Mapping[str, np.ndarray]]) -> Any:
    """Figure 1: each model's free run (``free_run[recording][model]``) over the measured
    loops, one panel per test recording; the legend names the models by `column_label`."""
    keys = {key for runs in free_run.values() for key in runs}
    return loops_figure(recordings, free_run, title=FIGURE1_TITLE,
                        labels={key: column_label(key) for key in keys})


def run_paper(
    models: Mapping[str, Mapping[str, Any]],
    data: DataSpec,
    trainer: TrainerSettings,
    output_dir: Path,
    seed: int = 0,
    use_tensorboard: bool = True,
    workers: int | str = "auto",
    resume: bool = True,
    training: Mapping[str, Any] | TrainingSettings | None = None,
) -> dict[str, PaperEntry]:
    """Train and score every model (their configs) on the data set ``data``, each network
    with the ``training`` config (its unset values: each model's own); write
    table2.md/.csv, paper_results.json, figure1.png.

    ``resume``: a model whose fit finished in its folder with the same settings and data (a
    rerun of a stopped experiment in its folder) is loaded and scored, not trained again.
    """
    configs = {
        key: RunConfig.build(cfg, data, trainer, output_dir / key, training, seed=seed,
                             use_tensorboard=use_tensorboard, reuse=resume, resume=resume)
        for key, cfg in models.items()
    }
    if any(config.model.is_network for config in configs.values()):
        check_trainer_settings(trainer)  # before any model trains, not in a worker
    splits = build_splits(data)
    if not splits.val:
        log.info(
            "validation: the study's random %.0f %% of the training windows (the multisine is "
            "periodic, so these windows repeat inputs the models train on; data=default "
            "outside experiment=paper validates on a second multisine instead)",
            100 * float(data.val_fraction),
        )
    processes, threads = plan_workers(len(models), trainer, workers)
    jobs = [_Job(key, config, splits, threads) for key, config in configs.items()]
    if processes == 1:
        entries = {}
        for job in jobs:
            log.info("=== %s ===", job.key)
            entries[job.key] = _run_job(job)
    else:
        # sequence models (LSTM, CNN) take longest: start them first to balance the workers
        jobs.sort(key=lambda job: job.config.model.layout != "sequence")
        log.info("training %s in %d processes with %d torch thread(s) each",
                 ", ".join(job.key for job in jobs), processes, threads)
        context = multiprocessing.get_context("spawn")  # fork after torch init can deadlock
        queue = context.Queue()
        relay = threading.Thread(target=_relay_progress, args=(queue,), daemon=True)
        relay.start()
        try:
            with ProcessPoolExecutor(
                processes, mp_context=context, initializer=_init_worker, initargs=(queue,)
            ) as pool:
                futures = {job.key: pool.submit(_run_job_in_worker, job) for job in jobs}
                try:
                    done = {key: future.result() for key, future in futures.items()}
                except (RunInterrupted, KeyboardInterrupt):
                    _stop_workers(pool)
                    raise
        finally:
            queue.put(None)
            relay.join(timeout=10)
        entries = {key: done[key] for key in models}  # the config's order
    documents = {key: entry.document for key, entry in entries.items()}
    labels = {key: column_label(key) for key in documents}
    md_path, csv_path = write_table2(documents, output_dir, labels)
    results_path = write_json(documents, output_dir / "paper_results.json")
    free_run = {
        rec.name: {key: entry.free_run[rec.name] for key, entry in entries.items()}
        for rec in splits.test
    }
    figure = save_figure(figure1(splits.test, free_run), output_dir / "figure1.png")
    _log_paper_result(documents, labels, output_dir, [md_path, csv_path, figure, results_path])
    return entries


def _log_paper_result(
    documents: Mapping[str, Mapping[str, Any]], labels: Mapping[str, str], output_dir: Path,
    files: list[Path],
) -> None:
    """The run's last lines: each model's mean scores (Table 2's mean row), and where the
    table, the figure and each model's run folder are."""
    width = max(len(label) for label in labels.values())
    log.info("Table 2, mean over the %d test recordings:",
             len(next(iter(documents.values()))["tests"]))
    for key, document in documents.items():
        mean, unit = document["mean"], document["units"].get("y", "")
        log.info("  %-*s free-run RMSE %.4g %s, one-step RMSE %.4g %s", width, labels[key],
                 mean["rmse_free_run"], unit, mean["rmse_one_step"], unit)
    md_path, csv_path, figure, results_path = files
    log.info("run folder: %s", output_dir)
    log.info("  %-12s %s, %s", "Table 2", md_path.name, csv_path.name)
    log.info("  %-12s %s", "Figure 1", figure.name)
    log.info("  %-12s %s", "all scores", results_path.name)
    log.info("  %-12s %s (each a run folder: model, metrics.json, figures)", "per model",
             ", ".join(f"{key}/" for key in documents))
    logs = sorted(output_dir.glob("*.log"))
    if logs:
        log.info("  %-12s %s", "full log", logs[0].name)
