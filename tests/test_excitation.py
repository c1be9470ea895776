"""How hard the tests drive an added effect's operators, against the identification data."""

from __future__ import annotations

import numpy as np
import pytest

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.loop.diagnosis.excitation import UNDER_EXCITED_RATIO, operator_excitation
from hysteresis_lab.signals import sine

FS = 2000.0
CTX = FeatureContext(fs=FS, u_amplitude=np.array([100.0]), duration_s=2.0)


def _sine(amplitude: float, frequency: float = 2.0) -> Recording:
    u = amplitude / 100.0 * sine(frequency, fs=FS, n_periods=4)
    return Recording(u=u, y=np.zeros(len(u)), fs=FS, name=f"{amplitude:g}V")


def test_identification_like_the_tests_drives_every_operator_as_hard():
    excitation = operator_excitation("hysteresis", [_sine(100)], [_sine(100)], CTX)
    assert len(excitation.ratios) == 8  # one per play operator
    assert all(r == pytest.approx(1.0) for r in excitation.ratios.values())
    assert "no operator of 'hysteresis' more than 1x" in excitation.reading()


def test_clipping_never_reached_while_identifying_is_flagged():
    """Saturation operators (the excess over 70-95 % of 100 V) never move under a 60 V sine."""
    excitation = operator_excitation("saturation", [_sine(60)], [_sine(100)], CTX)
    assert set(excitation.ratios.values()) == {None}
    assert "never moves in the identification data" in excitation.reading()
    half = operator_excitation("saturation", [_sine(85)], [_sine(100)], CTX)
    channel, ratio = half.worst
    assert half.ratios["saturation_0"] > 1.0 and ratio is None  # 85 V passes 70 V, not 90 V
    # an 85 V sine turns every play operator (thresholds 2-80 V), the widest ones barely
    weaker = operator_excitation("hysteresis", [_sine(85)], [_sine(100)], CTX)
    assert None not in weaker.ratios.values()
    channel, ratio = weaker.worst
    assert ratio > UNDER_EXCITED_RATIO
    assert f"'{channel}' moves {ratio:.3g}x less (RMS)" in weaker.reading()
    assert weaker.to_dict()["worst_ratio"] == ratio
