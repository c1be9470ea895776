"""Batches sliced from tensors already in memory, handed out a block of batches at a time.

A ``DataLoader`` that fetches and collates sample by sample costs more than a small
network's step; here one permutation per epoch (drawn as ``RandomSampler`` draws it:
``torch.randperm(n, generator=generator)``, so the same seed gives the same batches) is cut
into batches of ``batch_size`` rows, and the tensors are indexed once per batch (the same
batches, epoch by epoch, as ``BatchSampler(RandomSampler(data, generator=generator))``).

With ``per_step > 1`` the loader yields lists of ``per_step`` batches: the training loop's
fixed cost (Lightning's hooks, callbacks, progress bar) is then paid once per block instead
of once per batch, while the model still takes one optimiser step per batch
(`hysteresis_lab.models.base.NarxModule.training_step`; `hysteresis_lab.models.base.batches_of`
tells a batch from a block). ``per_step == 1`` yields the batches themselves, ``(x, target)``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import torch
from torch.utils.data import DataLoader, Dataset, Sampler


class BatchBlocks(Sampler[torch.Tensor | list[torch.Tensor]]):
    """Row indices per batch (``per_step == 1``), or lists of ``per_step`` of them (the last
    list may be shorter), from one order per epoch."""

    def __init__(
        self,
        n: int,
        batch_size: int,
        per_step: int = 1,
        shuffle: bool = False,
        generator: torch.Generator | None = None,
    ) -> None:
        if batch_size < 1 or per_step < 1:
            raise ValueError(f"batch_size={batch_size} and per_step={per_step} must be >= 1")
        self.n, self.batch_size, self.per_step = n, batch_size, per_step
        self.shuffle, self.generator = shuffle, generator

    def __iter__(self) -> Iterator[torch.Tensor | list[torch.Tensor]]:
        if self.shuffle:
            order = torch.randperm(self.n, generator=self.generator)
            # RandomSampler draws one more permutation when a pass ends and uses none of it:
            # drawn here too, so the generator gives every later epoch the same order
            torch.randperm(self.n, generator=self.generator)
        else:
            order = torch.arange(self.n)
        batches = order.split(self.batch_size)
        if self.per_step == 1:
            yield from batches
            return
        for first in range(0, len(batches), self.per_step):
            yield list(batches[first : first + self.per_step])

    def __len__(self) -> int:
        return math.ceil(math.ceil(self.n / self.batch_size) / self.per_step)


class SlicedTensors(Dataset):
    """Tensors of equal length; item ``[rows]``: the tuple of their slices (a batch), item
    ``[[rows, rows, ...]]``: a list of such tuples (a block)."""

    def __init__(self, *tensors: torch.Tensor) -> None:
        if len({len(t) for t in tensors}) != 1:
            raise ValueError("all tensors must have the same length")
        self.tensors = tensors

    def __len__(self) -> int:
        return len(self.tensors[0])

    def __getitem__(
        self, rows: torch.Tensor | list[torch.Tensor]
    ) -> tuple[torch.Tensor, ...] | list[tuple[torch.Tensor, ...]]:
        if isinstance(rows, torch.Tensor):
            return tuple(t[rows] for t in self.tensors)
        return [tuple(t[part] for t in self.tensors) for part in rows]


def block_loader(
    tensors: tuple[torch.Tensor, ...],
    batch_size: int,
    per_step: int = 1,
    shuffle: bool = False,
    generator: torch.Generator | None = None,
    num_workers: int = 0,
) -> DataLoader:
    """A loader of batches (``per_step == 1``) or blocks of batches sliced from ``tensors``."""
    dataset = SlicedTensors(*tensors)
    sampler = BatchBlocks(len(dataset), batch_size, per_step, shuffle, generator)
    return DataLoader(dataset, sampler=sampler, batch_size=None, num_workers=num_workers)
