"""The modes' feedthrough: a share of the input passed on directly (the residual stiffness of
modes above the modelled ones), in the torch run, the step, the numba chain, old saved states
and the grey-box."""

from __future__ import annotations

import numpy as np
import torch

from cells import fit_lbfgs, stepped, walk
from hysteresis_lab.blocks import BlockChain, SecondOrderMode, simulate_chain

FS = 20_000.0


def _with_share(share: float, n_modes: int = 1) -> SecondOrderMode:
    mode = SecondOrderMode(FS, 500.0, 0.01, n_modes=n_modes, feedthrough=True)
    with torch.no_grad():
        mode.raw_feedthrough.fill_(share)
    return mode


def test_the_share_passes_the_input_beside_the_mode() -> None:
    x = walk(3000, seed=0)
    plain = SecondOrderMode(FS, 500.0, 0.01)
    mode = _with_share(0.3)
    with torch.no_grad():
        expected = 0.7 * plain(x) + 0.3 * x
        np.testing.assert_allclose(mode(x).numpy(), expected.numpy(), atol=1e-12)
    with torch.no_grad():  # the shares still sum to one: the unit DC gain is kept
        assert abs(float(mode.weights.sum() + mode.feedthrough_share) - 1.0) < 1e-12


def test_its_step_and_the_numba_chain_run_as_the_torch_run() -> None:
    x = walk(2000, seed=1)
    for n_modes in (1, 2):
        mode = _with_share(-0.2, n_modes)
        with torch.no_grad():
            whole = mode(x)
        np.testing.assert_allclose(stepped(mode, x).numpy(), whole.numpy(), atol=1e-10)
        chain = BlockChain(mode=mode).double()
        np.testing.assert_allclose(simulate_chain(x.numpy(), chain.export()), whole.numpy(),
                                   atol=1e-10)


def test_a_state_saved_without_it_loads_at_share_zero() -> None:
    old = SecondOrderMode(FS, 800.0, 0.02)
    new = _with_share(0.5)
    new.load_state_dict(old.state_dict())
    x = walk(1000, seed=2)
    assert float(new.feedthrough_share) == 0.0
    with torch.no_grad():
        np.testing.assert_allclose(new(x).numpy(), old(x).numpy(), atol=1e-12)


def test_it_fits_a_mode_with_a_stiff_mode_above_it() -> None:
    """A resonance plus a flat share (a mode far above the band): one mode with a
    feedthrough holds it, one mode alone cannot."""
    x = walk(4000, seed=3, batch=1, step=0.05)
    with torch.no_grad():
        target = _with_share(0.25)(x)
    errors = {}
    for feedthrough in (False, True):
        mode = SecondOrderMode(FS, 480.0, 0.015, feedthrough=feedthrough)
        errors[feedthrough] = fit_lbfgs(mode, lambda m=mode: m(x), target, max_iter=200)
    scale = float(torch.mean(target ** 2))
    assert errors[True] < 1e-6 * scale
    assert errors[False] > 100 * errors[True]


def test_the_greybox_carries_it_unless_switched_off_and_grows_it() -> None:
    from hysteresis_lab.models.greybox import GreyBox

    settings = {"nu": 1, "ny": 1, "fs": FS, "hysteresis": "bouc_wen", "delay": 1}
    fitted = GreyBox(**settings, n_modes=1)
    assert GreyBox(**settings, n_modes=1, feedthrough=False).mode.raw_feedthrough is None
    with torch.no_grad():
        fitted.mode.raw_feedthrough.fill_(0.2)
    grown = GreyBox(**settings, n_modes=2)
    with torch.no_grad():
        grown._grow_mode(fitted.mode)
    assert float(grown.mode.feedthrough_share) == 0.2
    np.testing.assert_allclose(grown.mode.weights.detach().numpy(), [0.8, 0.0])
