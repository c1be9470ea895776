"""Model augmentation: a network that learns on top of a fitted baseline model.

``model.baseline=<run folder or model file>`` gives a network one more input per output:
the baseline's free-run simulation of that output from the measured inputs. A physical
model that extrapolates (the grey-box's Bouc–Wen cell, the linear model with its catalogue
effects) then carries what the identification data barely show, and the network learns
what the physics lacks (the physics-guided networks of Bolderman et al., IEEE TCST 2024,
and the model augmentation of Hoekstra et al., 2024). SUBNET's linear start then fits a
linear model of the inputs and the baseline's output: training begins near the baseline.

The baseline's file travels inside the network's saved model (`to_checkpoint`), so a loaded
model recomputes its baseline channels on any recording (`channels_for`) without the
original run folder.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.models.interface import SystemModel
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.run_folder import RunFolder

log = logging.getLogger(__name__)

#: the ``model`` config key naming the baseline
SETTING = "baseline"
#: prefix of the input channels the baseline adds
CHANNEL_PREFIX = "baseline_"


@dataclass
class Baseline:
    """A fitted model whose free run becomes extra input channels of another model.

    ``payload``: the bytes of its model file (``suffix`` ``.ckpt`` or ``.skops``);
    ``source``: where it was read from (for messages and reports).
    """

    model: SystemModel
    payload: bytes
    suffix: str
    source: str

    @classmethod
    def load(cls, path: str | Path) -> Baseline:
        """The baseline saved at ``path``: a model file or a run folder holding one."""
        from hysteresis_lab.models.io import load_model

        path = Path(path).expanduser()
        file = RunFolder(path).model_file() if path.is_dir() else path
        if file is None or not file.is_file():
            raise ConfigError(
                f"model.baseline={str(path)!r}: no fitted model there. Fix: train the "
                "baseline first (e.g. hysteresis-lab-train model=greybox) and pass its run "
                "folder or its model.ckpt."
            )
        model = load_model(file)
        return cls(model, file.read_bytes(), file.suffix, str(file))

    @classmethod
    def from_checkpoint(cls, entry: Mapping[str, Any]) -> Baseline:
        """The baseline stored by `to_checkpoint` inside another model's checkpoint."""
        from hysteresis_lab.models.io import load_model

        payload = entry["data"].numpy().tobytes()
        suffix = str(entry["suffix"])
        with tempfile.TemporaryDirectory() as folder:
            file = Path(folder) / f"baseline{suffix}"
            file.write_bytes(payload)
            model = load_model(file)
        return cls(model, payload, suffix, str(entry.get("source", "")))

    def to_checkpoint(self) -> dict[str, Any]:
        """Plain entries (loadable with ``weights_only=True``) that `from_checkpoint` reads."""
        data = torch.frombuffer(bytearray(self.payload), dtype=torch.uint8).clone()
        return {"data": data, "suffix": self.suffix, "source": self.source}

    @property
    def digest(self) -> str:
        """SHA-256 of the baseline's file: a finished fit is reused only with the same one."""
        return hashlib.sha256(self.payload).hexdigest()

    @property
    def n_inputs(self) -> int:
        """The measured inputs the baseline reads."""
        hparams = getattr(self.model, "hparams", {}) or {}
        return int(hparams.get("n_base_inputs") or hparams.get("nu") or self.model.nu)

    def channels_for(self, recordings: Sequence[Recording]) -> list[np.ndarray]:
        """The baseline's free run (T, ny) on each recording (its measured inputs only)."""
        from hysteresis_lab.evaluation.predict import free_run
        from hysteresis_lab.models.augment import for_model

        if not recordings:
            return []
        for rec in recordings:
            if rec.nu != self.n_inputs:
                raise DataError(
                    f"has {rec.nu} measured input(s); the baseline {self.source} reads "
                    f"{self.n_inputs}.",
                    source=f"recording '{rec.name}'",
                    fix="use a baseline fitted on the same inputs as this data set",
                )
        runs = free_run(self.model, for_model(self.model, recordings), self.model.window)
        for rec, y in zip(recordings, runs, strict=True):
            if not np.all(np.isfinite(y)):
                raise DataError(
                    f"the baseline {self.source} diverges in free run on it.",
                    source=f"recording '{rec.name}'",
                    fix="refit the baseline (a stable model) or leave model.baseline unset",
                )
        return runs

    def append_to(
        self, recordings: Sequence[Recording], measured: Sequence[Recording]
    ) -> list[Recording]:
        """``recordings`` with the baseline's free run of each ``measured`` recording (the
        same recordings before any other channel was added) as extra input channels."""
        runs = self.channels_for(measured)
        return [
            dataclasses.replace(
                rec, u=np.column_stack([rec.u, y]),
                u_names=(*rec.u_names, *(f"{CHANNEL_PREFIX}{name}" for name in rec.y_names)),
            )
            for rec, y in zip(recordings, runs, strict=True)
        ]

    def append_to_splits(self, data: DatasetSplits, measured: DatasetSplits) -> DatasetSplits:
        """Every recording of ``data`` with its baseline channels (see `append_to`)."""
        log.info("baseline %s: its free run is an input of the model", self.source)
        return dataclasses.replace(
            data,
            train=self.append_to(data.train, measured.train),
            val=self.append_to(data.val, measured.val),
            test=self.append_to(data.test, measured.test),
            metadata={"n_base_inputs": measured.nu, **data.metadata, SETTING: self.source},
        )


def baseline_of(spec: ModelSpec) -> Baseline | None:
    """The baseline a ``model`` config names (None when it names none); refused for a model
    that cannot take extra input channels (the physical models: they are the baselines)."""
    path = spec.settings.get(SETTING)
    if not path:
        return None
    from hysteresis_lab.models.physical_chain import PhysicalChainModule

    if not spec.is_network or issubclass(spec.cls, PhysicalChainModule):
        raise ConfigError(
            f"model.baseline is for the networks (ffnn, lstm, cnn, subnet, plugins); "
            f"{spec.cls.__name__} cannot take a baseline's output as an input. Fix: make "
            "this model the baseline of a network instead (model=subnet model.baseline=<its "
            "run folder>)."
        )
    return Baseline.load(str(path))
