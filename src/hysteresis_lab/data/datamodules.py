"""Lightning DataModules that turn `DatasetSplits` into scaled NARX regression windows."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, TensorDataset

from hysteresis_lab.data.blocks import block_loader
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.scaling import (
    DEFAULT_SCALING_MODE,
    PAPER_U_SCALE,
    PAPER_Y_SCALE,
    Scaler,
)
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import (
    Layout,
    Windows,
    WindowSpec,
    assemble,
    check_layout,
    make_windows,
)
from hysteresis_lab.errors import ConfigError

log = logging.getLogger(__name__)

#: training batches per Lightning step (`hysteresis_lab.data.blocks`): Lightning's fixed cost
#: per step, comparable to a small network's own step, is paid once per this many optimiser
#: steps, so that it no longer shows beside a bare PyTorch loop (`benchmarks/overhead.py`)
BATCHES_PER_STEP = 128


def random_holdout(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Sorted indices of a random ``fraction`` of ``n`` items (at least one) and of the rest."""
    order = np.random.default_rng(seed).permutation(n)
    n_val = max(1, int(round(fraction * n)))
    return np.sort(order[:n_val]), np.sort(order[n_val:])


class WindowDataModule(L.LightningDataModule):
    """Regression windows of any recordings, for estimation, validation and test.

    Validation windows come from ``splits.val`` when it has recordings; otherwise a random
    ``val_fraction`` of the training windows is held out (the study's 90/10 split), drawn
    with ``seed``. Batches are ``(x, target)``: ``x`` in the requested ``layout``, both
    scaled by ``scaler`` (fitted on the training recordings only). Batches are slices of
    tensors held in memory; the training and validation loaders hand them out
    ``batches_per_step`` at a time (a list of batches; one optimiser step per batch still),
    so that Lightning's fixed cost per step is paid once per block (1: plain batches).
    Lightning's own batch counts (progress bar, ``limit_train_batches``,
    ``val_check_interval``) count these blocks; ``trainer.global_step`` counts optimiser
    steps.
    """

    def __init__(
        self,
        splits: DatasetSplits,
        window: WindowSpec | None = None,
        layout: Layout = "flat",
        scaling: str = DEFAULT_SCALING_MODE,
        u_scale: float = PAPER_U_SCALE,
        y_scale: float = PAPER_Y_SCALE,
        val_fraction: float = 0.1,
        batch_size: int = 128,
        seed: int = 0,
        num_workers: int = 0,
        batches_per_step: int = BATCHES_PER_STEP,
    ) -> None:
        super().__init__()
        check_layout(layout)
        if not 0.0 < val_fraction < 1.0 and not splits.val:
            raise ConfigError(
                f"val_fraction={val_fraction} must lie strictly between 0 and 1 when the data set "
                "has no validation recordings. Fix: set data.val_fraction=0.1 or give data.val."
            )
        if batch_size < 1:
            raise ConfigError(f"batch_size={batch_size} must be >= 1. Fix: set data.batch_size.")
        if batches_per_step < 1:
            raise ConfigError(f"batches_per_step={batches_per_step} must be >= 1. Fix: e.g. 1 "
                              "(a Lightning step per batch) or 32.")
        self.splits = splits
        self.window = window or WindowSpec()
        self.layout: Layout = layout
        self.val_fraction = val_fraction
        self.batch_size = batch_size
        self.seed = seed
        self.num_workers = num_workers
        self.batches_per_step = batches_per_step
        self.scaler = Scaler.fit(splits.train, scaling, u_scale=u_scale, y_scale=y_scale)
        log.info(
            "%s: scaling=%s (scaled = (value - offset) / scale): u offset %s scale %s, "
            "y offset %s scale %s%s",
            splits.name,
            scaling,
            *(np.array2string(v, precision=4) for v in vars(self.scaler).values()),
            " (fitted to the training recordings)" if scaling == "standard" else "",
        )
        n_base = splits.metadata.get("n_base_inputs")
        if n_base is not None:  # effect operators appended to the measured inputs
            self.scaler = self.scaler.standardise_inputs_from(int(n_base), splits.train)
        self.train_windows: Windows | None = None
        self.val_windows: Windows | None = None
        self._tensors: dict[str, TensorDataset] = {}

    # ------------------------------------------------------------------ properties
    @property
    def fs(self) -> float:
        return self.splits.fs

    @property
    def nu(self) -> int:
        return self.splits.nu

    @property
    def ny(self) -> int:
        return self.splits.ny

    @property
    def test_recordings(self) -> list[Recording]:
        return self.splits.test

    # ------------------------------------------------------------------ Lightning hooks
    def setup(self, stage: str | None = None) -> None:
        if self.train_windows is not None:
            return
        train = make_windows(self.splits.train, self.window)
        if self.splits.val:
            val = make_windows(self.splits.val, self.window)
        else:
            held_out, kept = random_holdout(len(train), self.val_fraction, self.seed)
            val, train = train.take(held_out), train.take(kept)
        self.train_windows, self.val_windows = train, val
        self._tensors = {"train": self._to_tensors(train), "val": self._to_tensors(val)}
        log.info(
            "%s: %d training and %d validation windows (na=%d, nb=%d, nk=%d, layout=%s)",
            self.splits.name,
            len(train),
            len(val),
            self.window.na,
            self.window.nb,
            self.window.nk,
            self.layout,
        )

    def train_dataloader(self) -> DataLoader:
        generator = torch.Generator().manual_seed(self.seed)
        return self._loader("train", shuffle=True, generator=generator)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> list[DataLoader]:
        """One-step windows of each test recording (measured past outputs as regressors)."""
        return [
            DataLoader(self._to_tensors(make_windows(rec, self.window)), batch_size=4096)
            for rec in self.splits.test
        ]

    # ------------------------------------------------------------------ helpers
    def scale_windows(self, windows: Windows) -> tuple[np.ndarray, np.ndarray]:
        """Scaled regressors in this module's layout and scaled targets."""
        s = self.scaler
        u_past = (windows.u_past - s.u_offset) / s.u_scale
        y_past = (windows.y_past - s.y_offset) / s.y_scale
        target = (windows.target - s.y_offset) / s.y_scale
        x = assemble(u_past.astype(np.float32), y_past.astype(np.float32), self.layout)
        return x, target.astype(np.float32)

    def validation_mse(self, predict: Callable[[np.ndarray], np.ndarray]) -> float:
        """One-step MSE (scaled) of ``predict`` on the validation windows."""
        self.setup()
        x, target = self.scale_windows(self.val_windows)
        return float(np.mean((predict(x) - target) ** 2))

    def _to_tensors(self, windows: Windows) -> TensorDataset:
        x, target = self.scale_windows(windows)
        return TensorDataset(torch.from_numpy(x), torch.from_numpy(target))

    def _loader(self, split: str, shuffle: bool, **kwargs: Any) -> DataLoader:
        """Batches sliced from the split's tensors (shuffled: one permutation per epoch, as
        ``RandomSampler`` draws it), ``batches_per_step`` per item."""
        if split not in self._tensors:
            self.setup()
        return block_loader(
            self._tensors[split].tensors, self.batch_size, self.batches_per_step, shuffle,
            kwargs.get("generator"), self.num_workers,
        )


class PaperDataModule(WindowDataModule):
    """The study's protocol on the built-in simulated positioner.

    Training/validation: a 500-component multisine (0-500 Hz, +-100 V, 80,000 samples at
    20 kHz) cut into windows and split 90/10 at random; test: the twelve sines.
    ``effects`` switches and parameterises the simulator's blocks
    (``hysteresis_lab/conf/sim/positioner.yaml``).
    """

    def __init__(self, effects: dict[str, Any] | None = None, data_seed: int = 0, **kwargs: Any):
        from hysteresis_lab.sim.default_dataset import make_default_dataset

        super().__init__(make_default_dataset(effects=effects, seed=data_seed), **kwargs)
