"""The catalogue of physical effects a model can declare (``model.effects=[hysteresis, creep]``).

Each effect adds input operators computed from the measured input ``u`` (play operators,
creep filter bank, resonant filters, rates, clipped inputs, ...) and offers the same signals
as residual evidence for the diagnosis. Effects register through the entry-point group
``hysteresis_lab.effects`` exactly like models do.
"""
