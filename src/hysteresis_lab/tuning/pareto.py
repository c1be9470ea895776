"""The Pareto front of a multi-objective study: a table (CSV and Markdown) and a figure.

A sweep writes them when it ends; for a study in any storage, at any time::

    python -m hysteresis_lab.tuning.pareto sqlite:///outputs/optuna/ffnn_pareto_default.db \
        ffnn_pareto_default outputs/optuna/ffnn_pareto_default
"""

from __future__ import annotations

import argparse
import csv
import logging
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import FrozenTrial

from hysteresis_lab.tuning.bookkeeping import counted
from hysteresis_lab.tuning.objectives import OBJECTIVES

log = logging.getLogger(__name__)

FRONT_CSV, FRONT_MD, FRONT_PNG = "pareto.csv", "pareto.md", "pareto.png"


def pareto_front(study: optuna.Study) -> list[FrozenTrial]:
    """The complete, counted trials no other complete trial beats in every objective, by
    their first objective (the error), lowest first."""
    front = [t for t in study.best_trials if counted(t)]
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
    """Every complete trial in objective space, the front highlighted (2 or 3 objectives)."""
    import matplotlib.pyplot as plt
    from optuna.visualization import matplotlib as ovm

    if len(objectives) not in (2, 3):
        log.warning("a Pareto figure needs 2 or 3 objectives, not %d", len(objectives))
        return
    try:
        with warnings.catch_warnings():  # the plot is "experimental" in every Optuna so far
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            axes = ovm.plot_pareto_front(
                study, target_names=[OBJECTIVES.get(n, n) for n in objectives]
            )
    except (ValueError, RuntimeError) as exc:
        log.warning("could not draw %s: %s", path.name, exc)
        return
    axes.set_title(f"Pareto front of {study.study_name}")
    figure = axes.get_figure()
    figure.set_size_inches(7, 4.5)
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
