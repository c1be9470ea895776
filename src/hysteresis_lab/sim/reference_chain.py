"""The grey-box chain with a simulated positioner's own parameters (a reference for tests and
for comparing a fitted grey-box with the plant it was fitted to)."""

from __future__ import annotations

from typing import Any

from hysteresis_lab.blocks.bouc_wen import BoucWen, bouc_wen_scaled_params
from hysteresis_lab.blocks.chain import BlockChain
from hysteresis_lab.blocks.linear import CreepBank, Delay, FirstOrderLag, SecondOrderMode
from hysteresis_lab.sim.config import PositionerConfig


def chain_from_positioner(
    config: Any, fs: float, u_scale: float = 100.0, y_scale: float = 20.0
) -> BlockChain:
    """The chain with a simulator `PositionerConfig`'s (or mapping's) parameters, in units of
    ``u / u_scale`` and ``y / y_scale``: the blocks of its enabled amplifier, input delay,
    hysteresis (a Bouc–Wen cell of exponent 1), creep and modes (other effects are not
    represented)."""
    if not isinstance(config, PositionerConfig):
        config = PositionerConfig.from_dict(config)
    c = config
    amp = FirstOrderLag(fs, c.amplifier.cutoff_hz) if c.amplifier.enabled else None
    delay = Delay(c.input_delay.samples) if c.input_delay.enabled else None
    bw = None
    if c.hysteresis.enabled and c.hysteresis.cell == "bouc_wen" and c.hysteresis.exponent == 1:
        h = c.hysteresis
        bw = BoucWen(**bouc_wen_scaled_params(h.d_um_per_v, h.alpha, h.beta, h.gamma,
                                              u_scale, y_scale))
    creep = CreepBank(fs, c.creep.time_constants_s, c.creep.weight_per_decade) \
        if c.creep.enabled else None
    modes, weights = _modes(c)
    mode = None
    if len(modes) == 1:
        mode = SecondOrderMode(fs, modes[0].frequency_hz, modes[0].damping)
    elif modes:
        mode = SecondOrderMode(fs, [m.frequency_hz for m in modes], [m.damping for m in modes],
                               n_modes=len(modes), weights=weights)
    return BlockChain(amp, delay, bw, creep, mode)


def _modes(c: PositionerConfig) -> tuple[list[Any], list[float]]:
    """The enabled modes and the share of the static gain each carries (a later mode takes
    its ``weight`` of the response so far, `hysteresis_lab.sim.blocks.ModeBlock`)."""
    modes: list[Any] = []
    weights: list[float] = []
    for m in (c.mode1, c.mode2, c.mode3):
        if not m.enabled:
            continue
        weights = [w * (1.0 - m.weight) for w in weights] + [m.weight] if modes else [1.0]
        modes.append(m)
    return modes, weights
