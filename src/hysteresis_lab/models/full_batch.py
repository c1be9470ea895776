"""L-BFGS on whole recordings (``training.optimizer=lbfgs``): the second-order path of the
physical models, whose few parameters and deterministic full-batch loss (each recording
simulated from rest) suit a quasi-Newton step with a line search better than Adam's fixed
rate. `torch.optim.LBFGS` with the strong-Wolfe line search does the work.

An epoch is one L-BFGS step of `iterations` iterations over every training recording; the
learning rate and schedule do not apply (the line search sets each step's length), and a
stage ends once an epoch lowers the loss by less than `CONVERGED` of it. A trial
point whose free run is not finite (a step that leaves the stable region) returns a loss far
above the step's start with no gradient, so the line search steps back towards the start;
an infinite one would turn its cubic interpolation into NaN and end the step where it began.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import torch

#: past gradients the inverse-Hessian estimate keeps (the models have tens of parameters)
HISTORY = 50
#: the step stops where no gradient entry exceeds this, or the loss changes by less than
#: `TOLERANCE_CHANGE` (the scaled free-run MSE of a good fit is ~1e-7: the defaults of
#: `torch.optim.LBFGS`, 1e-7 and 1e-9, would stop far short of it)
TOLERANCE_GRAD, TOLERANCE_CHANGE = 1e-12, 1e-15
#: an epoch (one step of its iterations) that lowers the loss by less than this share of it:
#: converged, the stage ends
CONVERGED = 1e-4
#: the loss of a trial point whose free run is not finite: this many times the step's start
#: (at least `NON_FINITE_FLOOR`)
NON_FINITE_FACTOR, NON_FINITE_FLOOR = 1e3, 1.0


def make_lbfgs(parameters: Iterable[torch.nn.Parameter], iterations: int) -> torch.optim.LBFGS:
    """L-BFGS over ``parameters`` (the trainable ones), ``iterations`` per step."""
    return torch.optim.LBFGS(
        [p for p in parameters if p.requires_grad],
        lr=1.0,
        max_iter=iterations,
        history_size=HISTORY,
        line_search_fn="strong_wolfe",
        tolerance_grad=TOLERANCE_GRAD,
        tolerance_change=TOLERANCE_CHANGE,
    )


def lbfgs_closure(
    optimizer: torch.optim.Optimizer, loss_of: Callable[[], torch.Tensor],
    backward: Callable[[torch.Tensor], None],
) -> Callable[[], torch.Tensor]:
    """The closure L-BFGS evaluates in one step: the loss and its gradient at the current
    parameters. A non-finite loss comes with zero gradients: at the step's start (its first
    evaluation) as +inf (the fit has diverged); at a trial point as a finite loss far above
    the start (`NON_FINITE_FACTOR`), which the strong-Wolfe line search steps back from."""
    start: float | None = None

    def closure() -> torch.Tensor:
        nonlocal start
        optimizer.zero_grad()
        loss = loss_of()
        value = float(loss.detach())
        if start is None:  # the step's start
            start, far = value, math.inf
        else:
            far = (max(NON_FINITE_FLOOR, NON_FINITE_FACTOR * abs(start))
                   if math.isfinite(start) else math.inf)
        if not math.isfinite(value):
            for group in optimizer.param_groups:
                for parameter in group["params"]:
                    parameter.grad = torch.zeros_like(parameter)
            return torch.tensor(far, dtype=loss.dtype)
        backward(loss)
        return loss

    return closure
