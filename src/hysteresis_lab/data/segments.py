"""Free-run segments of the training recordings, for simulation-error training.

A segment is ``first_target + steps`` consecutive samples of one recording, scaled like the
one-step windows: the model starts from the first ``first_target`` measured outputs and
simulates the remaining ``steps`` from the input alone (`NarxModule.simulate_scaled`).
"""

from __future__ import annotations

import logging

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, TensorDataset

from hysteresis_lab.data.blocks import block_loader
from hysteresis_lab.data.datamodules import WindowDataModule, random_holdout
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import ConfigError

log = logging.getLogger(__name__)

#: the data sets already told that their training recordings also validate
_TOLD_NO_VALIDATION: set[tuple[str, tuple[str, ...]]] = set()


class SegmentDataModule(L.LightningDataModule):
    """Batches ``(u, y)`` of shape (B, first_target + steps, nu / ny), scaled.

    Segments start every ``steps // 2`` samples. Validation segments come from the validation
    recordings when there are any, otherwise a random share (``val_fraction`` of the window
    module, same seed) of the training segments is held out.
    """

    def __init__(self, windows: WindowDataModule, steps: int) -> None:
        super().__init__()
        if steps < 1:
            raise ConfigError(
                f"training.horizon={steps} must be >= 1 for simulation-error training."
            )
        self.windows = windows
        self.length = windows.window.first_target + steps
        self.stride = max(1, steps // 2)
        self._data: dict[str, TensorDataset] = {}

    def setup(self, stage: str | None = None) -> None:
        if self._data:
            return
        splits = self.windows.splits
        train_u, train_y = self._segments(splits.train)
        if splits.val:
            val_u, val_y = self._segments(splits.val)
        else:
            val, keep = random_holdout(len(train_u), self.windows.val_fraction, self.windows.seed)
            if len(keep) == 0:
                raise ConfigError(
                    f"only {len(train_u)} free-run segment(s) of {self.length} samples fit in the "
                    "training data; none would be left for training after the validation share. "
                    "Fix: a smaller training.horizon."
                )
            val_u, val_y, train_u, train_y = (
                train_u[val],
                train_y[val],
                train_u[keep],
                train_y[keep],
            )
        self._data = {
            "train": TensorDataset(torch.from_numpy(train_u), torch.from_numpy(train_y)),
            "val": TensorDataset(torch.from_numpy(val_u), torch.from_numpy(val_y)),
        }
        log.info(
            "simulation-error training: %d training and %d validation segments of %d samples",
            len(train_u),
            len(val_u),
            self.length,
        )

    def _segments(self, recordings: list[Recording]) -> tuple[np.ndarray, np.ndarray]:
        s = self.windows.scaler
        us, ys = [], []
        for rec in recordings:
            u = ((rec.u - s.u_offset) / s.u_scale).astype(np.float32)
            y = ((rec.y - s.y_offset) / s.y_scale).astype(np.float32)
            for start in range(0, rec.n_samples - self.length + 1, self.stride):
                us.append(u[start : start + self.length])
                ys.append(y[start : start + self.length])
        longest = max(rec.n_samples for rec in recordings)
        most = longest - self.windows.window.first_target
        if not us:
            raise ConfigError(
                f"free-run segments of {self.length} samples (training.horizon plus the "
                f"{self.windows.window.first_target} initial samples) do not fit in recordings "
                f"of at most {longest} samples. Fix: training.horizon={max(1, most)} or less."
            )
        short = [rec.name for rec in recordings if rec.n_samples < self.length]
        if short:
            log.warning(
                "recordings %s are shorter than one free-run segment (%d samples) and take no "
                "part in simulation-error training; training.horizon=%d or less would use them",
                short, self.length, min(r.n_samples for r in recordings)
                - self.windows.window.first_target,
            )
        return np.stack(us), np.stack(ys)

    def train_dataloader(self) -> DataLoader:
        """Shuffled batches sliced from the segments in memory (the batches of
        ``DataLoader(..., shuffle=True, generator=...)``, without its per-sample collation)."""
        self.setup()
        generator = torch.Generator().manual_seed(self.windows.seed)
        return block_loader(self._data["train"].tensors, self.windows.batch_size,
                            shuffle=True, generator=generator)

    def val_dataloader(self) -> DataLoader:
        self.setup()
        return block_loader(self._data["val"].tensors, self.windows.batch_size)


class RecordingDataModule(L.LightningDataModule):
    """Whole recordings ``(u, y)`` (1, N, nu / ny), scaled, one per batch, for models that
    simulate from rest (a grey-box's physical state is known only there).

    An epoch visits every training recording ``repeats`` times, one per batch, or with
    ``together`` all of them in one block (a full-batch step: L-BFGS); validation uses the
    validation recordings, or the training recordings when there are none (said in the log).
    """

    def __init__(self, windows: WindowDataModule, repeats: int = 1, together: bool = False
                 ) -> None:
        super().__init__()
        self.windows = windows
        self.repeats = repeats
        self.together = together
        self._data: dict[str, list[tuple[torch.Tensor, torch.Tensor]]] = {}

    def setup(self, stage: str | None = None) -> None:
        if self._data:
            return
        splits = self.windows.splits
        said = (splits.name, tuple(rec.name for rec in splits.train))
        if not splits.val and said not in _TOLD_NO_VALIDATION:  # once per data set and process
            _TOLD_NO_VALIDATION.add(said)
            log.warning(
                "no validation recordings: model selection reads the free run of the training "
                "recordings (give data.val, or for data=default data.splits.val_samples > 0)"
            )
        train = self._scaled(splits.train) * self.repeats
        self._data = {"train": [train] if self.together else train,
                      "val": self._scaled(splits.val or splits.train)}
        log.info("simulation-error training on %d whole recording(s), validation on %d",
                 len(splits.train), len(self._data["val"]))

    def _scaled(self, recordings: list[Recording]) -> list[tuple[torch.Tensor, torch.Tensor]]:
        s = self.windows.scaler
        return [
            (torch.from_numpy(((rec.u - s.u_offset) / s.u_scale).astype(np.float32))[None],
             torch.from_numpy(((rec.y - s.y_offset) / s.y_scale).astype(np.float32))[None])
            for rec in recordings
        ]

    def train_dataloader(self) -> DataLoader:
        self.setup()
        generator = torch.Generator().manual_seed(self.windows.seed)
        return DataLoader(self._data["train"], batch_size=None, shuffle=True,
                          generator=generator)

    def val_dataloader(self) -> DataLoader:
        self.setup()
        return DataLoader(self._data["val"], batch_size=None)


def simulation_data(windows: WindowDataModule, model: L.LightningModule, steps: int
                    ) -> L.LightningDataModule:
    """The free-run training data a model takes: whole recordings for models that simulate
    from rest (``whole_recordings``), else ``steps``-sample segments."""
    if getattr(model, "whole_recordings", False):
        return RecordingDataModule(windows, int(getattr(model, "recordings_per_epoch", 1)),
                                   together=bool(getattr(model, "full_batch_steps", False)))
    return SegmentDataModule(windows, steps)
