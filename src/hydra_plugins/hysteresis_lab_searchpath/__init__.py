"""Hydra search-path plugin: config folders registered by hysteresis_lab plugin packages."""
