"""The default grey-box chain, in torch (`BlockChain`) and as one numba kernel
(`simulate_chain`) for fast free-run inference:

    FirstOrderLag -> Delay -> BoucWen -> CreepBank -> SecondOrderMode(s)

``params`` for `simulate_chain` is `BlockChain.export()`: a dict with any of the keys
``"amplifier"``, ``"delay"``, ``"bouc_wen"``, ``"creep"``, ``"mode"``, each the ``export()`` of
that block (a missing key skips the block).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numba
import numpy as np
from torch import Tensor, nn

from hysteresis_lab.blocks.bouc_wen import BoucWen
from hysteresis_lab.blocks.linear import CreepBank, Delay, FirstOrderLag, SecondOrderMode
from hysteresis_lab.physics.bouc_wen import JIT, advance
from hysteresis_lab.physics.filters import mode_coefficients_np

CHAIN_KEYS = ("amplifier", "delay", "bouc_wen", "creep", "mode")


@numba.njit(**JIT)
def _chain_kernel(
    u: np.ndarray, lag_pole: float, delay: int, d: float, a: np.ndarray, r1: np.ndarray,
    r2: np.ndarray, creep_poles: np.ndarray, creep_w: np.ndarray, mode_b: np.ndarray,
    mode_a: np.ndarray, mode_w: np.ndarray, mode_feedthrough: float,
) -> np.ndarray:
    n_b, n_t = u.shape
    n_c, n_p, n_m = a.shape[0], creep_poles.shape[0], mode_w.shape[0]
    out = np.empty((n_b, n_t))
    v = np.empty(n_t)
    h = np.empty(n_c)
    lp = np.empty(n_p)
    z1 = np.empty(n_m)
    z2 = np.empty(n_m)
    for b in range(n_b):
        lag = 0.0  # amplifier, step-invariant first order (pole 0: pass-through)
        for k in range(n_t):
            lag = (1.0 - lag_pole) * u[b, k] + lag_pole * lag
            v[k] = lag
        h[:] = 0.0
        lp[:] = 0.0
        z1[:] = 0.0
        z2[:] = 0.0
        v_prev = 0.0
        for k in range(n_t):
            vk = v[k - delay] if k >= delay else 0.0
            dv = vk - v_prev
            x = d * vk
            for c in range(n_c):
                if dv != 0.0:
                    s = 1.0 if dv > 0.0 else -1.0
                    h[c] = advance(h[c], abs(dv), s, a[c], r1[c], r2[c])
                x -= h[c]
            v_prev = vk
            xc = x
            for i in range(n_p):
                lp[i] = (1.0 - creep_poles[i]) * x + creep_poles[i] * lp[i]
                xc += creep_w[i] * lp[i]
            if n_m == 0:
                out[b, k] = xc
                continue
            y = mode_feedthrough * xc
            for m in range(n_m):  # biquad, transposed direct form II (as lfilter)
                ym = mode_b[m, 0] * xc + z1[m]
                z1[m] = mode_b[m, 1] * xc - mode_a[m, 1] * ym + z2[m]
                z2[m] = mode_b[m, 2] * xc - mode_a[m, 2] * ym
                y += mode_w[m] * ym
            out[b, k] = y
    return out


def simulate_chain(u: np.ndarray, params: Mapping[str, Any]) -> np.ndarray:
    """Free run of the chain (B, T) for inputs ``u`` (B, T) (or (T,)), float64, at rest.

    ``params``: `BlockChain.export()` (see the module docstring); units are the blocks'.
    """
    unknown = set(params) - set(CHAIN_KEYS)
    if unknown:
        raise ValueError(f"unknown chain blocks {sorted(unknown)}; expected {CHAIN_KEYS}")
    u = np.asarray(u, dtype=float)
    squeeze = u.ndim == 1
    u = np.ascontiguousarray(np.atleast_2d(u))
    lag_pole = 0.0
    if "amplifier" in params:
        p = params["amplifier"]
        lag_pole = math.exp(-2.0 * math.pi * float(p["cutoff_hz"]) / float(p["fs"]))
    delay = int(params["delay"]["samples"]) if "delay" in params else 0
    d, a, r1, r2 = 1.0, np.zeros(0), np.zeros(0), np.zeros(0)
    if "bouc_wen" in params:
        p = params["bouc_wen"]
        if np.any(np.asarray(p.get("exponent", 1.0)) != 1.0):
            raise ValueError("simulate_chain runs Bouc–Wen cells of exponent 1 only; simulate a "
                             "cell of another exponent with BoucWen.numpy_kernel()")
        d = float(p["d"])
        alpha, beta, gamma = (np.atleast_1d(np.asarray(p[k], dtype=float))
                              for k in ("alpha", "beta", "gamma"))
        a, r1, r2 = alpha * d, beta - gamma, beta + gamma
    creep_poles, creep_w = np.zeros(0), np.zeros(0)
    if "creep" in params:
        p = params["creep"]
        taus = np.asarray(p["time_constants_s"], dtype=float)
        creep_poles = np.exp(-1.0 / (float(p["fs"]) * taus))
        creep_w = np.asarray(p["weights"], dtype=float).reshape(len(taus))
    mode_b, mode_a, mode_w = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    mode_feedthrough = 0.0
    if "mode" in params:
        p = params["mode"]
        freqs = np.atleast_1d(np.asarray(p["frequency_hz"], dtype=float))
        damp = np.atleast_1d(np.asarray(p["damping"], dtype=float))
        coeffs = [mode_coefficients_np(f, z, float(p["fs"])) for f, z in zip(freqs, damp,
                                                                               strict=True)]
        mode_b = np.array([c[0] for c in coeffs])
        mode_a = np.array([c[1] for c in coeffs])
        mode_w = np.atleast_1d(np.asarray(p.get("weights", np.ones(1)), dtype=float))
        mode_feedthrough = float(p.get("feedthrough", 0.0))
    y = _chain_kernel(u, lag_pole, delay, d, a, r1, r2, creep_poles, creep_w, mode_b, mode_a,
                      mode_w, mode_feedthrough)
    return y[0] if squeeze else y


class BlockChain(nn.Module):
    """The default chain in torch; any block may be left out (``None``)."""

    def __init__(
        self,
        amplifier: FirstOrderLag | None = None,
        delay: Delay | None = None,
        bouc_wen: BoucWen | None = None,
        creep: CreepBank | None = None,
        mode: SecondOrderMode | None = None,
    ) -> None:
        super().__init__()
        self.amplifier, self.delay, self.bouc_wen = amplifier, delay, bouc_wen
        self.creep, self.mode = creep, mode

    def forward(self, u: Tensor) -> Tensor:
        """``u`` (B, T) -> ``y`` (B, T), starting at rest."""
        x = u
        if self.amplifier is not None:
            x = self.amplifier(x)
        if self.delay is not None:
            x = self.delay(x)
        if self.bouc_wen is not None:
            x, _ = self.bouc_wen(x)
        if self.creep is not None:
            x = self.creep(x)
        if self.mode is not None:
            x = self.mode(x)
        return x

    def export(self) -> dict[str, dict[str, Any]]:
        """The parameters `simulate_chain` takes."""
        return {key: getattr(self, key).export() for key in CHAIN_KEYS
                if getattr(self, key) is not None}
