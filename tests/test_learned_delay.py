"""The grey-box's learned input delay (``model.delay_span``, `LearnedDelay`): an integer delay
to start, a Lagrange fractional delay within the span learned on the simulation error."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hysteresis_lab.blocks._util import logit
from hysteresis_lab.blocks.fractional_delay import LearnedDelay
from hysteresis_lab.blocks.linear import Delay
from hysteresis_lab.blocks.step import StepState
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.greybox import GreyBox
from hysteresis_lab.signals import multisine

FS = 20_000.0


def _move(block: LearnedDelay, samples: float) -> None:
    """Set the block's learned delay."""
    with torch.no_grad():
        block.raw_offset.fill_(logit((samples - block.whole) / block.order))


@pytest.mark.parametrize(("samples", "span"), [(0, 1), (3, 1), (1, 2), (5, 2)])
def test_it_starts_as_the_integer_delay_and_steps_as_it_simulates(samples, span):
    """It starts at the integer delay (exactly inside its range; 1e-3 samples from a range's
    edge); stepped sample by sample it gives what it simulates."""
    x = torch.randn(2, 60, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    block = LearnedDelay(samples, span)
    exact = samples >= span
    assert block.delay_samples == pytest.approx(samples, abs=0.0 if exact else 1.01e-3)
    torch.testing.assert_close(block(x), Delay(samples)(x), rtol=0, atol=0 if exact else 1e-2)
    _move(block, samples + 0.37)
    state = torch.zeros(2, len(block.state_names()), dtype=torch.float64)
    stepped = []
    for t in range(x.shape[1]):
        held = StepState(state)
        stepped.append(block.step(x[:, t], held))
        state = held.next_state()
    torch.testing.assert_close(torch.stack(stepped, dim=1), block(x))
    assert block.delay_samples == pytest.approx(samples + 0.37)


@pytest.mark.parametrize(("start", "true"), [(3, 4.0), (4, 3.0), (2, 2.6)])
def test_the_simulation_error_moves_it_to_the_signals_delay(start, true):
    """A band-limited signal delayed by ``true`` samples (whole or not): from a sample off,
    the delay is learned to within 0.02 samples."""
    n = 4000
    u = multisine(n + 64, FS, n_components=200, f_max=500.0, seed=3)
    spectrum = np.fft.rfft(u)
    shift = np.exp(-2j * np.pi * np.fft.rfftfreq(len(u)) * true)  # an exact delay
    target = torch.from_numpy(np.fft.irfft(spectrum * shift, len(u))[64:])
    x = torch.from_numpy(u)[None]
    block = LearnedDelay(start, span=1)
    optimiser = torch.optim.LBFGS(block.parameters(), max_iter=50, line_search_fn="strong_wolfe")

    def loss() -> torch.Tensor:
        optimiser.zero_grad()
        value = (block(x)[0, 64:] - target).pow(2).mean()
        value.backward()
        return value

    optimiser.step(loss)
    assert block.delay_samples == pytest.approx(true, abs=0.02)


def _greybox(**settings):
    return GreyBox(nu=1, ny=1, hysteresis="bouc_wen", delay=3, n_modes=1, **settings)


def test_the_greybox_learns_its_delay_at_span_one_and_keeps_it_fixed_at_span_zero():
    learned, fixed = _greybox(delay_span=1), _greybox(delay_span=0)
    assert isinstance(learned.delay, LearnedDelay) and learned.delay.samples == 3
    assert type(fixed.delay) is Delay and fixed.delay.samples == 3
    names = dict(learned.named_parameters())
    assert "delay.raw_offset" in names and names["delay.raw_offset"].requires_grad
    assert not any(name.startswith("delay.") for name, _ in fixed.named_parameters())


def test_a_bad_delay_span_is_named():
    with pytest.raises(ConfigError, match="model.delay_span"):
        _greybox(delay_span=-1)


def test_a_delay_the_data_cannot_show_stays_fixed_at_its_placeholder():
    """Where the training input excites too few frequencies to read the delay off (one slow
    sine), the delay's placeholder (one sample) is not learned either; where they show it,
    the delay read is learned within its span."""
    fs = 1000.0
    t = np.arange(4000) / fs
    slow = np.sin(2 * np.pi * 2.0 * t)
    blind = GreyBox(nu=1, ny=1, hysteresis="bouc_wen", delay="auto", n_modes="auto", fs=fs,
                    delay_span=1)
    blind.initialise_from_data(slow, 0.5 * slow, fs)
    assert type(blind.delay) is Delay and blind.delay.samples == 1
    assert blind.hparams["delay_span"] == 0

    rich = np.random.default_rng(0).normal(size=t.size)
    seeing = GreyBox(nu=1, ny=1, hysteresis="bouc_wen", delay="auto", n_modes="auto", fs=fs,
                     delay_span=1)
    seeing.initialise_from_data(rich, 0.5 * np.roll(rich, 2), fs)
    assert isinstance(seeing.delay, LearnedDelay)
