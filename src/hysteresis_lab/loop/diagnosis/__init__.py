"""Residual analysis and the diagnose -> augment -> refit loop."""
