"""Hydra configs of the GRU plugin (``model/gru.yaml``)."""
