"""Which recordings play which role in the loop: choose, fit, report.

The identification record (the data set's training and validation recordings) both
chooses the structure and fits the result; the test recordings never inform a choice:

* **folds** (choose): ``loop.folds`` = k folds of the identification record. Where it has
  at least k recordings, each fold holds out whole recordings (every k-th); else every
  recording is cut into k contiguous blocks and fold j holds out block j of each. A fold's
  models train on the rest, keep the epoch whose loss is best on a random share of that
  rest (as any fit without validation recordings: what a fold holds out only judges it;
  the length the final refit trains comes from those epochs), and are scored on the free
  run of each held-out recording, simulated end to end (a model that simulates from rest
  has no other state to start a block from), over the held-out samples only;
* **diagnosis** (chooses the effect): the folds' held-out residuals together, or the
  recordings named in ``data.diagnose=[...]``: names of the data set's test recordings (a
  test recording named there leaves the before/after set) or files, read like ``data.test``;
* **fit** (the result): the whole identification record, which the structure the folds
  chose is refitted on (`LoopData.whole`: every sample trains, for the folds' length);
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
    #: first sample after the scored part (None: the recording's end)
    end: int | None = None

    @property
    def name(self) -> str:
        return self.recording.name

    @property
    def stop(self) -> int:
        """First sample after the scored part."""
        return self.recording.n_samples if self.end is None else self.end

    def describe(self) -> str:
        """``name`` or ``name[start:stop]`` (samples), as the report lists it."""
        whole = self.start == 0 and self.stop == self.recording.n_samples
        return self.name if whole else f"{self.name}[{self.start}:{self.stop}]"

    def scored(self) -> Recording:
        """The scored part of the recording."""
        rec = self.recording
        return dataclasses.replace(rec, u=rec.u[self.start:self.stop],
                                   y=rec.y[self.start:self.stop])


@dataclass(frozen=True)
class Fold:
    """One fold of the identification record: what its models train on (``fit``, tested on
    the data set's test recordings) and the held-out stretches that score them."""

    fit: DatasetSplits
    held_out: list[Stretch]

    def describe(self) -> str:
        return ", ".join(s.describe() for s in self.held_out)


@dataclass(frozen=True)
class LoopData:
    """The loop's data in their roles (see the module docstring)."""

    #: the whole identification record (the result is fitted on it) and the tests
    fit: DatasetSplits
    folds: list[Fold]
    diagnosis: list[Stretch]

    @property
    def whole(self) -> DatasetSplits:
        """`fit` to refit the result on: every identification sample trains (nothing is held
        out for a validation share; its validation reads the same recordings)."""
        return dataclasses.replace(self.fit, val=list(self.fit.train))

    @property
    def validation(self) -> list[Stretch]:
        """Every fold's held-out stretches (together: the identification record)."""
        return [s for fold in self.folds for s in fold.held_out]

    def roles(self) -> dict[str, list[str]]:
        """Every role's recordings (``name[a:b]`` for a stretch), for the report."""
        return {
            "train": [r.name for r in self.fit.train],
            "folds": [fold.describe() for fold in self.folds],
            "diagnosis": [s.describe() for s in self.diagnosis],
            "test": [r.name for r in self.fit.test],
        }


def loop_data(splits: DatasetSplits, data: DataSpec, folds: int) -> LoopData:
    """The recordings of ``splits`` in the loop's roles, with ``folds`` folds of the
    identification record (training and validation recordings); ``data.diagnose`` names
    the diagnosis recordings (default: the folds' held-out stretches)."""
    named = list(data.diagnose)
    chosen, moved = _diagnosis_recordings(splits, named, data)
    test = [r for r in splits.test if r.name not in moved]
    if moved and not test:  # (no test recordings at all: the pipeline says so, with the fix)
        raise ConfigError(
            f"data.diagnose={named} takes every test recording: none is left for the "
            "before/after numbers. Fix: name fewer test recordings there (or none: the "
            "folds then choose)."
        )
    identification = [*splits.train, *splits.val]
    fit = dataclasses.replace(splits, train=identification, val=[], test=test)
    made = cross_validation_folds(fit, folds)
    held = [s for fold in made for s in fold.held_out]
    diagnosis = [Stretch(r) for r in chosen] or held
    log.info("loop folds: %s", "; ".join(fold.describe() for fold in made))
    return LoopData(fit, made, diagnosis)


def cross_validation_folds(fit: DatasetSplits, k: int) -> list[Fold]:
    """``k`` folds of ``fit.train``: whole recordings (every k-th) where there are at least
    ``k``, else the j-th of ``k`` contiguous blocks of every recording. A fold's fit
    chooses its checkpoint on a random share of its own training part, never on what the
    fold holds out (that would choose on the data that judge it)."""
    recordings = fit.train
    if k < 2:
        raise ConfigError(f"loop.folds={k} must be at least 2. Fix: e.g. loop.folds=3.")
    if len(recordings) >= k:
        return [Fold(dataclasses.replace(fit, train=[r for i, r in enumerate(recordings)
                                                     if i % k != j]),
                     [Stretch(r) for r in recordings[j::k]]) for j in range(k)]
    folds = []
    for j in range(k):
        train, held = [], []
        for rec in recordings:
            a, b = _block(rec, j, k)
            train += [piece for piece in (_piece(rec, 0, a), _piece(rec, b, rec.n_samples))
                      if piece is not None]
            held.append(Stretch(rec, a, b))
        folds.append(Fold(dataclasses.replace(fit, train=train), held))
    return folds


def _block(rec: Recording, j: int, k: int) -> tuple[int, int]:
    """Samples ``[a, b)`` of block ``j`` of ``k`` of ``rec``, at least `MIN_STRETCH` long."""
    n = rec.n_samples
    if n // k < MIN_STRETCH:
        raise DataError(
            f"has {n} samples: {k} folds (loop.folds) leave {n // k} per block (at least "
            f"{MIN_STRETCH}).",
            source=f"identification recording '{rec.name}'",
            fix="fewer folds (e.g. loop.folds=2) or a longer recording",
        )
    return round(j * n / k), round((j + 1) * n / k)


def _piece(rec: Recording, a: int, b: int) -> Recording | None:
    """Samples ``[a, b)`` of ``rec`` to train on (None: too short to train on)."""
    if b - a < MIN_STRETCH:
        return None
    if a == 0 and b == rec.n_samples:
        return rec
    metadata = {**rec.metadata, "loop_piece": [a, b]}
    return dataclasses.replace(rec, name=f"{rec.name}[{a}:{b}]", u=rec.u[a:b], y=rec.y[a:b],
                               metadata=metadata)


def _diagnosis_recordings(
    splits: DatasetSplits, named: Sequence[str], data: DataSpec
) -> tuple[list[Recording], set[str]]:
    """The recordings ``named`` (data set names or files) and the test names among them."""
    by_name = {r.name: r for r in splits.test}
    training = {r.name for r in [*splits.train, *splits.val]}
    chosen, moved = [], set()
    for entry in map(str, named):
        if entry in by_name:
            chosen.append(by_name[entry])
            moved |= {entry} & {r.name for r in splits.test}
        elif entry in training:
            raise ConfigError(
                f"data.diagnose names '{entry}', an identification recording: its residual is "
                "what the result is fitted to (the folds already diagnose it). Fix: name test "
                "recordings "
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

