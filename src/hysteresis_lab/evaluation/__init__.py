"""Scoring fitted models: one-step, n-step and free-run prediction, metrics, reports, figures."""
