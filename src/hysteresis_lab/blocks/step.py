"""One-sample steps of the blocks, in torch, for exporting a physical chain's simulation step.

A chain's state is one flat float64 vector per row, (B, n); each block reads its slice in
turn (`StepState.take`) and leaves its next value (`StepState.put`), so the state layout is the
blocks' order. Every block's state is zero at rest (zero input, zero output). The updates are
the physics floor's one-sample steps (`hysteresis_lab.physics`: ``tdf2_step``,
``bouc_wen_advance``, ``play_step``), the same arithmetic as the whole-recording passes.
"""

from __future__ import annotations

import torch
from torch import Tensor


def frozen(*tensors: Tensor) -> tuple[Tensor, ...]:
    """The tensors as they are; while tracing for export, as float64 constants of their
    current values. A step's coefficients derive from the raw parameters through functions
    (softplus, tan, ...) that ONNX runtimes compute in other precisions or not at all for
    float64; baked in, the exported step uses exactly the values the model simulates with."""
    if not torch.jit.is_tracing():
        return tensors
    return tuple(torch.from_numpy(t.detach().cpu().numpy().copy()) for t in tensors)


class StepState:
    """A flat state (B, n) read block by block; the next state is collected in the same order."""

    def __init__(self, state: Tensor) -> None:
        self.state = state
        self.position = 0
        self.parts: list[Tensor] = []

    def take(self, n: int) -> Tensor:
        """The next ``n`` columns (B, n)."""
        part = self.state[:, self.position : self.position + n]
        self.position += n
        return part

    def put(self, part: Tensor) -> None:
        """Append a block's next state (B, n)."""
        self.parts.append(part)

    def next_state(self) -> Tensor:
        """The collected next state (B, n); checks that every column was read."""
        if self.position != self.state.shape[1]:
            raise ValueError(f"the state has {self.state.shape[1]} columns, the blocks read "
                             f"{self.position}")
        if not self.parts:
            return self.state[:, :0]
        return torch.cat(self.parts, dim=1)


def delay_step(samples: int, x: Tensor, state: StepState) -> Tensor:
    """``samples`` of pure delay: a buffer of that many past inputs, oldest first."""
    if samples == 0:
        return x
    buffer = state.take(samples)
    state.put(torch.cat([buffer[:, 1:], x[:, None]], dim=1))
    return buffer[:, 0]
