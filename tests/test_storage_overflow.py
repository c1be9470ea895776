"""The storage overflow effect (an internal storage that spills over its rim, carried by
model=linear as an input block) and the learned shared initial state of physical chains."""

from __future__ import annotations

import numpy as np
import torch

from hysteresis_lab.blocks.spill import storage_spill
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.catalogue import StorageOverflow
from hysteresis_lab.models.linear import StorageSpill
from hysteresis_lab.training import build_model
from hysteresis_lab.workflows.pipeline import _trained_on
from narx import datamodule_for, narx_data


def test_the_spill_has_exact_gradients_and_holds_the_rim():
    """Exact gradients w.r.t. the input, the rates and the rims; a storage below its rim
    spills nothing, one filled past it spills what passes it and keeps its level there."""
    gen = torch.Generator().manual_seed(0)
    v = (0.5 * torch.randn(2, 50, dtype=torch.float64, generator=gen).cumsum(1)).requires_grad_()
    alpha = torch.tensor([0.3, 0.9, 0.05], dtype=torch.float64, requires_grad=True)
    rim = torch.tensor([0.5, 1.0, 0.2], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(storage_spill, (v, alpha, rim))
    assert float(storage_spill(v, alpha, rim).detach().abs().sum()) > 1.0

    one = torch.tensor([0.5], dtype=torch.float64)
    below = storage_spill(torch.full((1, 30), 0.8, dtype=torch.float64), one,
                          torch.tensor([1.0], dtype=torch.float64))
    assert float(below.abs().max()) == 0.0
    full = storage_spill(torch.full((1, 30), 3.0, dtype=torch.float64), one,
                         torch.tensor([1.0], dtype=torch.float64))[0, :, 0].numpy()
    # at the rim, each sample fills half the way to 3 and spills it: 0.5 * (3 - 1)
    np.testing.assert_allclose(full[-5:], 1.0, atol=1e-12)


def test_the_block_starts_at_no_effect_and_an_instant_storage_clips():
    """Weights at zero: the input as it is; one storage filling at once (rate 1) that loses
    all its spill: the input clipped at the rim."""
    v = torch.linspace(-1.0, 2.0, 40, dtype=torch.float64)[None]
    block = StorageSpill(np.array([0.2, 0.7]), np.array([0.5, 1.0]))
    np.testing.assert_array_equal(block(v).detach().numpy(), v.numpy())
    clip = StorageSpill(np.array([1.0 - 1e-9]), np.array([1.0]))
    with torch.no_grad():
        clip.weights.fill_(1.0)
    np.testing.assert_allclose(clip(v).detach().numpy(), np.minimum(v.numpy(), 1.0), atol=1e-6)


def test_the_effect_reads_the_spill_of_slow_storages_of_the_input():
    """A constant input at its amplitude fills every storage past its rim: each then loses
    the input's excess over the rim; an input under the lowest rim loses nothing."""
    ctx = FeatureContext(fs=1.0, u_amplitude=np.array([2.0]), duration_s=800.0)
    effect = StorageOverflow()
    features = effect.features(np.full((400, 1), 2.0), ctx)
    rates, rims = effect.storages(ctx, 0)
    assert features.shape == (400, len(rates)) == (400, 9)
    np.testing.assert_allclose(features[-1], 2.0 - rims, rtol=1e-6)
    assert np.all(features[:2, -1] < features[-1, -1])  # the slowest fills over time
    assert np.max(np.abs(effect.features(np.full((400, 1), 0.7), ctx))) == 0.0


def _splits(shared: bool) -> DatasetSplits:
    splits = narx_data(n=300)
    return DatasetSplits("d", splits.train, splits.test, shared_initial_state=shared)


def test_a_shared_initial_state_is_learned_only_where_the_data_say_so():
    """The data set's declaration reaches the model (and nothing else changes without it);
    the model then starts every recording from the learned state, which moves with
    ``start_input``, and trains it."""
    assert "shared_initial_state" not in _trained_on(_splits(False))
    trained_on = _trained_on(_splits(True))
    assert trained_on["shared_initial_state"] is True
    splits = _splits(True)
    dm = datamodule_for("linear", splits)
    model = build_model({"name": "linear"}, dm, trained_on=trained_on)
    rest = build_model({"name": "linear"}, dm, trained_on={"fs": 100.0})
    assert rest.start_input is None and model.start_input is not None
    rec = splits.train[0]
    model.initialise_from_data(rec.u[:, 0], rec.y[:, 0], rec.fs)  # dynamics with memory
    rest.load_state_dict({k: v for k, v in model.state_dict().items()
                          if k not in ("start_input", "burn_in")})
    with torch.no_grad():
        model.start_input.fill_(1.0)
    u = torch.zeros(1, 50, 1, dtype=torch.float64)
    started, from_rest = model.simulate_full(u), rest.simulate_full(u)
    assert float((started - from_rest).detach().abs().max()) > 1e-3
    started.sum().backward()
    assert float(model.start_input.grad.abs().max()) > 0.0
    assert float(model.initial_state().abs().max()) > 1e-3
    assert float(rest.initial_state().abs().max()) == 0.0


def test_the_cascaded_tanks_declare_a_shared_initial_state(tmp_path):
    """The tanks' protocol: estimation and test start from the same unknown state."""
    from hysteresis_lab.data.benchmarks import cascaded_tanks

    rows = ["uEst,uVal,yEst,yVal,Ts"] + [f"1,1,2,2,{4 if i == 0 else ''}" for i in range(20)]
    (tmp_path / "dataBenchmark.csv").write_text("\n".join(rows) + "\n")
    splits = cascaded_tanks(root=tmp_path)
    assert splits.shared_initial_state
    assert isinstance(splits.train[0], Recording)
