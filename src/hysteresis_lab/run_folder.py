"""The run folder: what one fit (``hysteresis-lab-train``, a paper model, a loop round) leaves
on disk, named in one place.

::

    <run folder>/
      model.ckpt | model.skops          the fitted model (a network | the SVM)
      metrics.json                      scores per test recording, their mean, training time
      fit_record.json                   what the fit depended on (`hysteresis_lab.fit_record`)
      rejected_refit_model.*            a loop refit that lost on validation: its own model
      rejected_refit_metrics.json       ... and its scores (``model.*`` holds its start)
      hysteresis_loops.png, residuals.png
      tensorboard/                      TensorBoard logs (``logger=none``: absent)
      checkpoints/, checkpoints_free_run/   Lightning's best-epoch checkpoints of each stage
                                        (and its last.ckpt while the fit is unfinished)
      fit_in_progress.json              a fit that has not finished: its fingerprint, so that
                                        a rerun resumes it from the last.ckpt files
      run.lock                          held (flock) by the process that runs in the folder

`pipeline` writes it, the loop sets a losing refit aside in it, `hysteresis-lab-evaluate` and
the benchmark scripts read it: all through `RunFolder`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.evaluation.report import write_json


@dataclass(frozen=True)
class RunFolder:
    """The files of one run under ``path`` (see the module docstring)."""

    path: Path

    MODEL_STEM: ClassVar[str] = "model"
    #: a network's checkpoint, then the SVM's file
    MODEL_SUFFIXES: ClassVar[tuple[str, ...]] = (".ckpt", ".skops")
    METRICS: ClassVar[str] = "metrics.json"
    FIT_RECORD: ClassVar[str] = "fit_record.json"
    REJECTED_REFIT_MODEL_STEM: ClassVar[str] = "rejected_refit_model"
    REJECTED_REFIT_METRICS: ClassVar[str] = "rejected_refit_metrics.json"
    TENSORBOARD: ClassVar[str] = "tensorboard"
    CHECKPOINTS: ClassVar[str] = "checkpoints"
    #: the free-run fine-tuning stage's (after a one-step stage)
    FREE_RUN_CHECKPOINTS: ClassVar[str] = "checkpoints_free_run"
    #: Lightning's checkpoint of a stage's last finished epoch (what a rerun resumes from)
    LAST_CHECKPOINT: ClassVar[str] = "last.ckpt"
    #: ``last.ckpt`` while it is written (a killed process may leave it)
    PARTIAL_CHECKPOINT: ClassVar[str] = "last.partial.ckpt"
    FIT_IN_PROGRESS: ClassVar[str] = "fit_in_progress.json"
    LOCK: ClassVar[str] = "run.lock"

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    # ------------------------------------------------------------------ paths
    @property
    def model_stem(self) -> Path:
        """Where the model is saved, without its suffix (`hysteresis_lab.models.io`)."""
        return self.path / self.MODEL_STEM

    @property
    def metrics(self) -> Path:
        return self.path / self.METRICS

    @property
    def fit_record(self) -> Path:
        return self.path / self.FIT_RECORD

    @property
    def rejected_refit_stem(self) -> Path:
        """Where a losing refit's own model is saved, without its suffix."""
        return self.path / self.REJECTED_REFIT_MODEL_STEM

    @property
    def rejected_refit_metrics(self) -> Path:
        return self.path / self.REJECTED_REFIT_METRICS

    @property
    def fit_in_progress(self) -> Path:
        return self.path / self.FIT_IN_PROGRESS

    @property
    def lock(self) -> Path:
        return self.path / self.LOCK

    def last_checkpoints(self) -> list[Path]:
        """The stages' ``last.ckpt`` files (those of an unfinished fit) and any partly
        written one."""
        stages = (self.CHECKPOINTS, self.FREE_RUN_CHECKPOINTS)
        names = (self.LAST_CHECKPOINT, self.PARTIAL_CHECKPOINT)
        found = (self.path / stage / name for stage in stages for name in names)
        return [path for path in found if path.is_file()]

    def figure(self, name: str) -> Path:
        """A figure of the run (``hysteresis_loops``, ``residuals``) as PNG."""
        return self.path / f"{name}.png"

    def model_file(self) -> Path | None:
        """The saved model (``model.ckpt`` or ``model.skops``), None when there is none."""
        return _first_existing(self.model_stem, self.MODEL_SUFFIXES)

    def rejected_refit_model_file(self) -> Path | None:
        """A losing refit's own model, None when the run kept its refit."""
        return _first_existing(self.rejected_refit_stem, self.MODEL_SUFFIXES)

    # ------------------------------------------------------------------ documents
    def read_fit_in_progress(self) -> str | None:
        """The fingerprint of the unfinished fit in the folder, None when there is none."""
        try:
            return str(json.loads(self.fit_in_progress.read_text())["fingerprint"])
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def start_fit(self, fingerprint: str) -> None:
        """Mark a fit with ``fingerprint`` unfinished (until `finish_fit`)."""
        write_json({"fingerprint": fingerprint}, self.fit_in_progress)

    def claim_fit(self, fingerprint: str, resume: bool) -> bool:
        """Mark the fit with ``fingerprint`` unfinished here (until `finish_fit`); whether it
        goes on from the last checkpoints of an interrupted fit with the same fingerprint
        (``resume``). An interrupted fit with another fingerprint is refused when
        ``resume``, else started over."""
        interrupted = self.read_fit_in_progress()
        if resume and interrupted is not None and interrupted != fingerprint:
            raise ConfigError(
                f"{self.path} holds a training interrupted with other settings (model, "
                "data, trainer, seed or start differ). Fix: rerun it with its own settings to "
                f"resume it, use another folder (hydra.run.dir=...), or delete "
                f"{self.fit_in_progress} to start over there."
            )
        self.start_fit(fingerprint)
        return resume and interrupted == fingerprint

    def finish_fit(self) -> None:
        """The fit finished: nothing to resume, so its ``last.ckpt`` files and mark go."""
        for path in [*self.last_checkpoints(), self.fit_in_progress]:
            path.unlink(missing_ok=True)

    def read_metrics(self) -> dict[str, Any]:
        return json.loads(self.metrics.read_text())

    def write_metrics(self, document: dict[str, Any]) -> None:
        write_json(document, self.metrics)

    def read_rejected_refit_metrics(self) -> dict[str, Any]:
        return json.loads(self.rejected_refit_metrics.read_text())

    def write_rejected_refit_metrics(self, document: dict[str, Any]) -> None:
        write_json(document, self.rejected_refit_metrics)

    def set_model_aside_as_rejected(self, model_path: Path) -> Path:
        """Rename the run's model (``model_path``) and metrics to the rejected refit's names
        (the loop's refit that validation refused); returns the model's new path."""
        aside = self.rejected_refit_stem.with_suffix(Path(model_path).suffix)
        Path(model_path).replace(aside)
        self.metrics.replace(self.rejected_refit_metrics)
        return aside


def _first_existing(stem: Path, suffixes: tuple[str, ...]) -> Path | None:
    for suffix in suffixes:
        path = stem.with_suffix(suffix)
        if path.is_file():
            return path
    return None


@dataclass(frozen=True)
class LoopFolder:
    """The folder of one ``hysteresis-lab-loop`` run::

        <loop folder>/
          loop_report.json, loop_report.md, loops_before_after.png
          figures/round_<n>_<name>.png   the report's figures of round n (residual, scores,
                                         added_<effect>), linked from loop_report.md
          round_<n>/                     a `RunFolder` (the round's fit), with the round's
                                         residual_analysis.json and residual_diagnostics.png
            refit_lr_<rate>/             a `RunFolder` per refit rate, when a round tried several
    """

    path: Path

    REPORT_JSON: ClassVar[str] = "loop_report.json"
    REPORT_MD: ClassVar[str] = "loop_report.md"
    FIGURES: ClassVar[str] = "figures"
    BEFORE_AFTER: ClassVar[str] = "loops_before_after.png"

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    @property
    def report_json(self) -> Path:
        return self.path / self.REPORT_JSON

    @property
    def report_md(self) -> Path:
        return self.path / self.REPORT_MD

    @property
    def before_after_figure(self) -> Path:
        """The test recordings' free run before (the start) and after (the result)."""
        return self.path / self.BEFORE_AFTER

    def figure(self, number: int, name: str) -> Path:
        """Round ``number``'s report figure ``name`` (PNG)."""
        return self.path / self.FIGURES / f"round_{number}_{name}.png"

    def relative(self, path: Path) -> str:
        """``path`` as the report links it: relative to the loop folder, with ``/``."""
        return Path(path).relative_to(self.path).as_posix()

    def round_dir(self, number: int) -> Path:
        """Round ``number``'s folder (round 0: the start model)."""
        return self.path / f"round_{number}"

    @staticmethod
    def refit_dir(round_dir: Path, rate: float | None, several: bool) -> Path:
        """Where a round's fit at ``rate`` lands: its own ``refit_lr_<rate>`` folder when the
        round tried ``several`` rates, else the round's folder."""
        return Path(round_dir) / f"refit_lr_{rate:.3g}" if several else Path(round_dir)
