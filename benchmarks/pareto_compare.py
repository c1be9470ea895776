"""Compare the Pareto studies of runs of `benchmarks/pareto_study.py` (e.g. two pruners).

    python benchmarks/pareto_compare.py 'hyperband, first rung 10=/tmp/pareto_hb' \\
        'successive halving, first rung 3=/tmp/pareto_sh' --out docs/results/pareto_pruners.md

Each run is ``label=folder``: a ``--results`` folder of `pareto_study.py`, whose
``<arch>_pareto_default.db`` files hold the studies. For every architecture some run has, the
page lists per run: the trials and their states, the compute they took (worker-seconds from
the trials' start and end stamps, and the epochs trained, read off the per-epoch reports in the
companion ``.pruning`` study), the lowest validation free-run error and the hypervolume of the
front. The hypervolume is taken in the plane (log10 error, training seconds) against one
reference point shared by every run of that architecture (just beyond the worst values of
their fronts), so that it compares fronts of different runs: larger is better.
"""

from __future__ import annotations

import argparse
import datetime
import logging
import math
import os
import platform
import shlex
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import optuna
from optuna.trial import FrozenTrial, TrialState

from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.tuning.bookkeeping import counted
from hysteresis_lab.tuning.pareto import pareto_front
from hysteresis_lab.tuning.pruning import pruning_study_name

log = logging.getLogger("pareto_compare")

REPO = Path(__file__).resolve().parents[1]
ARCHS = ("ffnn", "lstm", "cnn", "svm", "subnet")


@dataclass
class StudySummary:
    """What one run's study of one architecture cost and found."""

    states: dict[str, int]
    worker_seconds: float
    epochs: int | None  # None: no companion study (nothing reported per epoch)
    best_error: float
    points: list[tuple[float, float]]  # (log10 error, training seconds) of the front


def summarise(folder: Path, arch: str) -> StudySummary | None:
    """The study of ``arch`` in a results folder; None where the run has none."""
    name = f"{arch}_pareto_default"
    db = folder / f"{name}.db"
    if not db.is_file():
        return None
    url = f"sqlite:///{db.resolve()}"
    study = optuna.load_study(study_name=name, storage=url)
    trials = [t for t in study.get_trials(deepcopy=False) if counted(t) and t.state.is_finished()]
    states = dict(Counter(t.state.name.lower() for t in trials))
    front = pareto_front(study)
    errors = [t.values[0] for t in front]
    return StudySummary(
        states=states,
        worker_seconds=sum(_duration(t) for t in trials),
        epochs=_epochs_reported(url, name),
        best_error=min(errors) if errors else math.nan,
        points=[(math.log10(t.values[0]), t.values[1]) for t in front if t.values[0] > 0],
    )


def _duration(trial: FrozenTrial) -> float:
    if trial.datetime_start is None or trial.datetime_complete is None:
        return 0.0
    return (trial.datetime_complete - trial.datetime_start).total_seconds()


def _epochs_reported(url: str, name: str) -> int | None:
    """Epochs trained over the study: one report per epoch per trial in its companion study."""
    try:
        companion = optuna.load_study(study_name=pruning_study_name(name), storage=url)
    except KeyError:
        return None
    return sum(
        len(t.intermediate_values)
        for t in companion.get_trials(deepcopy=False)
        if t.state in (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
    )


def hypervolume_2d(points: list[tuple[float, float]], reference: tuple[float, float]) -> float:
    """The area dominated by ``points`` (both coordinates minimised) and bounded by
    ``reference``: along the first axis, the best second coordinate reached so far."""
    inside = sorted(p for p in points if p[0] < reference[0] and p[1] < reference[1])
    if not inside:
        return 0.0
    edges = [p[0] for p in inside[1:]] + [reference[0]]
    area, best_second = 0.0, reference[1]
    for (first, second), right in zip(inside, edges, strict=True):
        best_second = min(best_second, second)
        area += (right - first) * (reference[1] - best_second)
    return area


def reference_point(points: list[tuple[float, float]]) -> tuple[float, float]:
    """A tenth of a decade of error and a tenth of the seconds beyond the worst values, so
    that the fronts' extreme points count too."""
    return max(p[0] for p in points) + 0.1, 1.1 * max(p[1] for p in points)


def write_page(labels: list[str], table: dict[str, list[StudySummary | None]], out: Path,
               argv: list[str]) -> None:
    lines = [
        "# Compute-aware tuning: two studies' costs and fronts compared",
        "",
        "Written by `benchmarks/pareto_compare.py` (do not edit by hand).",
        "",
        f"- command: `python benchmarks/pareto_compare.py {shlex.join(argv)}`",
        f"- commit: {commit_stamp(REPO, ['src'])}",
        f"- date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
        f"- machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "",
        "*worker-s*: the trials' seconds from start to end, summed (two workers run two at a "
        "time); *epochs*: epochs trained over all trials, from their per-epoch reports; "
        "*hypervolume*: the area the front dominates in (log10 validation free-run MSE, "
        "training seconds) up to 0.1 decade and 10 % beyond the worst values on the fronts "
        "of that architecture's runs (larger is better; comparable within an architecture "
        "only).",
        "",
        "| study | run | trials | worker-s | epochs | best val_free_run_mse | hypervolume |",
        "|---|---|---|---|---|---|---|",
    ]
    for arch, summaries in table.items():
        points = [p for s in summaries if s for p in s.points]
        if not points:
            continue
        reference = reference_point(points)
        for label, s in zip(labels, summaries, strict=True):
            if s is None:
                lines.append(f"| {arch} | {label} | not run | | | | |")
                continue
            states = ", ".join(f"{n} {k}" for k, n in sorted(s.states.items()))
            epochs = "" if s.epochs is None else str(s.epochs)
            lines.append(
                f"| {arch} | {label} | {states} | {s.worker_seconds:.0f} | {epochs} | "
                f"{s.best_error:.4g} | {hypervolume_2d(s.points, reference):.4g} |"
            )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    log.info("wrote %s", out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="label=results folder of pareto_study.py")
    parser.add_argument("--out", default=str(REPO / "docs" / "results" / "pareto_pruners.md"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    labels, folders = [], []
    for run in args.runs:
        label, sep, folder = run.rpartition("=")
        if not sep or not Path(folder).is_dir():
            parser.error(f"'{run}' is not label=<an existing results folder>.")
        labels.append(label)
        folders.append(Path(folder))
    table = {arch: [summarise(folder, arch) for folder in folders] for arch in ARCHS}
    write_page(labels, table, Path(args.out), sys.argv[1:])


if __name__ == "__main__":
    main()
