"""The Pareto front of a multi-objective study: a table (CSV and Markdown) and a figure.

A sweep writes them when it ends; for a study in any storage, at any time::

    python -m hysteresis_lab.tuning.pareto sqlite:///outputs/optuna/ffnn_pareto_default.db \
        ffnn_pareto_default outputs/optuna/ffnn_pareto_default
"""

from __future__ import annotations

import argparse
import csv
import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from hysteresis_lab.tuning.bookkeeping import counted
from hysteresis_lab.tuning.objectives import OBJECTIVES

log = logging.getLogger(__name__)

FRONT_CSV, FRONT_MD, FRONT_PNG = "pareto.csv", "pareto.md", "pareto.png"


def pareto_front(study: optuna.Study) -> list[FrozenTrial]:
    """The complete, counted trials no other complete trial beats in every objective, by
    their first objective (the error), lowest first; a trial with an infinite objective (a
    diverged free run) is left out."""
    front = [t for t in study.best_trials if counted(t) and all(math.isfinite(v) for v in t.values)]
    return sorted(front, key=lambda t: (t.values[0], t.number))


def objective_names(study: optuna.Study) -> list[str]:
    """The study's objective names as the sweeper stored them (else ``objective_<i>``)."""
    names = study.user_attrs.get("objectives")
    return list(names) if names else [f"objective_{i}" for i in range(len(study.directions))]


def front_rows(front: Sequence[FrozenTrial], objectives: Sequence[str]) -> list[dict[str, Any]]:
    """One row per front trial: its number, its objective values, its parameters."""
    names = sorted({name for t in front for name in t.params})
    return [
        {
            "trial": t.number,
            **dict(zip(objectives, t.values, strict=True)),
            **{name: t.params.get(name, "") for name in names},
        }
        for t in front
    ]


def write_front(
    study: optuna.Study, directory: Path, objectives: Sequence[str] | None = None
) -> list[FrozenTrial]:
    """Write ``pareto.csv``, ``pareto.md`` and ``pareto.png`` of ``study`` to ``directory``;
    return the front (`pareto_front`)."""
    objectives = list(objectives or objective_names(study))
    directory.mkdir(parents=True, exist_ok=True)
    front = pareto_front(study)
    rows = front_rows(front, objectives)
    columns = list(rows[0]) if rows else ["trial", *objectives]
    with (directory / FRONT_CSV).open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    (directory / FRONT_MD).write_text(markdown_table(study.study_name, rows, columns))
    _plot_front(study, objectives, directory / FRONT_PNG)
    log.info(
        "Pareto front of '%s': %d trial(s), in %s",
        study.study_name,
        len(front),
        directory / FRONT_MD,
    )
    return front


def markdown_table(title: str, rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """The front as a Markdown table under a heading naming the study."""
    lines = [
        f"# Pareto front of study `{title}`",
        "",
        "Every objective is minimised; no trial below is beaten in all of them by another.",
        "",
        "| " + " | ".join(columns) + " |",
        "|" + "---|" * len(columns),
    ]
    lines += ["| " + " | ".join(_cell(row.get(c, "")) for c in columns) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _cell(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _plot_front(study: optuna.Study, objectives: Sequence[str], path: Path) -> None:
    """The first two objectives of every complete trial with finite values, the front
    highlighted, joined and labelled with trial numbers."""
    import matplotlib.pyplot as plt

    if len(objectives) < 2:
        return
    trials = [
        t
        for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        if counted(t) and all(math.isfinite(v) for v in t.values)
    ]
    front = pareto_front(study)
    figure, axes = plt.subplots(figsize=(7, 4.5))
    axes.scatter(
        [t.values[0] for t in trials],
        [t.values[1] for t in trials],
        s=18,
        color="0.6",
        label="trial",
    )
    axes.step(
        [t.values[0] for t in front],
        [t.values[1] for t in front],
        where="post",
        color="tab:red",
        marker="o",
        label="Pareto front",
    )
    for t in front:
        axes.annotate(
            str(t.number),
            (t.values[0], t.values[1]),
            textcoords="offset points",
            xytext=(4, 4),
            fontsize=8,
        )
    for axis, scale in enumerate((axes.set_xscale, axes.set_yscale)):
        values = [t.values[axis] for t in trials]
        if values and min(values) > 0 and max(values) > 30 * min(values):
            scale("log")  # errors and costs of a study span decades
    axes.set_xlabel(OBJECTIVES.get(objectives[0], objectives[0]))
    axes.set_ylabel(OBJECTIVES.get(objectives[1], objectives[1]))
    axes.set_title(f"Pareto front of {study.study_name} ({len(trials)} trials shown)")
    axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main(argv: Sequence[str] | None = None) -> None:
    """Write the Pareto front of a stored study (storage URL, study name, folder)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("storage", help="e.g. sqlite:///outputs/optuna/ffnn_pareto_default.db")
    parser.add_argument("study", help="the study's name, e.g. ffnn_pareto_default")
    parser.add_argument("directory", type=Path, help="where the table and figure go")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    study = optuna.load_study(study_name=args.study, storage=args.storage)
    write_front(study, args.directory)


if __name__ == "__main__":
    main()
