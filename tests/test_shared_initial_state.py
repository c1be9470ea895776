"""The learned shared initial state of the physical chains (a data set whose recordings all
start from one unknown state: the cascaded tanks)."""

from __future__ import annotations

import torch

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.fitting import build_model
from hysteresis_lab.models.augment import trained_on as _trained_on
from narx import datamodule_for, narx_data


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
    assert trained_on["burn_in_samples"] == max(r.n_samples for r in _splits(True).train)
    splits = _splits(True)
    dm = datamodule_for("linear", splits)
    model = build_model({"name": "linear"}, dm, trained_on=trained_on)
    rest = build_model({"name": "linear"}, dm, trained_on={"fs": 100.0})
    assert rest.start_input is None and model.start_input is not None
    assert int(model.burn_in) == trained_on["burn_in_samples"]
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


def test_the_cascaded_tanks_declare_a_shared_initial_state():
    """The tanks' protocol (their SOURCE.md): estimation and test start from the same unknown
    state. Read from the bundled benchmark file."""
    from hysteresis_lab.data.benchmarks import cascaded_tanks

    splits = cascaded_tanks()
    assert splits.shared_initial_state
    assert isinstance(splits.train[0], Recording) and splits.train[0].n_samples == 1024
