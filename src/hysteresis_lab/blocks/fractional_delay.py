"""A delay learned within a few samples of a starting one: an integer delay and a Lagrange
fractional-delay interpolator (Laakso et al., "Splitting the unit delay", IEEE Signal
Processing Magazine 13(1), 1996) whose offset is a parameter.

The delay read off the data can be a sample or two off (the amplifier lag and a hysteresis
loop's lag look alike within the excited band), and no other block of a chain makes up for
a delay too long. With the offset learned, the simulation error sets it instead.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from hysteresis_lab.blocks._util import logit
from hysteresis_lab.blocks.step import StepState, delay_step, frozen

#: a delay starting at the span's edge (a delay of 0 samples, or below the span) starts this
#: share of the interpolator's range inside it: within 1e-3 samples of the integer delay
EDGE = 5e-4


def lagrange_taps(offset: Tensor, order: int) -> Tensor:
    """The ``order + 1`` taps of the Lagrange interpolator that delays by ``offset`` samples
    (``0 <= offset <= order``): ``h_k = prod_{m != k} (offset - m) / (k - m)``; at a whole
    ``offset`` one tap is 1 and the others 0 (an exact delay)."""
    taps = []
    for k in range(order + 1):
        tap = torch.ones_like(offset)
        for m in range(order + 1):
            if m != k:
                tap = tap * (offset - m) / (k - m)
        taps.append(tap)
    return torch.stack(taps)


class LearnedDelay(nn.Module):
    """A delay of ``samples`` to start, learned within ``span`` samples either side of it
    (never below zero): ``max(samples - span, 0)`` whole samples, then a Lagrange interpolator
    of order ``2 span`` whose offset in ``(0, 2 span)`` is learned. It starts at ``samples``
    (exactly, unless that is the range's edge: `EDGE`). ``samples`` stays the starting delay
    (the model's ``delay`` setting); `delay_samples` is the learned one."""

    def __init__(self, samples: int = 1, span: int = 1) -> None:
        super().__init__()
        if samples < 0 or span < 1:
            raise ValueError(f"need samples >= 0 and span >= 1, got {samples}, {span}")
        self.samples = int(samples)
        self.whole = max(self.samples - span, 0)
        self.order = 2 * span
        share = min(max((self.samples - self.whole) / self.order, EDGE), 1.0 - EDGE)
        self.raw_offset = nn.Parameter(torch.tensor(logit(share), dtype=torch.float64))

    @property
    def offset(self) -> Tensor:
        """The interpolator's delay, ``2 span sigmoid(raw)``: smooth, inside ``(0, 2 span)``
        for any raw value (a clamp's flat sides would stall the L-BFGS polish)."""
        return self.order * torch.sigmoid(self.raw_offset)

    def taps(self) -> Tensor:
        """The interpolator's taps, newest sample first."""
        return lagrange_taps(self.offset, self.order)

    @property
    def delay_samples(self) -> float:
        """The learned delay in samples."""
        return self.whole + float(self.offset.detach())

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (B, T) -> (B, T), zeros before the start."""
        t = x.shape[1]
        shifted = F.pad(x, (self.whole + self.order, 0))
        taps = self.taps().to(x.dtype)
        out = torch.zeros_like(x)
        for k in range(self.order + 1):
            start = self.order - k
            out = out + taps[k] * shifted[:, start: start + t]
        return out

    def state_names(self) -> list[str]:
        return ([f"delay_{i}" for i in range(self.whole)]
                + [f"interpolator_{i}" for i in range(self.order)])

    def step(self, x: Tensor, state: StepState) -> Tensor:
        """One sample (B,) -> (B,): the whole delay's buffer, then the interpolator's last
        ``2 span`` inputs (oldest first)."""
        x = delay_step(self.whole, x, state)
        window = torch.cat([state.take(self.order), x[:, None]], dim=1)  # oldest first
        state.put(window[:, 1:])
        (taps,) = frozen(self.taps())
        return window.flip(1) @ taps.to(x.dtype)

    def export(self) -> dict[str, Any]:
        return {"samples": self.samples, "delay_samples": self.delay_samples,
                "span": self.order // 2}
