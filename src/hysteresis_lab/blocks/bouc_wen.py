"""Differentiable Bouc–Wen hysteresis (the simulator's exact discrete recursion).

Model::

    x = d v - sum_c h_c,
    dh_c/dt = alpha_c d v' - beta_c |v'| |h_c|^(n_c-1) h_c - gamma_c v' |h_c|^(n_c)

updated per sample as the simulator does (`hysteresis_lab.physics.bouc_wen`: the input moves
linearly between samples; exactly at ``n = 1``, otherwise in Runge–Kutta sub-steps ten times
coarser than the simulator's, `MODEL_SLOPE_CHANGE`). The
forward pass and its adjoint are the physics floor's numba kernels (float64) in a
`torch.autograd.Function`; gradients are those of the update (w.r.t. the input, the initial
state, ``d, alpha, beta, gamma`` and the exponent; zero-length steps carry no input gradient).

The exponent ``n >= 1`` is fixed at 1 unless ``learn_exponent``; learned, it starts at 1,
where the update is the exact one: it
leaves 1 only when the loss falls as it grows (`ExponentAboveOne`: a bound held by
projection). While it changes, the saturated state ``(alpha d / (beta + gamma))^(1/n)``
stays that of ``n = 1`` (the rates are scaled with it, `BoucWen.rates`), so the exponent
alone sharpens or softens the loop's approach to saturation.

Scaling. With scaled signals ``v_s = v / U`` and ``x_s = x / Y`` (and ``h_s = h / Y``) the
equations keep their form with::

    d_s = d U / Y,   alpha_s = alpha,   beta_s = beta U,   gamma_s = gamma U

(``h = Y h_s`` cancels in ``beta |v'| h`` and ``gamma v' |h|``, while ``v' = U v_s'`` does
not), see `bouc_wen_scaled_params`. The simulator's d = 0.23 µm/V, alpha = 0.32, beta = 0.02,
gamma = 0.006 with U = 100 V, Y = 20 µm become d = 1.15, alpha = 0.32, beta = 2, gamma = 0.6.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from hysteresis_lab.blocks._util import as_float_array
from hysteresis_lab.blocks.step import StepState, frozen
from hysteresis_lab.physics.bouc_wen import (
    BoucWenStates,
    bouc_wen_advance,
    bouc_wen_advance_exponent,
    bw_states,
)

GAMMA_RATIO_MAX = 0.999  # |gamma| < beta: both rates beta -/+ gamma stay positive
#: where an exponent freed on a fitted cell starts (`BoucWen.start_exponent_off_one`): at
#: exactly 1 the update is the exact one and just above it the Runge–Kutta one, whose error
#: (~1e-4 of the state) jumps the loss by more than a step near the optimum gains, so an
#: L-BFGS line search started at 1 never leaves it
FREED_EXPONENT_START = 1.02


def bouc_wen_scaled_params(
    d: float, alpha: float, beta: float, gamma: float, u_scale: float, y_scale: float
) -> dict[str, float]:
    """Physical Bouc–Wen parameters -> those of the model on ``v / u_scale``, ``x / y_scale``."""
    return {
        "d": d * u_scale / y_scale,
        "alpha": alpha,
        "beta": beta * u_scale,
        "gamma": gamma * u_scale,
    }


def bouc_wen_free_run(
    v: np.ndarray,
    d: float,
    alpha: float | np.ndarray,
    beta: float | np.ndarray,
    gamma: float | np.ndarray,
    h0: np.ndarray | None = None,
    v0: np.ndarray | None = None,
    exponent: float | np.ndarray = 1.0,
) -> np.ndarray:
    """``x = d v - sum_c h_c`` (B, T) for ``v`` (B, T) float64, compiled (no gradients).

    ``alpha, beta, gamma, exponent``: one value per parallel element (or scalars for one
    element), in the simulator's convention (`BoucWen.export`).
    """
    v = np.ascontiguousarray(np.atleast_2d(v), dtype=float)
    n_c = max(np.size(alpha), np.size(beta), np.size(gamma), np.size(exponent))
    alpha_, beta_, gamma_, n_ = (as_float_array(p, n_c) for p in (alpha, beta, gamma,
                                                                   exponent))
    h0_ = np.zeros((v.shape[0], n_c)) if h0 is None else np.asarray(h0, float).reshape(
        v.shape[0], n_c)
    v0_ = np.zeros(v.shape[0]) if v0 is None else np.asarray(v0, float).reshape(v.shape[0])
    hs = bw_states(v, v0_, h0_, alpha_ * d, beta_ - gamma_, beta_ + gamma_, None, n_)
    return d * v - hs.sum(axis=2)


class ExponentAboveOne(torch.autograd.Function):
    """``1 + max(raw, 0)`` with the bound held by projection: at or below it (the exponent
    at 1) the gradient passes only where it would raise the exponent, so a fit that gains
    nothing from it keeps the exact ``n = 1`` update, and one that does lifts it off."""

    @staticmethod
    def forward(ctx: Any, raw: Tensor) -> Tensor:
        ctx.save_for_backward(raw)
        return 1.0 + torch.clamp(raw, min=0.0)

    @staticmethod
    def backward(ctx: Any, g: Tensor) -> Tensor:
        (raw,) = ctx.saved_tensors
        return torch.where((raw > 0.0) | (g < 0.0), g, torch.zeros_like(g))


class BoucWen(nn.Module):
    """Bouc–Wen hysteresis ``x = d v - sum_c h_c`` with learnable ``d, alpha, beta, gamma`` and
    exponents ``n_c >= 1``.

    Parameters are given in the simulator's convention for the (scaled) signals the block sees
    (see the module docstring and `bouc_wen_scaled_params`), at ``n = 1``. ``d, alpha, beta >
    0`` are log-parametrised; ``gamma = beta * 0.999 * tanh(raw)`` keeps ``|gamma| < beta``
    (both rates positive, bounded state) for any raw value. With ``n_channels > 1`` the
    elements run in parallel, ``alpha`` is split equally between them and their ``beta``
    spread over half a decade around ``beta`` (so they differ); the starting loop then
    differs slightly from one element's. ``learn_exponent``: the exponents start at 1 and are
    learned (`ExponentAboveOne`; the rates scaled to keep the saturated state, `rates`);
    false: fixed at 1 (a block that runs the exact update in a kernel of its own).
    """

    def __init__(
        self,
        d: float = 1.0,
        alpha: float = 0.3,
        beta: float = 0.02,
        gamma: float = 0.006,
        n_channels: int = 1,
        learn_exponent: bool = False,
    ) -> None:
        super().__init__()
        if min(d, alpha, beta) <= 0 or abs(gamma) >= GAMMA_RATIO_MAX * beta or n_channels < 1:
            raise ValueError(
                f"Bouc-Wen needs d, alpha, beta > 0, |gamma| < {GAMMA_RATIO_MAX} beta and "
                f"n_channels >= 1 (got d={d}, alpha={alpha}, beta={beta}, gamma={gamma}, "
                f"n_channels={n_channels})"
            )
        self.n_channels = int(n_channels)
        spread = np.logspace(-0.25, 0.25, n_channels) if n_channels > 1 else np.ones(1)
        ratio = gamma / (beta * GAMMA_RATIO_MAX)
        self.raw_d = nn.Parameter(torch.tensor(math.log(d), dtype=torch.float64))
        self.raw_alpha = nn.Parameter(torch.full((n_channels,), math.log(alpha / n_channels),
                                                 dtype=torch.float64))
        self.raw_beta = nn.Parameter(torch.tensor(np.log(beta * spread)))
        self.raw_gamma = nn.Parameter(torch.full((n_channels,), math.atanh(ratio),
                                                 dtype=torch.float64))
        #: the exponents' excess over 1 (`ExponentAboveOne`); None: fixed at 1
        self.raw_exponent = nn.Parameter(torch.zeros(n_channels, dtype=torch.float64)) \
            if learn_exponent else None

    def _load_from_state_dict(self, state_dict: dict[str, Any], prefix: str,
                              *args: Any) -> None:
        """A state saved before the exponent was learnable holds none: it is 1 there."""
        key = prefix + "raw_exponent"
        if self.raw_exponent is not None and key not in state_dict:
            state_dict[key] = torch.zeros_like(self.raw_exponent)
        super()._load_from_state_dict(state_dict, prefix, *args)

    def start_exponent_off_one(self, exponent: float = FREED_EXPONENT_START) -> None:
        """Start a learned exponent at ``exponent`` (> 1), inside the sub-stepped update,
        where the loss is continuous in it (`FREED_EXPONENT_START`)."""
        if self.raw_exponent is None:
            raise ValueError("this Bouc-Wen cell's exponent is fixed at 1 (learn_exponent=False)")
        with torch.no_grad():
            self.raw_exponent.fill_(exponent - 1.0)

    @property
    def d(self) -> Tensor:
        return self.raw_d.double().exp()

    @property
    def alpha(self) -> Tensor:
        return self.raw_alpha.double().exp()

    @property
    def beta(self) -> Tensor:
        return self.raw_beta.double().exp()

    @property
    def gamma(self) -> Tensor:
        return self.beta * GAMMA_RATIO_MAX * torch.tanh(self.raw_gamma.double())

    @property
    def exponent(self) -> Tensor:
        """The exponents ``n_c >= 1`` (C,); ones where not learned."""
        if self.raw_exponent is None:
            return torch.ones(self.n_channels, dtype=torch.float64,
                              device=self.raw_gamma.device)
        return ExponentAboveOne.apply(self.raw_exponent.double())

    def rates(self) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``a = alpha d``, the rates ``r1, r2`` the update runs with and the exponents.

        ``r1, r2 = (beta -/+ gamma) (a / (beta + gamma))^(1 - n)``: at ``n = 1`` those of
        ``beta, gamma`` (the factor is exactly 1), otherwise scaled so that the saturated
        state ``(a / r2)^(1/n)`` stays ``a / (beta + gamma)``."""
        d, beta, gamma = self.d, self.beta, self.gamma
        a = self.alpha * d
        r1, r2 = beta - gamma, beta + gamma
        if self.raw_exponent is None:
            return a, r1, r2, self.exponent
        n = self.exponent
        scale = (a / r2) ** (1.0 - n)
        return a, r1 * scale, r2 * scale, n

    def forward(
        self, v: Tensor, h0: Tensor | None = None, v0: Tensor | None = None,
        alpha_factor: Tensor | None = None,
    ) -> tuple[Tensor, Tensor]:
        """``x`` (B, T) and the last states (B,) (``(B, C)`` when ``n_channels > 1``).

        ``h0``: states before the first sample (default 0, at rest); ``v0``: the input there
        (default 0); ``alpha_factor`` (B, T): the step into each sample runs with ``alpha``
        times it (rate-dependent hysteresis; >= 0), differentiable. Computed in float64,
        returned in ``v``'s dtype.
        """
        n_b = v.shape[0]
        v64 = v.double()
        h0_ = torch.zeros(n_b, self.n_channels, dtype=torch.float64, device=v.device) \
            if h0 is None else h0.double().reshape(n_b, self.n_channels)
        v0_ = torch.zeros(n_b, dtype=torch.float64, device=v.device) if v0 is None \
            else v0.double().reshape(n_b)
        d = self.d
        a, r1, r2, n = self.rates()
        factor = None if alpha_factor is None else alpha_factor.double().reshape(v64.shape)
        hs = BoucWenStates.apply(v64, v0_, h0_, a.to(v.device), r1.to(v.device),
                                 r2.to(v.device), factor,
                                 None if self.raw_exponent is None else n.to(v.device))
        x = d.to(v.device) * v64 - hs.sum(dim=2)
        h_last = hs[:, -1, :]
        if self.n_channels == 1:
            h_last = h_last[:, 0]
        return x.to(v.dtype), h_last.to(v.dtype)

    def state_names(self) -> list[str]:
        return ["v_prev"] + [f"h{c}" for c in range(self.n_channels)]

    def step(
        self, v: Tensor, state: StepState,
        alpha_factor: Callable[[Tensor], Tensor] | None = None,
    ) -> Tensor:
        """One sample ``v`` (B,) -> ``x`` (B,); state: the previous input, then ``h_c``.

        ``alpha_factor``: the factor of ``alpha`` for this step from the input step
        ``v - v_prev`` (B,) -> (B,) (`forward`'s per sample)."""
        v_prev = state.take(1)[:, 0]
        h = state.take(self.n_channels)
        d, a, r1, r2, n = frozen(self.d, *self.rates())
        a = a[None] if alpha_factor is None else a[None] * alpha_factor(v - v_prev)[:, None]
        if self.raw_exponent is None or bool((n == 1.0).all()):  # n: frozen while tracing
            h = bouc_wen_advance(h, (v - v_prev)[:, None], a, r1[None], r2[None])
        elif torch.jit.is_tracing():
            raise ValueError(
                "a Bouc-Wen cell whose learned exponent is not 1 cannot be exported: its step "
                "takes as many sub-steps as each input step needs, which a traced graph cannot "
                "hold. Fix: fit with the exponent fixed at 1 (model.hysteresis=bouc_wen "
                "model.learn_exponent=false) to export, or simulate the model in Python.")
        else:
            h = bouc_wen_advance_exponent(h, (v - v_prev)[:, None], a, r1[None], r2[None],
                                          n[None])
        state.put(v[:, None])
        state.put(h)
        return d * v - h.sum(dim=1)

    def export(self) -> dict[str, Any]:
        """Current parameters in the simulator's convention: ``d`` (float), ``alpha, beta,
        gamma, exponent`` (arrays, one per element; ``beta, gamma`` those the update runs
        with, `rates`)."""
        with torch.no_grad():
            n = self.exponent
            scale = (self.alpha * self.d / (self.beta + self.gamma)) ** (1.0 - n)
            return {
                "d": float(self.d),
                "alpha": self.alpha.cpu().numpy().copy(),
                "beta": (self.beta * scale).cpu().numpy().copy(),
                "gamma": (self.gamma * scale).cpu().numpy().copy(),
                "exponent": n.cpu().numpy().copy(),
            }

    def numpy_kernel(self):  # noqa: ANN201 - returns a closure
        """``f(v: np.ndarray (B, T) float64) -> x`` with the current parameters (compiled)."""
        p = self.export()
        return lambda v: bouc_wen_free_run(v, p["d"], p["alpha"], p["beta"], p["gamma"],
                                           exponent=p["exponent"])
