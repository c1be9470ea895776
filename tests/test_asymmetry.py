"""The asymmetry effect: a square law of the drive on ``model=linear``'s hysteresis cell,
from zero; it fits a known square-law plant that the cell without it cannot."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch

from hysteresis_lab.blocks.step import StepState
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.effects.hysteresis import HysteresisCell
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.sim.default_dataset import make_default_dataset

TRAINER = TrainerSettings(max_epochs=20, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)


def _sine(n: int = 600) -> torch.Tensor:
    t = np.linspace(0.0, 1.0, n)
    return torch.tensor((1.5 * np.sin(2 * np.pi * 3 * t) * (0.3 + 0.7 * t))[None])


def test_the_square_law_starts_at_zero_and_its_step_matches() -> None:
    plain, asymmetric = HysteresisCell(), HysteresisCell(square_amplitude=1.5)
    asymmetric.load_state_dict(plain.state_dict(), strict=False)  # the loop's warm start
    v = _sine()
    with torch.no_grad():
        for cell in (plain, asymmetric):
            cell.weight.fill_(0.6)
        np.testing.assert_array_equal(asymmetric(v).numpy(), plain(v).numpy())
        asymmetric.square_weight.fill_(0.1)
        difference = (asymmetric(v) - plain(v)).numpy()
        np.testing.assert_allclose(difference, 0.1 * v.numpy() ** 2 / 1.5, rtol=0, atol=1e-14)
        state = torch.zeros(1, len(asymmetric.state_names()), dtype=torch.float64)
        steps = []
        for k in range(v.shape[1]):
            stepper = StepState(state)
            steps.append(asymmetric.step(v[:, k], stepper))
            state = stepper.next_state()
        np.testing.assert_allclose(torch.stack(steps, 1).numpy(), asymmetric(v).numpy(),
                                   rtol=0, atol=1e-12)


def test_the_cell_fits_an_asymmetric_loop_the_plain_cell_cannot() -> None:
    """Data of a cell with a square law (rise 5 % of the input's amplitude at full drive):
    fitted from zero, the square law comes back; the cell without it stays 100 x worse."""
    v = _sine(800)
    source = HysteresisCell(square_amplitude=1.5)
    with torch.no_grad():
        source.weight.fill_(0.5)
        source.square_weight.fill_(0.05)
        target = source(v)

    def fitted(cell: HysteresisCell) -> float:
        with torch.no_grad():
            cell.weight.fill_(0.4)
        optimiser = torch.optim.LBFGS(cell.parameters(), lr=0.5, max_iter=200,
                                      line_search_fn="strong_wolfe")

        def closure() -> torch.Tensor:
            optimiser.zero_grad()
            loss = torch.mean((cell(v) - target) ** 2)
            loss.backward()
            return loss

        optimiser.step(closure)
        with torch.no_grad():
            return float(torch.mean((cell(v) - target) ** 2))

    asymmetric = HysteresisCell(square_amplitude=1.5)
    loss = fitted(asymmetric)
    assert float(asymmetric.square_weight.detach()) == pytest.approx(0.05, rel=0.02)
    assert fitted(HysteresisCell()) > 100 * loss


def test_model_linear_learns_a_plants_square_law(tmp_path) -> None:
    """``model=linear model.effects=[asymmetry]`` on a linear plant with the simulator's
    square law (0.8 µm at ±100 V over a 23 µm drive: 3.5 %): the cell's square law comes
    back as that share."""
    data = make_default_dataset(
        effects={"hysteresis": {"enabled": False}, "creep": {"enabled": False},
                 "asymmetry": {"enabled": True, "coefficient": 0.02}},
        n_train=8000, test_frequencies=(10.0,), max_test_samples=1000, val_samples=4000)
    augmented, context = augment_splits(data, ["asymmetry"])
    dm = WindowDataModule(augmented, scaling="paper")
    L.seed_everything(0)
    model = build_model({"name": "linear", "effects": ["asymmetry"]}, dm,
                        TrainingSettings(lr=0.01, objective="simulation"),
                        trained_on={"fs": data.fs}, feature_context=context_to_dict(context),
                        n_base_inputs=1)
    fitted = fit(model, dm, TRAINER, tmp_path).model
    share = 0.02 * 40.0 / (0.23 * 100.0)
    q = float(fitted.input_blocks[0]["hysteresis"].square_weight.detach())
    assert q == pytest.approx(share, rel=0.15)


def test_the_effect_is_in_the_catalogue_and_refits_whole() -> None:
    effect = get_effect("asymmetry")
    assert effect.linear_carried and effect.linear_whole_refit
    assert effect.greybox_part().cell_term is not None  # the grey-box's cell takes it too
    u = np.linspace(-2.0, 2.0, 5)[:, None]
    from hysteresis_lab.effects.base import FeatureContext

    features = effect.features(u, FeatureContext(fs=1.0, u_amplitude=np.array([2.0]),
                                                 duration_s=5.0))
    np.testing.assert_allclose(features[:, 0], (u[:, 0] / 2.0) ** 2)
    with pytest.raises(ValueError):
        HysteresisCell(square_amplitude=0.0)
