"""The simulated piezoelectric cantilever positioner, the built-in default data source.

Signal chain (each block switchable; the effects' blocks live with the effects,
`hysteresis_lab.effects.<name>`, the plant-only ones in `hysteresis_lab.sim.blocks`; the
positioner runs them in signal order; parameters in `hysteresis_lab.sim.config` and
``hysteresis_lab/conf/sim/positioner.yaml``; defaults in brackets, "off" = disabled by default)::

    u [V] -> amplifier        first-order low-pass [5 kHz]
          -> saturation       clipping at ±limit [off, 90 V]
          -> dead_zone        sign(v) max(|v| - w, 0) [off, 10 V]
          -> backlash         play operator of half-width w [off, 5 V]
          -> input_delay      [1 sample]
          -> hysteresis       Bouc-Wen, n = 1 [d = 0.23 um/V, alpha 0.32, beta 0.02, gamma 0.006]
                              (or any n >= 1, or a Prandtl-Ishlinskii cell)
          -> asymmetry        + c * 40 um * (v / 100 V)^2 [off, c = 0.02]
          -> rate_dependence  alpha * (1 + k |dv/dt| / rate_ref) [off, k = 0.5]
          -> creep            x + w * sum_i lowpass_tau_i(x), tau = 0.1, 1, 10, 100 s [w = 1.5 %]
          -> mode1            2nd-order resonance, unit DC gain [900 Hz, zeta 0.03]
          -> mode2            second bending mode [off, 2.8 kHz, zeta 0.02, 15 % of the gain]
          -> mode3            third mode [off, 4.5 kHz, zeta 0.02, 5 % of the gain]
          -> output_delay     [off]
          -> drift            ramp + slow oscillation [off, 4 nm/s, 0.08 um, 20 s period]
          -> noise            Gaussian sensor noise [0.01 um RMS]
          -> quantisation     sensor resolution [1 nm]  -> y [um]

The defaults are chosen so that a ±100 V, 1 Hz sine gives about 40 um peak-to-peak with a
major loop about 12 % of the stroke wide, a step creeps by about 1.5 % of its size per decade
of time, and the frequency response peaks at the 900 Hz first mode (`tests/test_simulator.py`
holds the simulator to these).

Sources and justification:

* Bouc-Wen hysteresis for piezo actuators: Low & Guo 1995 (J. MEMS 4(4)); Goldfarb &
  Celanovic 1997 (J. Dyn. Sys. Meas. Control 119). Piezo stacks/benders show loops of
  10-15 % of the stroke at full amplitude; ~0.2 um/V gives ±20 um at ±100 V.
  The per-sample update is exact for piecewise-linear input (`hysteresis_lab.physics.bouc_wen`).
* Creep as a logarithmic step response, ~1-2 % per decade of time: Jung & Gweon 2000
  (Rev. Sci. Instrum. 71); Croft, Shed & Devasia 2001 (J. Dyn. Sys. Meas. Control 123);
  PI piezo catalogue (~1 % per decade). Approximated by parallel first-order elements with
  log-spaced time constants, one per decade.
* Cantilever/bender first bending mode at a few hundred Hz to ~1 kHz with light damping
  (zeta 0.02-0.05); discretised bilinearly with prewarping at the mode frequency.
* Amplifier bandwidth of a few kHz for piezo loads; capacitive sensors ~0.01 um RMS noise.

`Positioner` simulates, `simulate_recording` returns a `Recording`, and
`hysteresis_lab.sim.default_dataset.make_default_dataset` builds the study's data set;
`hysteresis_lab.sim.zoo` draws random positioners of the same physics class from a seed.
"""

from hysteresis_lab.sim.config import PositionerConfig
from hysteresis_lab.sim.positioner import Positioner, simulate_recording

__all__ = ["Positioner", "PositionerConfig", "simulate_recording"]
