"""The packaged Hydra configs (``pkg://hysteresis_lab.conf``)."""
