"""First-order storages: a storage with a rim (an upstream tank that overflows) and the
dynamics as storages in a row (`StorageCascade`, ``model.feedback_on=output_stage``).

The rim, per sample ``t`` (from an empty storage, ``s = 0``)::

    pre[t]   = s[t-1] + alpha (v[t] - s[t-1])      (a unit-gain first-order storage)
    spill[t] = w relu(pre[t] - c)                   (``w = 1``: all above the rim ``c`` spills)
    s[t]     = pre[t] - spill[t]                    (the level is held at the rim)

Below the rim it is a first-order low-pass; at the rim its level is held, so it drains from
the rim, not from where a linear storage would have risen to: a saturation of an internal
state, with memory, which no clip of the input or of the output gives. The forward pass and
its adjoint are numba kernels (float64) wrapped in a `torch.autograd.Function`: exact
gradients w.r.t. the input, ``alpha``, the rim ``c`` and the weight ``w``.
"""

from __future__ import annotations

import logging
from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor, nn

from hysteresis_lab.blocks.sections import MAX_RADIUS, StableSections, held_poles, polymul
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.physics.tensors import from_numpy, to_numpy64

log = logging.getLogger(__name__)

JIT = {"cache": True, "error_model": "numpy"}


@numba.njit(**JIT)
def rim_states(v: np.ndarray, alpha: float, rim: float, weight: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Levels ``s``, spills and the levels before the spill ``pre`` (each (B, T)) for inputs
    ``v`` (B, T), from empty storages."""
    n_b, n_t = v.shape
    s = np.zeros((n_b, n_t))
    spill = np.zeros((n_b, n_t))
    pre = np.zeros((n_b, n_t))
    for r in range(n_b):
        level = 0.0
        for t in range(n_t):
            p = level + alpha * (v[r, t] - level)
            out = weight * max(p - rim, 0.0)
            level = p - out
            pre[r, t] = p
            spill[r, t] = out
            s[r, t] = level
    return s, spill, pre


@numba.njit(**JIT)
def rim_backward(g_s: np.ndarray, g_spill: np.ndarray, v: np.ndarray, s: np.ndarray,
                 pre: np.ndarray, alpha: float, rim: float, weight: float
                 ) -> tuple[np.ndarray, float, float, float]:
    """Adjoint of `rim_states`: ``g_s, g_spill`` (B, T) = dL/d(s, spill); returns
    dL/d(v, alpha, rim, weight)."""
    n_b, n_t = v.shape
    gv = np.zeros((n_b, n_t))
    g_alpha, g_rim, g_weight = 0.0, 0.0, 0.0
    for r in range(n_b):
        g_pre_next = 0.0
        for t in range(n_t - 1, -1, -1):
            g_level = g_s[r, t] + (1.0 - alpha) * g_pre_next  # s[t] also feeds pre[t+1]
            g_out = g_spill[r, t] - g_level  # spill[t] leaves the level
            over = pre[r, t] - rim
            g_pre = g_level
            if over > 0.0:
                g_pre += weight * g_out
                g_weight += g_out * over
                g_rim -= g_out * weight
            s_prev = s[r, t - 1] if t > 0 else 0.0
            gv[r, t] = alpha * g_pre
            g_alpha += g_pre * (v[r, t] - s_prev)
            g_pre_next = g_pre
    return gv, g_alpha, g_rim, g_weight


class _RimFunction(torch.autograd.Function):
    """``(s, spill)`` (B, T) each from ``v`` (B, T) and the scalars ``alpha, rim, weight``."""

    @staticmethod
    def forward(ctx: Any, v: Tensor, alpha: Tensor, rim: Tensor,
                weight: Tensor) -> tuple[Tensor, Tensor]:
        v_ = to_numpy64(v)
        scalars = float(alpha.detach()), float(rim.detach()), float(weight.detach())
        s, spill, pre = rim_states(v_, *scalars)
        ctx.saved = (v_, s, pre, *scalars)
        return from_numpy(s, v), from_numpy(spill, v)

    @staticmethod
    def backward(ctx: Any, g_s: Tensor | None, g_spill: Tensor | None) -> tuple[Tensor, ...]:
        v_, s, pre, alpha, rim, weight = ctx.saved
        zeros = np.zeros_like(v_)
        gs = zeros if g_s is None else to_numpy64(g_s)
        gsp = zeros if g_spill is None else to_numpy64(g_spill)
        gv, ga, gc, gw = rim_backward(gs, gsp, v_, s, pre, alpha, rim, weight)
        ref = g_s if g_s is not None else g_spill
        return (from_numpy(gv, ref), *(torch.tensor(x, dtype=torch.float64, device=ref.device)
                                       for x in (ga, gc, gw)))


def rim_storage(v: Tensor, alpha: Tensor, rim: Tensor, weight: Tensor) -> tuple[Tensor, Tensor]:
    """The storage's levels and spills (B, T) each for inputs ``v`` (B, T), rate ``alpha``,
    rim ``rim`` and spill weight ``weight`` (scalars), from an empty storage; differentiable
    w.r.t. all four."""
    return _RimFunction.apply(v.double(), alpha, rim, weight)


def rim_step(v: Tensor, level: Tensor, alpha: Tensor, rim: Tensor,
             weight: Tensor) -> tuple[Tensor, Tensor]:
    """One sample of `rim_storage`: inputs and last levels (B,) -> (level, spill) (B,)."""
    pre = level + alpha * (v - level)
    spill = weight * torch.relu(pre - rim)
    return pre - spill, spill


class StagePole(nn.Module):
    """One real pole ``p = MAX_RADIUS tanh(raw)`` with unit static gain,
    ``(1 - p) / (1 - p z^-1)``: a first-order storage, stable for any parameter value. It has
    `StableSections`' ``polynomials`` and ``delay`` (none), so the closed loops
    (`StaticFeedback`, `StateHysteresis`) run around it as they do around the dynamics."""

    def __init__(self) -> None:
        super().__init__()
        self.raw_pole = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.register_buffer("delay", torch.zeros((), dtype=torch.long))

    @property
    def pole(self) -> torch.Tensor:
        return MAX_RADIUS * torch.tanh(self.raw_pole)

    def set_pole(self, pole: float) -> None:
        """Start at ``pole`` (kept within ``MAX_RADIUS``)."""
        held = float(np.clip(pole / MAX_RADIUS, -0.999999, 0.999999))
        with torch.no_grad():
            self.raw_pole.fill_(float(np.arctanh(held)))

    def polynomials(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``b = [1 - p]``, ``a = [1, -p]``."""
        p = self.pole
        return (1.0 - p).reshape(1), torch.stack([torch.ones_like(p), -p])


class StorageCascade(nn.Module):
    """The dynamics as storages in a row (``model.feedback_on=output_stage``): an upstream
    part (`StableSections`: the gain, delay and the other poles, open loop), then an
    upstream storage (one real pole, `StagePole`'s rate, optionally with a rim:
    `hysteresis_lab.blocks.storage`, its level held there and a share of the spill passed
    on), then the output stage (one real pole) whose own level the loop forces
    (`StaticFeedback`, `StateHysteresis`) act on — a tank whose outflow law reads its own
    level, fed by an upper tank that overflows. Both storages have unit static gain, so the
    cascade's static gain is the upstream part's."""

    def __init__(self, order: int, rim_level: float | None = None) -> None:
        super().__init__()
        #: room for ``order`` poles upstream (sections the start leaves empty may train)
        self.upstream = StableSections(order)
        self.storage = StagePole()
        self.stage = StagePole()
        self.rim_weight: nn.Parameter | None = None
        if rim_level is not None:  # effect overflow: the rim, spill weight and share from zero
            self.rim_weight = nn.Parameter(torch.zeros((), dtype=torch.float64))
            self.rim_level = nn.Parameter(torch.tensor(float(rim_level), dtype=torch.float64))
            self.spill_share = nn.Parameter(torch.zeros((), dtype=torch.float64))

    def _rim(self, offset: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The rim on the storage's level (the output's units less its ``offset``), the
        spill's weight and its share passed on (zeros without a rim)."""
        if self.rim_weight is None:
            zero = torch.zeros((), dtype=torch.float64, device=offset.device)
            return zero, zero, zero
        return self.rim_level - offset, self.rim_weight, self.spill_share

    def storage_output(self, x: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
        """What fills the output stage (B, T): the upstream storage's level plus its share of
        the spill (over the output stage's rate: ``share = 1`` passes all of it into the
        stage's level), for the cascade's input ``x`` (B, T)."""
        rim, weight, share = self._rim(offset)
        level, spill = rim_storage(self.upstream(x), 1.0 - self.storage.pole, rim, weight)
        return level + share * spill / (1.0 - self.stage.pole)

    def storage_step(self, x: torch.Tensor, state: StepState,
                     offset: torch.Tensor) -> torch.Tensor:
        """One sample of `storage_output`; state: the upstream part's, the storage's level."""
        v = self.upstream.step(x, state)
        alpha, rim, weight, share, stage = frozen(1.0 - self.storage.pole, *self._rim(offset),
                                                  1.0 - self.stage.pole)
        level, spill = rim_step(v, state.take(1)[:, 0], alpha, rim, weight)
        state.put(level[:, None])
        return level + share * spill / stage

    def storage_state_names(self) -> list[str]:
        return [f"upstream.{name}" for name in self.upstream.state_names()] + ["storage"]

    def set_transfer_function(self, b: np.ndarray, a: np.ndarray) -> None:
        """Start from ``b(z^-1) / a(z^-1)``: its two slowest real poles become the storages
        (the slowest the upstream storage, the other the output stage), the other poles the
        upstream part with ``b``'s delay and the static gain but no zeros (the inflow: the
        exact numerator over two slow storages amplifies high frequencies a thousandfold on
        the cascaded tanks, where the rim then acts). Where ``a`` has fewer real poles, its
        slowest complex pair gives two real poles of its radius. So the start keeps the
        poles, the delay and the static gain, not the zeros."""
        held = held_poles(a)
        poles = list(held)
        chosen = []
        for _ in range(2):
            real = [i for i, p in enumerate(poles) if abs(p.imag) <= 1e-9]
            if not real and poles:
                i = max(range(len(poles)), key=lambda k: abs(poles[k]))
                radius = abs(poles[i])
                pair = [k for k in range(len(poles)) if k != i
                        and abs(poles[k] - np.conj(poles[i])) < 1e-9][:1]
                poles = [p for k, p in enumerate(poles) if k not in (i, *pair)]
                poles += [complex(radius)] * (1 + len(pair))
                log.info("output stage start: no real pole left, a pole pair of radius %.4f "
                         "made real", radius)
                real = [len(poles) - 1]
            if not real:
                chosen.append(0.0)
                continue
            i = max(real, key=lambda k: poles[k].real)
            chosen.append(float(poles.pop(i).real))
        rest = np.atleast_1d(np.real(np.poly(poles)))
        b = np.asarray(b, dtype=float)
        static_gain = b.sum() / np.sum(np.real(np.poly(held)))
        lead = int(np.flatnonzero(b)[0]) if np.any(b) else 0
        upstream = np.zeros(lead + 1)
        upstream[lead] = static_gain * rest.sum()  # the inflow: no zeros, the static gain kept
        self.upstream.set_transfer_function(upstream, rest)
        self.storage.set_pole(chosen[0])
        self.stage.set_pole(chosen[1])

    def polynomials(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The cascade below the rim as one transfer function (upstream, storage, stage)."""
        b, a = self.upstream.polynomials()
        for part in (self.storage, self.stage):
            bp, ap = part.polynomials()
            b, a = polymul(b, bp), polymul(a, ap)
        return b, a

    def export(self) -> dict[str, Any]:
        with torch.no_grad():
            out = {"upstream": self.upstream.export(),
                   "storage_pole": float(self.storage.pole), "stage_pole": float(self.stage.pole)}
            if self.rim_weight is not None:
                out.update(rim_level=float(self.rim_level), rim_weight=float(self.rim_weight),
                           spill_share=float(self.spill_share))
        return out
