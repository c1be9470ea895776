"""The study's experiment: every architecture on one data set, then Table 2 and Figure 1.

On a CPU the networks are small, so one training process cannot keep every core busy (two
threads train an LSTM only ~1.4x faster than one). ``workers="auto"`` therefore trains the
models in parallel processes, one per core up to the number of models, each with its share of
the threads; with a GPU they train one after the other on it.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.plots import loops_figure, save_figure
from hysteresis_lab.evaluation.report import write_json, write_table2
from hysteresis_lab.pipeline import evaluation_device, plain_dict, train_and_evaluate
from hysteresis_lab.training import check_trainer_settings, is_network, model_layout

log = logging.getLogger(__name__)

LOG_FORMAT = "[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"


@dataclass
class PaperEntry:
    """What one architecture contributes to the tables and the figure (picklable)."""

    document: dict[str, Any]
    free_run: dict[str, np.ndarray]


@dataclass
class _Job:
    key: str
    model_cfg: dict[str, Any]
    data_cfg: dict[str, Any]
    trainer_cfg: dict[str, Any]
    output_dir: Path
    seed: int
    use_tensorboard: bool
    splits: DatasetSplits
    threads: int | None = None
    resume: bool = True


def available_cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def plan_workers(
    n_models: int, trainer_cfg: Mapping[str, Any], workers: int | str = "auto"
) -> tuple[int, int | None]:
    """``(processes, torch threads per process)``; threads None means torch's default."""
    if workers == "auto":
        if evaluation_device(trainer_cfg) != "cpu":
            return 1, None
        workers = min(n_models, available_cores())
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise ConfigError(f"paper.workers={workers!r} is invalid. Fix: 'auto' or an integer >= 1.")
    workers = min(workers, n_models)
    if workers == 1:
        return 1, None
    return workers, max(1, available_cores() // workers)


def _run_job(job: _Job) -> PaperEntry:
    if job.threads is not None:
        torch.set_num_threads(job.threads)
    result = train_and_evaluate(
        job.model_cfg, job.data_cfg, job.trainer_cfg, job.output_dir, seed=job.seed,
        splits=job.splits, use_tensorboard=job.use_tensorboard, reuse=job.resume,
    )
    free_run = {name: p["free_run"] for name, p in result.evaluation.predictions.items()}
    return PaperEntry(result.document, free_run)


def _run_job_in_worker(job: _Job) -> PaperEntry:
    """Entry point of a worker process: log to stderr and the model's own train.log."""
    job.output_dir.mkdir(parents=True, exist_ok=True)
    formatter = logging.Formatter(LOG_FORMAT.replace("%(message)s", f"[{job.key}] %(message)s"))
    handlers = [logging.StreamHandler(), logging.FileHandler(job.output_dir / "train.log")]
    root = logging.getLogger()
    root.setLevel(logging.INFO)
    for handler in handlers:
        handler.setFormatter(formatter)
        root.addHandler(handler)
    try:
        return _run_job(job)
    finally:  # a worker process runs several jobs: each logs only to its own file
        for handler in handlers:
            root.removeHandler(handler)
            handler.close()


def run_paper(
    models: Mapping[str, Mapping[str, Any]],
    data_cfg: Mapping[str, Any],
    trainer_cfg: Mapping[str, Any],
    output_dir: Path,
    seed: int = 0,
    use_tensorboard: bool = True,
    workers: int | str = "auto",
    resume: bool = True,
) -> dict[str, PaperEntry]:
    """Train and score every model; write table2.md/.csv, paper_results.json, figure1.png.

    ``resume``: a model whose fit finished in its folder with the same settings and data (a
    rerun of a stopped experiment in its folder) is loaded and scored, not trained again.
    """
    data_cfg, trainer_cfg = plain_dict(data_cfg), plain_dict(trainer_cfg)
    if any(is_network(cfg) for cfg in models.values()):
        check_trainer_settings(trainer_cfg)  # before any model trains, not in a worker
    splits = build_splits(data_cfg)
    if not splits.val:
        log.info(
            "validation: the study's random %.0f %% of the training windows (the multisine is "
            "periodic, so these windows repeat inputs the models train on; data=default "
            "outside experiment=paper validates on a second multisine instead)",
            100 * float(data_cfg.get("val_fraction", 0.1)),
        )
    processes, threads = plan_workers(len(models), trainer_cfg, workers)
    jobs = [
        _Job(key, plain_dict(cfg), data_cfg, trainer_cfg, output_dir / key, seed,
             use_tensorboard, splits, threads, resume)
        for key, cfg in models.items()
    ]
    if processes == 1:
        entries = {}
        for job in jobs:
            log.info("=== %s ===", job.key)
            entries[job.key] = _run_job(job)
    else:
        # sequence models (LSTM, CNN) take longest: start them first to balance the workers
        jobs.sort(key=lambda job: model_layout(job.model_cfg) != "sequence")
        log.info("training %s in %d processes with %d torch thread(s) each",
                 ", ".join(job.key for job in jobs), processes, threads)
        context = multiprocessing.get_context("spawn")  # fork after torch init can deadlock
        with ProcessPoolExecutor(processes, mp_context=context) as pool:
            futures = {job.key: pool.submit(_run_job_in_worker, job) for job in jobs}
            done = {key: future.result() for key, future in futures.items()}
        entries = {key: done[key] for key in models}  # the config's order
    documents = {key: entry.document for key, entry in entries.items()}
    md_path, csv_path = write_table2(documents, output_dir)
    write_json(documents, output_dir / "paper_results.json")
    free_run = {
        rec.name: {key: entry.free_run[rec.name] for key, entry in entries.items()}
        for rec in splits.test
    }
    figure = save_figure(
        loops_figure(
            splits.test,
            free_run,
            title="Free-run simulation: measured (black) and "
            "predicted displacement against voltage",
        ),
        output_dir / "figure1.png",
    )
    log.info("Table 2: %s, %s; Figure 1: %s", md_path, csv_path, figure)
    log.info("\n%s", md_path.read_text())
    return entries
