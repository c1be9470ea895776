"""Differentiable physical blocks of a grey-box positioner model (scaled units).

Each block is an `nn.Module` with ``export() -> dict`` of its physical parameters; the numba
kernels (`bouc_wen_free_run`, `simulate_chain`) run the same recursions in float64 for
inference. See `hysteresis_lab.blocks.bouc_wen` for the scaling of the Bouc–Wen parameters.
"""

from hysteresis_lab.blocks.bouc_wen import BoucWen, bouc_wen_free_run, bouc_wen_scaled_params
from hysteresis_lab.blocks.chain import BlockChain, simulate_chain
from hysteresis_lab.blocks.estimate import estimate_mode, estimate_static_gain
from hysteresis_lab.blocks.linear import (
    CreepBank,
    Delay,
    FirstOrderLag,
    SecondOrderMode,
    iir_filter,
    mode_coefficients,
)
from hysteresis_lab.blocks.play import PlayOperators, play

__all__ = [
    "BlockChain",
    "BoucWen",
    "CreepBank",
    "Delay",
    "FirstOrderLag",
    "PlayOperators",
    "SecondOrderMode",
    "bouc_wen_free_run",
    "bouc_wen_scaled_params",
    "estimate_mode",
    "estimate_static_gain",
    "iir_filter",
    "mode_coefficients",
    "play",
    "simulate_chain",
]
