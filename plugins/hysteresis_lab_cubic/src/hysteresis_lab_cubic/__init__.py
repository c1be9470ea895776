"""Example third-party effect for hysteresis_lab: a cubic law of the drive (`CubicInput`)."""
