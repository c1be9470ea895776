"""hysteresis_lab: deep-learning identification of hysteretic actuators."""

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import HysteresisLabError

__all__ = ["HysteresisLabError", "Recording"]
__version__ = "0.1.0"
