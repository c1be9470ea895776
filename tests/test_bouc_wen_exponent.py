"""The Bouc–Wen exponent of the models' cell: the sub-stepped update's adjoint against finite
differences, the exact update kept at ``n = 1`` (to the last bit), the bound ``n >= 1``
held by projection, the one-sample step, and a fit that recovers an exponent."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cells import fit_lbfgs, stepped, walk
from hysteresis_lab.blocks import BoucWen, bouc_wen_free_run
from hysteresis_lab.blocks.step import StepState
from hysteresis_lab.physics.bouc_wen import BoucWenStates, bouc_wen_state


def _sine(n: int = 600) -> torch.Tensor:
    t = np.linspace(0.0, 1.0, n)
    return torch.tensor((np.sin(2 * np.pi * 2 * t) * (0.4 + 0.6 * t))[None])


def test_exponent_gradcheck_includes_zero_crossings() -> None:
    """The adjoint of the sub-stepped update, w.r.t. every input and the exponents, against
    finite differences, on steps that cross ``h = 0`` (one element at ``n = 1``)."""
    v = walk(30, 1).requires_grad_()
    v0 = torch.tensor([0.1, -0.2], dtype=torch.float64, requires_grad=True)
    h0 = torch.tensor([[0.05, -0.1], [-0.2, 0.02]], dtype=torch.float64, requires_grad=True)
    a = torch.tensor([0.37, 0.2], dtype=torch.float64, requires_grad=True)
    r1 = torch.tensor([1.4, 0.5], dtype=torch.float64, requires_grad=True)
    r2 = torch.tensor([2.6, 1.5], dtype=torch.float64, requires_grad=True)
    n = torch.tensor([1.6, 2.3], dtype=torch.float64, requires_grad=True)

    def states(*args: torch.Tensor) -> torch.Tensor:
        return BoucWenStates.apply(*args[:6], None, args[6])

    assert torch.autograd.gradcheck(states, (v, v0, h0, a, r1, r2, n), atol=1e-6, rtol=1e-4)
    hs = states(v, v0, h0, a, r1, r2, n).detach().numpy()
    assert (np.sign(hs[:, 1:]) * np.sign(hs[:, :-1]) < 0).sum() >= 2  # crossings exercised


def test_module_exponent_gradient_matches_finite_differences() -> None:
    """d loss / d raw exponent of the module (the rates rescaled with it) against a central
    difference, above the bound."""
    bw = BoucWen(d=1.0, alpha=0.32, beta=2.0, gamma=0.6, learn_exponent=True)
    v = _sine()
    with torch.no_grad():
        bw.raw_exponent.fill_(0.8)
    x, _ = bw(v)
    x.square().sum().backward()
    eps = 1e-6
    losses = []
    for shift in (eps, -eps):
        with torch.no_grad():
            bw.raw_exponent.fill_(0.8 + shift)
            losses.append(float(bw(v)[0].square().sum()))
    numeric = (losses[0] - losses[1]) / (2 * eps)
    assert float(bw.raw_exponent.grad[0]) == pytest.approx(numeric, rel=1e-4)


def test_n_equal_one_is_the_exact_update_to_the_last_bit() -> None:
    """A learnable exponent at 1 runs the exact update: the same states as the simulator's
    and the same gradients for every other parameter as a cell without the exponent."""
    v = _sine()
    learned = BoucWen(d=1.0, alpha=0.32, beta=2.0, gamma=0.6, learn_exponent=True)
    fixed = BoucWen(d=1.0, alpha=0.32, beta=2.0, gamma=0.6, learn_exponent=False)
    x_learned, _ = learned(v)
    x_fixed, _ = fixed(v)
    h_sim = bouc_wen_state(v[0].numpy(), 1.0, np.full(v.shape[1], 0.32), 2.0, 0.6)
    np.testing.assert_array_equal(x_learned.detach().numpy(), x_fixed.detach().numpy())
    np.testing.assert_array_equal(x_learned.detach().numpy()[0], 1.0 * v[0].numpy() - h_sim)
    x_learned.square().sum().backward()
    x_fixed.square().sum().backward()
    for name, p in fixed.named_parameters():
        np.testing.assert_array_equal(dict(learned.named_parameters())[name].grad.numpy(),
                                      p.grad.numpy(), err_msg=name)
    assert float(learned.exponent.detach()[0]) == 1.0


def test_the_bound_lets_the_exponent_rise_only() -> None:
    """At ``n = 1`` the raw exponent gets a gradient only where raising ``n`` lowers the
    loss; below the bound the exponent stays exactly 1 and climbs back where it pays."""
    v = _sine()
    bw = BoucWen(d=1.0, alpha=0.32, beta=2.0, gamma=0.6, learn_exponent=True)
    with torch.no_grad():
        sharp = bw(v)[0]  # n = 1
        bw.raw_exponent.fill_(1.0)
        blunt = bw(v)[0]  # n = 2
        bw.raw_exponent.zero_()
    (bw(v)[0] - blunt).square().sum().backward()
    assert float(bw.raw_exponent.grad[0]) < 0.0  # descent raises n
    bw.zero_grad()
    beyond = sharp - 0.5 * (blunt - sharp)  # as if n < 1: raising n costs
    (bw(v)[0] - beyond).square().sum().backward()
    assert float(bw.raw_exponent.grad[0]) == 0.0
    assert float(bw.raw_alpha.grad[0]) != 0.0
    with torch.no_grad():
        bw.raw_exponent.fill_(-0.5)
    assert float(bw.exponent[0]) == 1.0
    bw.zero_grad()
    (bw(v)[0] - blunt).square().sum().backward()
    assert float(bw.raw_exponent.grad[0]) < 0.0


def test_step_and_free_run_match_the_batched_update() -> None:
    """At ``n != 1`` the one-sample torch step and the compiled free run run the batched
    update's scheme; the simulator's finer sub-steps give the same loop to 1e-4."""
    bw = BoucWen(d=1.0, alpha=0.32, beta=2.0, gamma=0.6, n_channels=2, learn_exponent=True)
    with torch.no_grad():
        bw.raw_exponent.copy_(torch.tensor([0.7, 1.4], dtype=torch.float64))
    v = walk(300, 6, step=0.05)
    with torch.no_grad():
        whole, _ = bw(v)
    np.testing.assert_allclose(stepped(bw, v).numpy(), whole.numpy(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(bw.numpy_kernel()(v.numpy()), whole.numpy(), rtol=0, atol=1e-12)
    p = bw.export()
    one = bouc_wen_free_run(v.numpy()[:1], p["d"], p["alpha"][0], p["beta"][0], p["gamma"][0],
                            exponent=p["exponent"][0])
    sim = bouc_wen_state(v.numpy()[0], p["d"], np.full(v.shape[1], p["alpha"][0]),
                         p["beta"][0], p["gamma"][0], p["exponent"][0])
    np.testing.assert_allclose(one[0], p["d"] * v.numpy()[0] - sim, rtol=0, atol=1e-4)


def test_the_exponent_keeps_the_saturated_state() -> None:
    """Raising ``n`` rescales the rates so the state saturates where it did at ``n = 1``."""
    bw = BoucWen(d=1.0, alpha=0.32, beta=2.0, gamma=0.6, learn_exponent=True)
    ramp = torch.linspace(0.0, 5.0, 2000, dtype=torch.float64)[None]
    saturated = []
    for raw in (0.0, 1.5):
        with torch.no_grad():
            bw.raw_exponent.fill_(raw)
            x, h_last = bw(ramp)
        saturated.append(float(h_last[0]))
    assert saturated[1] == pytest.approx(saturated[0], rel=1e-3)
    assert saturated[0] == pytest.approx(0.32 / 2.6, rel=1e-3)


def test_a_fit_recovers_the_exponent() -> None:
    """Data of an ``n = 2`` cell: fitted from ``n = 1`` (every parameter free), the exponent
    comes back near 2 and the error falls far below that of the best ``n = 1`` cell."""
    v = _sine(800)
    target_cell = BoucWen(d=1.0, alpha=0.32, beta=2.0, gamma=0.6, learn_exponent=True)
    with torch.no_grad():
        target_cell.raw_exponent.fill_(1.0)
        target = target_cell(v)[0]

    def fitted(learn: bool) -> tuple[BoucWen, float]:
        cell = BoucWen(d=1.0, alpha=0.25, beta=1.5, gamma=0.3, learn_exponent=learn)
        return cell, fit_lbfgs(cell, lambda: cell(v)[0], target, max_iter=200)

    cell, loss = fitted(True)
    _, loss_fixed = fitted(False)
    assert float(cell.exponent[0]) == pytest.approx(2.0, abs=0.1)
    assert loss < 0.01 * loss_fixed


def test_a_state_saved_without_the_exponent_loads_at_one() -> None:
    old = BoucWen(learn_exponent=False).state_dict()
    bw = BoucWen(learn_exponent=True)
    with torch.no_grad():
        bw.raw_exponent.fill_(0.5)
    bw.load_state_dict(old)
    assert float(bw.exponent[0]) == 1.0


def test_the_derivative_at_one_is_the_schemes() -> None:
    """The cheap exponent derivative at ``n = 1`` equals the full tangent's component."""
    from hysteresis_lab.physics.bouc_wen import advance_exponent_grad, exponent_derivative_at_one

    rng = np.random.default_rng(0)
    work = np.empty((6, 6))
    for _ in range(200):
        h, x, s = rng.normal(0, 0.2), abs(rng.normal(0, 0.3)), float(rng.choice([-1.0, 1.0]))
        r1, r2 = rng.uniform(0.2, 3.0), rng.uniform(0.5, 5.0)
        full = advance_exponent_grad(h, x, s, 0.3, r1, r2, 1.0, 0.5 / max(r1, r2), work)[6]
        cheap = exponent_derivative_at_one(h, x, s, 0.3, r1, r2, 0.5 / max(r1, r2))
        assert cheap == pytest.approx(full, rel=1e-12, abs=1e-15)


def test_a_cell_whose_exponent_left_1_refuses_onnx_tracing_with_the_fix():
    bw = BoucWen(d=1.0, alpha=0.32, beta=2.0, gamma=0.6, learn_exponent=True)
    bw.requires_grad_(False)  # traced as constants, as an export freezes them
    bw.raw_exponent.fill_(0.5)
    state0 = torch.zeros(1, len(bw.state_names()), dtype=torch.float64)

    def one_step(v: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        return bw.step(v, StepState(state.clone()))

    with pytest.raises(ValueError, match="model.learn_exponent=false"):
        torch.jit.trace(one_step, (torch.tensor([0.3], dtype=torch.float64), state0))
    bw.raw_exponent.fill_(0.0)  # back at 1: the exact update traces
    torch.jit.trace(one_step, (torch.tensor([0.3], dtype=torch.float64), state0))


def test_the_greybox_learns_the_exponent_of_any_bouc_wen_cell_it_is_told_to() -> None:
    """``model.learn_exponent=true``: the Bouc–Wen cell built, and the one ``auto`` sets
    once the data choose it, learn their exponent; by default they hold it at 1."""
    from hysteresis_lab.models.greybox import GreyBox

    settings = {"nu": 1, "ny": 1, "fs": 20_000.0, "delay": 1, "n_modes": 1}
    assert GreyBox(**settings, hysteresis="bouc_wen").hysteresis.raw_exponent is None
    assert GreyBox(**settings, hysteresis="bouc_wen",
                   learn_exponent=True).hysteresis.raw_exponent is not None
    chosen = GreyBox(**settings, hysteresis="auto", learn_exponent=True)
    chosen._set_cell("prandtl_ishlinskii")
    chosen._set_cell("bouc_wen")
    assert chosen.hysteresis.raw_exponent is not None


def test_an_exponent_freed_on_a_fitted_cell_starts_where_the_loss_is_continuous_in_it() -> None:
    """The polish frees the exponent of a cell fitted at 1: the warm start puts it at
    `FREED_EXPONENT_START`. There a step of 1e-9 in it moves the output by about as much; from
    exactly 1 the same step swaps the exact update for Runge–Kutta sub-steps and jumps the
    output by ~1e-4 on a fast drive, more than a line search near the optimum can gain. An
    exponent the earlier model learned is carried as it is."""
    from hysteresis_lab.blocks.bouc_wen import FREED_EXPONENT_START
    from hysteresis_lab.models.greybox import GreyBox

    settings = {"nu": 1, "ny": 1, "fs": 20_000.0, "delay": 1, "n_modes": 1,
                "hysteresis": "bouc_wen"}
    freed = GreyBox(**settings, learn_exponent=True)
    freed.warm_start_from(GreyBox(**settings))
    cell = freed.hysteresis
    assert float(cell.exponent) == pytest.approx(FREED_EXPONENT_START)

    v = walk(4000, seed=0, batch=1)  # steps as large as a fast multisine's

    def jump_of_a_small_step() -> float:
        with torch.no_grad():
            before = cell(v)[0]
            cell.raw_exponent += 1e-9
            after = cell(v)[0]
            cell.raw_exponent -= 1e-9
        return float((after - before).abs().max())

    assert jump_of_a_small_step() < 1e-7
    with torch.no_grad():
        cell.raw_exponent.fill_(0.0)
    assert jump_of_a_small_step() > 1e-6

    with torch.no_grad():
        cell.raw_exponent.fill_(0.3)
    again = GreyBox(**settings, learn_exponent=True)
    again.warm_start_from(freed)
    assert float(again.hysteresis.exponent) == pytest.approx(1.3)
