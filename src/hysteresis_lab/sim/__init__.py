"""The simulated piezoelectric cantilever positioner, the built-in default data source.

Signal chain (each block switchable, parameters in `hysteresis_lab.sim.config` and
``conf/sim/positioner.yaml``)::

    u [V] -> amplifier (low-pass 5 kHz) -> saturation (off) -> input delay (1 sample)
          -> Bouc-Wen hysteresis (+ asymmetry, rate dependence: off) -> creep (0.1-100 s)
          -> first mode (900 Hz, zeta 0.03) [+ second mode 2.8 kHz: off] -> output delay (off)
          -> drift (off) -> sensor noise (0.01 um RMS) -> quantisation (1 nm) -> y [um]

`Positioner` simulates, `simulate_recording` returns a `Recording`, and
`hysteresis_lab.sim.default_dataset.make_default_dataset` builds the study's data set.
"""

from hysteresis_lab.sim.config import PositionerConfig
from hysteresis_lab.sim.positioner import Positioner, simulate_recording

__all__ = ["Positioner", "PositionerConfig", "simulate_recording"]
