"""Example hysteresis_lab plugin: a GRU NARX network (``model=gru``)."""
