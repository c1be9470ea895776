"""The physics floor: the recursions every effect, simulator block and trainable block runs.

Each recursion lives here once, in NumPy/numba (float64, the simulator and the free-run
kernels) and in torch with its adjoint (the trainable blocks):

* `hysteresis_lab.physics.play`: the Prandtl–Ishlinskii play operator;
* `hysteresis_lab.physics.bouc_wen`: Bouc–Wen hysteresis, the exact per-sample update;
* `hysteresis_lab.physics.filters`: first-order filter banks (creep), resonators, modes and
  the IIR filter with exact gradients, and their one-sample steps;
* `hysteresis_lab.physics.static`: static input laws (dead zone, clip, rate).

Nothing here imports the simulator, the blocks, the effects or the models.
"""
