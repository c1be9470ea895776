"""Hydra sweeper ``hydra/sweeper=hysteresis_lab``: resumable, distributed Optuna studies."""
