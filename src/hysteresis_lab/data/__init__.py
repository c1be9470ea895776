"""Recordings, file readers, bundled benchmark loaders, regression windows and DataModules."""

from hysteresis_lab.data.recording import Recording

__all__ = ["Recording"]
