"""One-sample steps of the blocks, in torch, for exporting a physical chain's simulation step.

A chain's state is one flat float64 vector per row, (B, n); each block reads its slice in
turn (`StepState.take`) and leaves its next value (`StepState.put`), so the state layout is the
blocks' order. Every block's state is zero at rest (zero input, zero output). The updates are
the same arithmetic as the whole-recording passes (``scipy.signal.lfilter``'s transposed
direct form II, `hysteresis_lab.sim.bouc_wen.advance`, the play recursion), written with
``torch.where`` instead of branches so that they trace to ONNX.
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


def tdf2_step(b: Tensor, a: Tensor, x: Tensor, state: StepState) -> Tensor:
    """One sample of ``lfilter(b, a, .)`` (transposed direct form II, ``a[0] = 1``): input
    (B,) -> output (B,); ``max(len(b), len(a)) - 1`` states."""
    n = max(b.shape[0], a.shape[0])
    if n == 1:
        return b[0] * x
    b = torch.cat([b, b.new_zeros(n - b.shape[0])]) if b.shape[0] < n else b
    a = torch.cat([a, a.new_zeros(n - a.shape[0])]) if a.shape[0] < n else a
    z = state.take(n - 1)
    y = z[:, 0] + b[0] * x
    nxt = [(z[:, i + 1] if i + 1 < n - 1 else 0.0) + x * b[i + 1] - y * a[i + 1]
           for i in range(n - 1)]
    state.put(torch.stack(nxt, dim=1))
    return y


def delay_step(samples: int, x: Tensor, state: StepState) -> Tensor:
    """``samples`` of pure delay: a buffer of that many past inputs, oldest first."""
    if samples == 0:
        return x
    buffer = state.take(samples)
    state.put(torch.cat([buffer[:, 1:], x[:, None]], dim=1))
    return buffer[:, 0]


def bouc_wen_advance(h: Tensor, dv: Tensor, a: Tensor, r1: Tensor, r2: Tensor) -> Tensor:
    """`hysteresis_lab.sim.bouc_wen.advance` for an input step ``dv`` (any sign, zero keeps
    ``h``), elementwise; ``h, dv`` broadcast against the per-element ``a, r1, r2``."""
    s = torch.where(dv > 0.0, torch.ones_like(dv), -torch.ones_like(dv))
    x = dv.abs()
    against = h * s < 0.0
    h_inf1 = s * a / r1
    h_new1 = h_inf1 + (h - h_inf1) * torch.exp(-r1 * x)
    done = against & (h_new1 * s <= 0.0)
    crossing = torch.log((h - h_inf1) / (-h_inf1)) / r1
    x_rest = torch.where(against, x - crossing, x)
    h_start = torch.where(against, torch.zeros_like(h), h)
    h_inf2 = s * a / r2
    h_new2 = h_inf2 + (h_start - h_inf2) * torch.exp(-r2 * x_rest)
    h_new = torch.where(done, h_new1, h_new2)
    return torch.where(dv != 0.0, h_new, h)


def play_step(v: Tensor, thresholds: Tensor, state: StepState) -> Tensor:
    """Play operators (B, m) of ``v`` (B,): ``p = max(v - r, min(v + r, p_prev))``."""
    p = state.take(thresholds.shape[0])
    vv = v[:, None]
    p = torch.maximum(vv - thresholds, torch.minimum(vv + thresholds, p))
    state.put(p)
    return p
