"""L-BFGS on whole recordings (``training.optimizer=lbfgs``): the second-order path of the
physical models, whose few parameters and deterministic full-batch loss (each recording
simulated from rest) suit a quasi-Newton step with a line search better than Adam's fixed
rate. `torch.optim.LBFGS` with the strong-Wolfe line search does the work.

An epoch is one L-BFGS step of `iterations` iterations over every training recording; the
learning rate and schedule do not apply (the line search sets each step's length), and a
stage ends once an epoch lowers the loss by less than `CONVERGED` of it. A trial
point whose free run is not finite returns an infinite loss with no gradient, so the line
search shortens its step instead of stopping the fit.
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
    """The closure L-BFGS evaluates: the loss and its gradient at the current parameters; a
    non-finite loss is returned as +inf with zero gradients (the line search steps back)."""

    def closure() -> torch.Tensor:
        optimizer.zero_grad()
        loss = loss_of()
        if not math.isfinite(float(loss.detach())):
            for group in optimizer.param_groups:
                for parameter in group["params"]:
                    parameter.grad = torch.zeros_like(parameter)
            return torch.tensor(math.inf, dtype=loss.dtype)
        backward(loss)
        return loss

    return closure
