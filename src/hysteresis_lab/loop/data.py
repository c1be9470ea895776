"""Which recordings play which role in the loop: train, validate, choose, report.

The effect a round adds is chosen from the residual of recordings that the before/after
numbers (the test recordings) do not use, and a refit is judged on recordings it did not
train on:

* **validation** (judges every refit): the data set's validation recordings, or, where it
  has none, a held-out stretch at the end of every training recording (``loop.holdout``,
  a share of its samples). The model trains on the rest; the stretch is scored on the free
  run of the whole recording, simulated end to end (a model that simulates from rest has no
  other state to start the stretch from);
* **diagnosis** (chooses the effect): the validation data, or the recordings named in
  ``data.diagnose=[...]``: names of the data set's validation or test recordings (a test
  recording named there leaves the before/after set) or files, read like ``data.test``;
* **test** (before/after): the test recordings that are left.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hysteresis_lab.data.readers import read_recording
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError, DataError

log = logging.getLogger(__name__)

#: fewest samples a held-out stretch (and the training part before it) may keep
MIN_STRETCH = 40


@dataclass(frozen=True, eq=False)
class Stretch:
    """A recording simulated end to end and scored from sample ``start`` on (compared by
    identity: the same stretch may play two roles)."""

    recording: Recording
    start: int = 0

    @property
    def name(self) -> str:
        return self.recording.name

    def describe(self) -> str:
        """``name`` or ``name[start:]`` (samples), as the report lists it."""
        n = self.recording.n_samples
        return self.name if self.start == 0 else f"{self.name}[{self.start}:{n}]"


@dataclass(frozen=True)
class LoopData:
    """The loop's data in their roles (see the module docstring)."""

    fit: DatasetSplits  # what every round trains on (and is tested on: ``fit.test``)
    validation: list[Stretch]
    diagnosis: list[Stretch]

    def roles(self) -> dict[str, list[str]]:
        """Every role's recordings (``name[a:b]`` for a stretch), for the report."""
        def cut(rec: Recording) -> str:
            full = rec.metadata.get("loop_cut_from")
            return f"{rec.name}[0:{rec.n_samples}]" if full else rec.name

        return {
            "train": [cut(r) for r in self.fit.train],
            "validation": [s.describe() for s in self.validation],
            "diagnosis": [s.describe() for s in self.diagnosis],
            "test": [r.name for r in self.fit.test],
        }


def loop_data(splits: DatasetSplits, data: DataSpec, holdout: float) -> LoopData:
    """The recordings of ``splits`` in the loop's roles; ``data.diagnose`` names the
    diagnosis recordings (default: the validation data)."""
    named = list(data.diagnose)
    chosen, moved = _diagnosis_recordings(splits, named, data)
    test = [r for r in splits.test if r.name not in moved]
    if moved and not test:  # (no test recordings at all: the pipeline says so, with the fix)
        raise ConfigError(
            f"data.diagnose={named} takes every test recording: none is left for the "
            "before/after numbers. Fix: name fewer test recordings there (or none: the "
            "validation data then choose)."
        )
    if splits.val:
        fit = dataclasses.replace(splits, test=test)
        validation = [Stretch(r) for r in splits.val]
    else:
        train, validation = _held_out_stretches(splits.train, holdout)
        fit = dataclasses.replace(splits, train=train, test=test)
    diagnosis = [Stretch(r) for r in chosen] or validation
    return LoopData(fit, validation, diagnosis)


def _held_out_stretches(
    recordings: Sequence[Recording], holdout: float
) -> tuple[list[Recording], list[Stretch]]:
    """Each training recording's first ``1 - holdout`` share to train on, and the whole
    recording scored from the cut on."""
    train, stretches = [], []
    for rec in recordings:
        cut = int(round((1.0 - holdout) * rec.n_samples))
        if min(cut, rec.n_samples - cut) < MIN_STRETCH:
            raise DataError(
                f"has {rec.n_samples} samples: a held-out stretch of loop.holdout={holdout:g} "
                f"leaves {cut} to train on and {rec.n_samples - cut} to validate on (at least "
                f"{MIN_STRETCH} each).",
                source=f"training recording '{rec.name}'",
                fix="give validation recordings (data.val=[...]), a longer training recording, "
                "or another loop.holdout",
            )
        metadata = {**rec.metadata, "loop_cut_from": rec.n_samples}
        train.append(dataclasses.replace(rec, u=rec.u[:cut], y=rec.y[:cut], metadata=metadata))
        stretches.append(Stretch(rec, cut))
    log.info("no validation recordings: the last %g %% of every training recording is held out "
             "(%s)", 100 * holdout, ", ".join(s.describe() for s in stretches))
    return train, stretches


def _diagnosis_recordings(
    splits: DatasetSplits, named: Sequence[str], data: DataSpec
) -> tuple[list[Recording], set[str]]:
    """The recordings ``named`` (data set names or files) and the test names among them."""
    by_name = {r.name: r for r in [*splits.val, *splits.test]}
    training = {r.name for r in splits.train}
    chosen, moved = [], set()
    for entry in map(str, named):
        if entry in by_name:
            chosen.append(by_name[entry])
            moved |= {entry} & {r.name for r in splits.test}
        elif entry in training:
            raise ConfigError(
                f"data.diagnose names '{entry}', a training recording: its residual is what the "
                "model was fitted to. Fix: name validation or test recordings "
                f"({sorted(by_name)}) or files."
            )
        elif Path(entry).is_file():
            chosen.append(read_recording(entry, **data.recording_options))
        else:
            raise ConfigError(
                f"data.diagnose names '{entry}': no recording of data '{splits.name}' and no "
                f"file has that name. Fix: one of {sorted(by_name)} or a file path."
            )
    for rec in chosen:
        if not np.isclose(rec.fs, splits.fs) or rec.nu != splits.nu or rec.ny != splits.ny:
            raise DataError(
                f"has {rec.nu} input(s), {rec.ny} output(s) at {rec.fs:g} Hz; the data set "
                f"{splits.nu}, {splits.ny} at {splits.fs:g} Hz.",
                source=f"diagnosis recording '{rec.name}'",
                fix="record it like the training data",
            )
    return chosen, moved

