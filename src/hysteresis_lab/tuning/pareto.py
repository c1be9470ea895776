"""The Pareto front of a multi-objective study: a table (CSV and Markdown) and a figure.

The table and figure hold the complete trials and the pruned ones, each pruned trial a point
at its own fidelity (its objectives as its model stood when pruned, `STOPPED_VALUES`): a
model trained a few epochs is a real error-for-seconds trade, and without them a study whose
pruner stops most trials has a front of two or three points. The best trial
(`experiment=best_<study>`) is the most accurate complete one (`pareto_front`).

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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from hysteresis_lab.tuning.bookkeeping import counted
from hysteresis_lab.tuning.objectives import OBJECTIVES, STOPPED_EPOCHS, STOPPED_VALUES

log = logging.getLogger(__name__)

FRONT_CSV, FRONT_MD, FRONT_PNG = "pareto.csv", "pareto.md", "pareto.png"


def pareto_front(study: optuna.Study) -> list[FrozenTrial]:
    """The complete, counted trials no other complete trial beats in every objective, by
    their first objective (the error), lowest first; a trial with an infinite objective (a
    diverged free run) is left out."""
    front = [t for t in study.best_trials if counted(t) and all(math.isfinite(v) for v in t.values)]
    return sorted(front, key=lambda t: (t.values[0], t.number))


@dataclass(frozen=True)
class FrontPoint:
    """A trial as a point of the trade: a complete trial, or a pruned one at its stop."""

    number: int
    values: tuple[float, ...]
    params: dict[str, Any]
    #: the epochs a pruned trial had trained when it stopped (None: complete)
    stopped_epochs: int | None = None

    @property
    def stopped(self) -> str:
        """``pruned at epoch k`` for a pruned trial, empty for a complete one."""
        return "" if self.stopped_epochs is None else f"pruned at epoch {self.stopped_epochs}"


def study_points(study: optuna.Study) -> list[FrontPoint]:
    """The counted trials with finite objectives: complete ones, and pruned ones that recorded
    their objectives when pruned."""
    points = []
    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)):
        values = t.values if t.state == TrialState.COMPLETE else t.user_attrs.get(STOPPED_VALUES)
        if not counted(t) or not values or not all(math.isfinite(v) for v in values):
            continue
        epochs = None if t.state == TrialState.COMPLETE else int(t.user_attrs[STOPPED_EPOCHS])
        points.append(FrontPoint(t.number, tuple(values), dict(t.params), epochs))
    return points


def non_dominated(points: Sequence[FrontPoint]) -> list[FrontPoint]:
    """The points no other point beats in every objective (lower or equal in all, lower in
    one), lowest first objective first."""

    def beats(a: FrontPoint, b: FrontPoint) -> bool:
        pairs = list(zip(a.values, b.values, strict=True))
        return all(x <= y for x, y in pairs) and any(x < y for x, y in pairs)

    front = [p for p in points if not any(beats(q, p) for q in points)]
    return sorted(front, key=lambda p: (p.values[0], p.number))


def pareto_points(study: optuna.Study) -> list[FrontPoint]:
    """The Pareto front over complete and pruned trials (`study_points`)."""
    return non_dominated(study_points(study))


def objective_names(study: optuna.Study) -> list[str]:
    """The study's objective names as the sweeper stored them (else ``objective_<i>``)."""
    names = study.user_attrs.get("objectives")
    return list(names) if names else [f"objective_{i}" for i in range(len(study.directions))]


def front_rows(front: Sequence[FrontPoint], objectives: Sequence[str]) -> list[dict[str, Any]]:
    """One row per front point: its trial, its objective values, where a pruned trial
    stopped, its parameters."""
    names = sorted({name for p in front for name in p.params})
    return [
        {
            "trial": p.number,
            **dict(zip(objectives, p.values, strict=True)),
            "stopped": p.stopped,
            **{name: p.params.get(name, "") for name in names},
        }
        for p in front
    ]


def write_front(
    study: optuna.Study, directory: Path, objectives: Sequence[str] | None = None
) -> list[FrontPoint]:
    """Write ``pareto.csv``, ``pareto.md`` and ``pareto.png`` of ``study`` to ``directory``;
    return the front over complete and pruned trials (`pareto_points`)."""
    objectives = list(objectives or objective_names(study))
    directory.mkdir(parents=True, exist_ok=True)
    front = pareto_points(study)
    rows = front_rows(front, objectives)
    columns = list(rows[0]) if rows else ["trial", *objectives, "stopped"]
    with (directory / FRONT_CSV).open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    (directory / FRONT_MD).write_text(markdown_table(study.study_name, rows, columns))
    _plot_front(study, objectives, directory / FRONT_PNG)
    log.info(
        "Pareto front of '%s': %d trial(s) (%d of them pruned), in %s",
        study.study_name,
        len(front),
        sum(p.stopped_epochs is not None for p in front),
        directory / FRONT_MD,
    )
    return front


def markdown_table(title: str, rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """The front as a Markdown table under a heading naming the study."""
    lines = [
        f"# Pareto front of study `{title}`",
        "",
        "Every objective is minimised; no trial below is beaten in all of them by another. "
        "A pruned trial (`stopped`) is its model as it stood when pruned: a point at its own "
        "fidelity; `experiment=best_<study>` trains the most accurate complete trial.",
        "",
        "| " + " | ".join(columns) + " |",
        "|" + "---|" * len(columns),
    ]
    lines += ["| " + " | ".join(_cell(row.get(c, "")) for c in columns) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _cell(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _plot_front(study: optuna.Study, objectives: Sequence[str], path: Path) -> None:
    """The first two objectives of every complete trial (filled) and every pruned trial at
    its stop (hollow), the front highlighted, joined and labelled with trial numbers."""
    import matplotlib.pyplot as plt

    if len(objectives) < 2:
        return
    points = study_points(study)
    front = non_dominated(points)
    figure, axes = plt.subplots(figsize=(7, 4.5))
    for pruned, label, style in ((False, "trial", {"color": "0.6"}),
                                 (True, "pruned trial at its stop",
                                  {"facecolors": "none", "edgecolors": "0.5"})):
        shown = [p for p in points if (p.stopped_epochs is not None) == pruned]
        if shown:
            axes.scatter([p.values[0] for p in shown], [p.values[1] for p in shown], s=18,
                         label=label, **style)
    axes.step(
        [p.values[0] for p in front],
        [p.values[1] for p in front],
        where="post",
        color="tab:red",
        marker="o",
        label="Pareto front",
    )
    for p in front:
        axes.annotate(
            str(p.number),
            (p.values[0], p.values[1]),
            textcoords="offset points",
            xytext=(4, 4),
            fontsize=8,
        )
    for axis, scale in enumerate((axes.set_xscale, axes.set_yscale)):
        values = [p.values[axis] for p in points]
        if values and min(values) > 0 and max(values) > 30 * min(values):
            scale("log")  # errors and costs of a study span decades
    axes.set_xlabel(OBJECTIVES.get(objectives[0], objectives[0]))
    axes.set_ylabel(OBJECTIVES.get(objectives[1], objectives[1]))
    axes.set_title(f"Pareto front of {study.study_name} ({len(points)} trials shown)")
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
