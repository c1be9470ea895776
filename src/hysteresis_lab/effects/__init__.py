"""The catalogue of physical effects a model can declare (``model.effects=[hysteresis, creep]``).

One file per effect (`hysteresis_lab.effects.hysteresis`, ``.creep``, ...) owns all its
faces (`hysteresis_lab.effects.base.Effect`): its input operators and the evidence the
diagnosis scores, its simulator block, its trainable blocks for ``model=linear`` and the
grey-box, and where it sits in a plant. Effects register through the entry-point group
``hysteresis_lab.effects`` exactly like models do; a plugin effect is one file and one entry
point (``plugins/hysteresis_lab_cubic``).
"""
