"""The rate-dependent Bouc–Wen cell (effect ``rate`` of ``model=linear``): its kernel's
gradients, the simulator's law, its one-sample step, its start and a fit of its gain."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cells import fit_lbfgs, stepped, walk
from hysteresis_lab.blocks import BoucWen
from hysteresis_lab.effects.hysteresis import HysteresisCell
from hysteresis_lab.physics.bouc_wen import BoucWenStates, bouc_wen_state


def _rate_cell(gain: float, weight: float = 0.8, rate_step: float = 0.05) -> HysteresisCell:
    cell = HysteresisCell(rate_step)
    with torch.no_grad():
        cell.weight.fill_(weight)
        cell.rate_gain.fill_(gain)
    return cell


def test_per_sample_alpha_gradcheck_includes_zero_crossings() -> None:
    """The kernel's adjoint with a per-sample factor of ``a``: gradients w.r.t. every input,
    the factor included, on steps that cross ``h = 0``."""
    v = walk(40, 1).requires_grad_()
    v0 = torch.tensor([0.1, -0.2], dtype=torch.float64, requires_grad=True)
    h0 = torch.tensor([[0.05, -0.1], [-0.2, 0.02]], dtype=torch.float64, requires_grad=True)
    a = torch.tensor([0.37, 0.2], dtype=torch.float64, requires_grad=True)
    r1 = torch.tensor([1.4, 0.5], dtype=torch.float64, requires_grad=True)
    r2 = torch.tensor([2.6, 1.5], dtype=torch.float64, requires_grad=True)
    m = torch.tensor(np.random.default_rng(2).uniform(0.5, 3.0, (2, 40)), requires_grad=True)
    assert torch.autograd.gradcheck(BoucWenStates.apply, (v, v0, h0, a, r1, r2, m))
    hs = BoucWenStates.apply(v, v0, h0, a, r1, r2, m).detach().numpy()
    assert (np.sign(hs[:, 1:]) * np.sign(hs[:, :-1]) < 0).sum() >= 2  # crossings exercised
    plain = BoucWenStates.apply(v, v0, h0, a, r1, r2).detach().numpy()
    assert np.max(np.abs(hs - plain)) > 1e-3  # the factor acts


def test_rate_cell_gradcheck_through_the_rate() -> None:
    """Gradients of the whole cell (the factor from ``|dv|``) w.r.t. the input and the gain."""
    cell = _rate_cell(0.7)
    v = walk(30, 4, batch=1).requires_grad_()
    gain = torch.tensor(0.7, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda x, g: torch.func.functional_call(cell, {"rate_gain": g}, (x,)), (v, gain))


def test_per_sample_alpha_is_the_simulators_law() -> None:
    """``alpha_factor`` runs the simulator's per-sample ``alpha`` (physics.bouc_wen)."""
    rng = np.random.default_rng(3)
    v = np.concatenate([[0.0], 60.0 * np.sin(np.linspace(0, 12, 399)) + rng.normal(0, 2, 399)])
    factor = 1.0 + 0.5 * np.abs(np.diff(v, prepend=v[0])) / 3.0
    d, alpha, beta, gamma = 0.23, 0.32, 0.02, 0.006
    x_sim = d * v - bouc_wen_state(v, d, alpha * factor, beta, gamma)
    x, _ = BoucWen(d, alpha, beta, gamma)(torch.tensor(v[None]),
                                          alpha_factor=torch.tensor(factor[None]))
    np.testing.assert_allclose(x.detach().numpy()[0], x_sim, rtol=0, atol=1e-10)


def test_rate_cell_starts_as_the_plain_cell_and_its_gain_acts() -> None:
    plain = HysteresisCell()
    rated = HysteresisCell(0.05)
    rated.load_state_dict(plain.state_dict(), strict=False)  # the loop's warm start
    with torch.no_grad():
        for cell in (plain, rated):
            cell.weight.fill_(0.8)
    v = walk(200, 5, step=0.05)
    with torch.no_grad():
        np.testing.assert_array_equal(rated(v).numpy(), plain(v).numpy())
        rated.rate_gain.fill_(0.5)
        assert torch.max(torch.abs(rated(v) - plain(v))) > 1e-3


@pytest.mark.parametrize("gain", [0.5, -3.0])  # -3: the factor clips at zero on fast steps
def test_rate_cell_step_matches_its_free_run(gain: float) -> None:
    cell = _rate_cell(gain)
    v = walk(300, 6, step=0.05)
    with torch.no_grad():
        whole = cell(v)
    np.testing.assert_allclose(stepped(cell, v).numpy(), whole.numpy(), rtol=0, atol=1e-12)


def test_a_fit_recovers_the_rate_gain() -> None:
    """Data of a cell with gain 0.5 on a signal with slow and fast parts: the cell's gain
    fitted from 0 (the Bouc–Wen parameters free too) comes back near 0.5."""
    t = np.linspace(0.0, 1.0, 2000)
    v = torch.tensor((np.sin(2 * np.pi * 3 * t) + 0.3 * np.sin(2 * np.pi * 60 * t))[None])
    rate_step = HysteresisCell.rate_step_for(1.3)
    with torch.no_grad():
        target = _rate_cell(0.5, weight=1.0, rate_step=rate_step)(v)
    cell = _rate_cell(0.0, weight=1.0, rate_step=rate_step)
    fit_lbfgs(cell, lambda: cell(v), target, max_iter=100)
    assert float(cell.rate_gain.detach()) == pytest.approx(0.5, abs=0.05)


def test_rate_alone_brings_the_cell_and_the_loop_refits_whole() -> None:
    """``effects=[rate]`` builds the rate-dependent input cell (no feedback force), at no
    effect; the loop refits the whole model when it adds ``rate`` (the fitted ``alpha``
    shares the loop width with the gain)."""
    from hysteresis_lab.data.datamodules import WindowDataModule
    from hysteresis_lab.fitting import build_model
    from hysteresis_lab.loop.driver import _refit_mode
    from hysteresis_lab.models.augment import augment_splits, context_to_dict
    from hysteresis_lab.models.linear import LinearModel
    from hysteresis_lab.sim.default_dataset import make_default_dataset

    data = make_default_dataset(effects={}, n_train=2000, test_frequencies=(10.0,),
                                max_test_samples=500, val_samples=0)
    augmented, context = augment_splits(data, ["rate"])
    model = build_model({"name": "linear", "effects": ["rate"]},
                        WindowDataModule(augmented, scaling="paper"), trained_on={"fs": data.fs},
                        feature_context=context_to_dict(context), n_base_inputs=1)
    cell = model.input_blocks[0]["hysteresis"]
    assert float(cell.rate_gain.detach()) == 0.0 and float(cell.weight.detach()) == 0.0
    amplitude = model._input_amplitude(0)
    assert float(cell.rate_step) == pytest.approx(2 * np.pi * amplitude / 200)
    assert model.effect_sites["force"] == []  # rate alone brings no restoring force
    assert _refit_mode("new_inputs", "rate", LinearModel) == "full"
