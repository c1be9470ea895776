"""The loop forces on the output stage's own level (``model.feedback_on=output_stage``): the
rim storage's kernel, the factored start, and the placement that two cascaded tanks need."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import signal

from hysteresis_lab.blocks.sections import held_poles
from hysteresis_lab.blocks.storage import StorageCascade, rim_step, rim_storage
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.nonlinear_feedback import StaticFeedback
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.fitting import build_model
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.models.linear import LinearModel
from narx import datamodule_for, narx_data


def test_the_rim_storage_has_exact_gradients_and_holds_its_level():
    """Exact gradients w.r.t. the input, rate, rim and spill weight; without a spill it is
    the unit-gain first-order storage; with a full spill the level never passes the rim."""
    gen = torch.Generator().manual_seed(0)
    v = (1.5 * torch.rand(2, 30, dtype=torch.float64, generator=gen)).requires_grad_()
    alpha, rim, weight = (torch.tensor(x, dtype=torch.float64, requires_grad=True)
                          for x in (0.4, 0.6, 0.7))
    assert torch.autograd.gradcheck(lambda *a: torch.cat(rim_storage(*a), dim=1),
                                    (v, alpha, rim, weight))
    zero = torch.zeros((), dtype=torch.float64)
    level, spill = rim_storage(v, alpha, rim, zero)
    expected = signal.lfilter([0.4], [1.0, -0.6], v.detach().numpy(), axis=1)
    np.testing.assert_allclose(level.detach().numpy(), expected, atol=1e-12)
    assert float(spill.detach().abs().max()) == 0.0
    full, spilled = rim_storage(v, alpha, rim, torch.ones((), dtype=torch.float64))
    assert float(full.detach().max()) <= 0.6 + 1e-12 and float(spilled.detach().max()) > 0.0
    stepped, state = [], torch.zeros(2, dtype=torch.float64)  # the step: the same recursion
    for t in range(v.shape[1]):
        state, _ = rim_step(v[:, t], state, alpha, rim, weight)
        stepped.append(state)
    np.testing.assert_allclose(torch.stack(stepped, 1).detach().numpy(),
                               rim_storage(v, alpha, rim, weight)[0].detach().numpy(),
                               atol=1e-12)


def test_the_cascade_starts_with_the_start_poles_and_static_gain():
    """Factored from a start with real poles, the cascade keeps every pole and the static
    gain; the two slowest poles are the storages (the slowest upstream)."""
    poles = [0.97, 0.9, 0.5, 0.3 + 0.2j, 0.3 - 0.2j]
    a = np.real(np.poly(poles))
    b = np.array([0.0, 0.02, -0.01, 0.004])
    cascade = StorageCascade(5)
    cascade.set_transfer_function(b, a)
    with torch.no_grad():
        bc, ac = (x.numpy() for x in cascade.polynomials())
    np.testing.assert_allclose(np.sort_complex(np.roots(ac)[np.abs(np.roots(ac)) > 1e-9]),
                               np.sort_complex(held_poles(a)), atol=1e-9)
    np.testing.assert_allclose(bc.sum() / ac.sum(), b.sum() / a.sum(), rtol=1e-9)
    assert float(cascade.storage.pole.detach()) == pytest.approx(0.97)
    assert float(cascade.stage.pole.detach()) == pytest.approx(0.9)


def _model(config: dict, splits: DatasetSplits) -> LinearModel:
    augmented, context = augment_splits(splits, config.get("effects", []))
    model = build_model(config, datamodule_for("linear", augmented), trained_on={"fs": 1.0},
                        feature_context=context_to_dict(context), n_base_inputs=1)
    rec = splits.train[0]
    model.initialise_from_data(rec.u[:, 0], rec.y[:, 0], rec.fs)
    return model


def test_an_order_below_two_is_refused():
    with pytest.raises(ConfigError, match="feedback_on=output_stage"):
        _model({"name": "linear", "order": 1, "feedback_on": "output_stage"}, narx_data(n=300))
    with pytest.raises(ConfigError, match="model.feedback_on"):
        _model({"name": "linear", "feedback_on": "input"}, narx_data(n=300))


def _two_tanks(u: np.ndarray) -> np.ndarray:
    """An upper tank that overflows at its rim, feeding a lower tank that drains through an
    orifice (outflow ~ sqrt of its own level)."""
    y, x1, x2 = np.zeros(len(u)), 0.0, 0.0
    for t, inflow in enumerate(u):
        y[t] = x2
        x1 = min(x1 + 0.1 * (inflow - x1), 1.0)
        x2 = max(x2 + 0.1 * (x1 - 1.2 * np.sqrt(max(x2, 0.0))), 0.0)
    return y


def _tank_splits() -> DatasetSplits:
    rng = np.random.default_rng(3)
    recs = []
    for name in ("train", "test"):
        steps = np.repeat(rng.uniform(0.1, 1.8, 12), 50)
        y = _two_tanks(steps)
        recs.append(Recording(u=steps[:, None], y=y[:, None], fs=1.0, name=name))
    return DatasetSplits(name="two_tanks", train=[recs[0]], val=[recs[0]], test=[recs[1]])


def _fitted_error(place: str, splits: DatasetSplits, steps: int = 150) -> float:
    """Train RMSE (scaled) after ``steps`` Adam steps on the free-run error."""
    torch.manual_seed(0)
    model = _model({"name": "linear", "order": 2, "feedback_on": place,
                    "effects": ["nonlinear_feedback", "overflow"]}, splits)
    rec = splits.train[0]
    u = torch.as_tensor(((rec.u - model.u_offset.numpy()) / model.u_scale.numpy())[None])
    y = torch.as_tensor(((rec.y - model.y_offset.numpy()) / model.y_scale.numpy())[None])
    optimiser = torch.optim.Adam(model.parameters(), lr=0.02)
    for _ in range(steps):
        optimiser.zero_grad()
        loss = torch.mean((model.simulate_full(u) - y) ** 2)
        loss.backward()
        optimiser.step()
    return float(loss.detach().sqrt())


def test_two_tanks_fit_better_with_the_law_on_the_output_stage():
    """On two cascaded tanks (an overflowing upper tank, an orifice below) the same blocks fit
    clearly better with the law on the output stage's own level and the rim on the upper
    tank than with the law around the whole dynamics and the clip on the output."""
    splits = _tank_splits()
    around = _fitted_error("dynamics", splits)
    on_stage = _fitted_error("output_stage", splits)
    assert on_stage < 0.7 * around, (on_stage, around)



class _OutputStagePath(torch.nn.Module):
    """The cascade's path with the law on its output stage, as `LinearModel` runs it."""

    def __init__(self, cascade: StorageCascade, law: StaticFeedback) -> None:
        super().__init__()
        self.cascade, self.law = cascade, law

    def forward(self, x: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
        inflow = self.cascade.storage_output(x, offset)
        return self.law(self.cascade.stage, inflow, offset)


def test_the_output_stage_law_has_exact_gradients():
    """The whole output-stage path (upstream part, storage with a rim and its spill share,
    the output stage in a closed loop with the law of its own level): exact gradients
    w.r.t. the input and every parameter."""
    cascade = StorageCascade(2, rim_level=0.6)
    cascade.set_transfer_function(np.array([0.0, 0.3]), np.real(np.poly([0.8, 0.6])))
    law = StaticFeedback(0.0, 1.5, n_knots=3)
    with torch.no_grad():
        law.weights.copy_(torch.tensor([0.4, -0.2, 0.3], dtype=torch.float64))
        cascade.rim_weight.fill_(0.8)
        cascade.spill_share.fill_(0.5)
    path = _OutputStagePath(cascade, law)
    names = [name for name, _ in path.named_parameters()]
    offset = torch.tensor(0.1, dtype=torch.float64)

    def run(x: torch.Tensor, *values: torch.Tensor) -> torch.Tensor:
        return torch.func.functional_call(path, dict(zip(names, values, strict=True)),
                                          (x, offset))

    gen = torch.Generator().manual_seed(1)
    x = (3.0 * torch.rand(1, 25, dtype=torch.float64, generator=gen)).requires_grad_()
    values = tuple(v.detach().clone().requires_grad_() for v in path.parameters())
    with torch.no_grad():
        level, spill = rim_storage(cascade.upstream(x), 1.0 - cascade.storage.pole,
                                   cascade.rim_level - offset, cascade.rim_weight)
    assert float(spill.max()) > 0.0  # the rim is reached: its gradients are checked too
    assert torch.autograd.gradcheck(run, (x, *values))


def test_the_loop_tries_both_places_once():
    """A refit that adds a storage's law or its overflow to a model whose forces act on the
    whole dynamics is fitted both ways; once the output stage stands it stays; other effects
    (hysteresis too) and the first round keep the place."""
    splits = narx_data(n=300)
    around = _model({"name": "linear", "order": 2}, splits)
    on_stage = _model({"name": "linear", "order": 2, "feedback_on": "output_stage"}, splits)
    cfg = {"order": 2, "feedback_on": "dynamics"}
    both = [{"feedback_on": "dynamics"}, {"feedback_on": "output_stage"}]
    assert LinearModel.refit_variants(cfg, around, "nonlinear_feedback") == both
    assert LinearModel.refit_variants(cfg, around, "overflow") == both
    assert LinearModel.refit_variants(cfg, around, "creep") == [{"feedback_on": "dynamics"}]
    # a restoring force acts on the whole oscillator (hysteresis: with each input cell)
    assert {v["feedback_on"] for v in LinearModel.refit_variants(cfg, around, "hysteresis")} \
        == {"dynamics"}
    assert LinearModel.refit_variants(cfg, None, None) == [{"feedback_on": "dynamics"}]
    assert {v["feedback_on"] for v in LinearModel.refit_variants(cfg, on_stage, "hysteresis")} \
        == {"output_stage"}
    assert LinearModel.refit_variants({**cfg, "order": 1}, around, "overflow") == [
        {"feedback_on": "dynamics"}]


def test_a_warm_start_factors_the_fitted_dynamics_into_the_cascade():
    """From a model around the whole dynamics into one with the output stage: the static
    gain carries over, the factored parts are not new blocks (no raised rate), the rim is."""
    splits = narx_data(n=300)
    fitted = _model({"name": "linear", "order": 2}, splits)
    grown = _model({"name": "linear", "order": 2, "feedback_on": "output_stage",
                    "effects": ["overflow"]}, splits)
    grown.warm_start_from(fitted)
    with torch.no_grad():
        b, a = fitted.dynamics[0][0].polynomials()
        bc, ac = grown.dynamics[0][0].polynomials()
    assert float(bc.sum() / ac.sum()) == pytest.approx(float(b.sum() / a.sum()), rel=1e-9)
    assert set(grown._new_entries) == {"dynamics.0.0.rim_weight", "dynamics.0.0.rim_level",
                                       "dynamics.0.0.spill_share", "overflow.0.weights",
                                       "overflow.0.levels"}
