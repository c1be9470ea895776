"""Compiled and NumPy free-run kernels: fast sequential simulation for the evaluation.

Free run is sequential (~200,000 steps for the 0.1 Hz test sine), so its per-step cost
decides the evaluation's speed. A model offers a kernel through one of two hooks, and
`hysteresis_lab.evaluation.predict` uses it when the model runs on the CPU:

* ``free_run_kernel(u_scaled, window)`` returns a `interface.FreeRunKernel` (step by step,
  or every step at once with ``run_all``): FFNN (`ffnn`: compiled ``run_all``, the NumPy
  step of `interface.FlatKernel` for restarts), SVR (`interface.FlatKernel`, `svm`), LSTM
  (`lstm`), CNN (`cnn`);
* ``compiled_free_run(...)`` of a state-space model: SUBNET (`subnet`).

**The reference path** is each model's own torch (or scikit-learn) prediction stepped in
Python: ``hysteresis_lab.evaluation.predict.free_run(..., fast=False)`` for the NARX models,
the torch loop of `hysteresis_lab.models.state_space.StateSpaceModule.simulate_recordings`
(taken on a GPU or with restarts) for SUBNET. Every kernel is tested against its reference
(``tests/test_*_kernel.py``, ``tests/test_state_space.py``). The physical
chains (``greybox``, ``linear``) need no kernel here: their blocks are numba recursions
already (`hysteresis_lab.blocks`).

Modules: `interface` (the kernel protocol and the NumPy flat kernel), `jit_ops` (numba
building blocks shared by the compiled kernels), `ffnn`, `cnn`, `lstm`, `svm`, `subnet`.
"""
