"""Bayesian hyperparameter tuning: a resumable, distributable Optuna study behind Hydra multirun."""
