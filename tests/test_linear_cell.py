"""``model=linear``'s input hysteresis cell (``model.hysteresis``): Bouc–Wen or
Prandtl–Ishlinskii, read off the data by the grey-box's test (``auto``).

The play cell starts as the identity and grows a loop as its weights leave zero, stepping as
it runs on a whole recording; ``auto`` with ``hysteresis`` declared chooses play operators on
a Prandtl–Ishlinskii zoo plant and Bouc–Wen on a Bouc–Wen one; a run through ``data=csv``
trains the chosen cell and names it in ``metrics.json``; the loop tries both cells when it
adds hysteresis and keeps the fitted one afterwards; a rate-dependent cell stays Bouc–Wen; a
value that is no cell is refused with the choices."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from hysteresis_lab.api import compose, train
from hysteresis_lab.blocks.step import StepState
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.effects.hysteresis import HysteresisCell, PlayCell, input_cell_kind
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.fitting import build_model
from hysteresis_lab.models.augment import augment_splits, context_to_dict
from hysteresis_lab.models.io import load_model
from hysteresis_lab.models.linear import LinearModel
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.sim.zoo import draw_effects, export_zoo_plant

#: zoo plants whose cell the data test tells apart by a wide margin (as in
#: test_greybox_auto_cell.py)
PRANDTL_ISHLINSKII_PLANT = 5
BOUC_WEN_PLANT = 6
QUICK = ("trainer.max_epochs=1", "model.recording_repeats=1", "logger=none", "plots=false",
         "trainer.enable_progress_bar=false")


def triangle(periods: int = 3, samples: int = 400, amplitude: float = 2.0) -> torch.Tensor:
    """A triangle wave (1, T) in double precision."""
    phase = np.linspace(0.0, periods, periods * samples, endpoint=False) % 1.0
    wave = amplitude * (4.0 * np.abs(phase - 0.5) - 1.0)
    return torch.tensor(wave[None], dtype=torch.float64)


def test_the_play_cell_starts_as_the_identity_and_grows_a_loop():
    v = triangle()
    cell = PlayCell(amplitude=2.0)
    assert torch.equal(cell(v), v)
    with torch.no_grad():
        cell.weights.fill_(0.1)
    out = cell(v)[0].detach().numpy()
    x = v[0].numpy()
    rising = np.r_[False, np.diff(x) > 0]
    # the same input level gives a different output going up than coming down: a loop
    level = np.abs(x) < 0.05
    assert np.ptp(out[level & rising]) < np.ptp(out[level])
    gap = np.mean(out[level & ~rising]) - np.mean(out[level & rising])
    assert gap > 0.1


def test_the_play_cell_learns_a_prandtl_ishlinskii_loop_from_zero():
    """Its weights, from zero, fit a loop of play operators at other thresholds."""
    v = triangle(periods=4, samples=200) * torch.linspace(0.3, 1.0, 800, dtype=torch.float64)
    target_cell = PlayCell(amplitude=1.7, n_operators=5)
    with torch.no_grad():
        target_cell.weights.copy_(torch.tensor([0.05, 0.1, 0.0, 0.15, 0.05]))
        target = target_cell(v)
    cell = PlayCell(amplitude=2.0)
    optimizer = torch.optim.LBFGS(cell.parameters(), max_iter=50, line_search_fn="strong_wolfe")

    def loss() -> torch.Tensor:
        optimizer.zero_grad()
        value = torch.mean((cell(v) - target) ** 2)
        value.backward()
        return value

    start = float(loss())
    optimizer.step(loss)
    assert float(loss()) < 1e-3 * start


def test_the_play_cell_steps_as_it_runs_on_a_recording():
    v = triangle(periods=2, samples=60)
    cell = PlayCell(amplitude=2.0, square_amplitude=2.0)
    with torch.no_grad():
        cell.weights.copy_(torch.linspace(-0.05, 0.2, cell.weights.numel()))
        cell.square_weight.fill_(0.3)
    whole = cell(v)[0]
    state = torch.zeros(1, len(cell.state_names()), dtype=torch.float64)
    stepped = []
    for k in range(v.shape[1]):
        reader = StepState(state)
        stepped.append(cell.step(v[:, k], reader)[0])
        state = reader.next_state()
    stepped = torch.stack(stepped)
    torch.testing.assert_close(stepped, whole, rtol=0, atol=1e-12)


def zoo_splits(seed: int):
    return make_default_dataset(draw_effects(seed), seed=0, val_samples=20_000,
                                max_test_samples=1000)


@pytest.mark.parametrize(("seed", "cell"), [(PRANDTL_ISHLINSKII_PLANT, "prandtl_ishlinskii"),
                                            (BOUC_WEN_PLANT, "bouc_wen")])
def test_auto_reads_the_input_cell_off_the_data(seed, cell):
    assert draw_effects(seed)["hysteresis"]["cell"] == cell
    settings = {"hysteresis": "auto", "effects": ["hysteresis"]}
    candidates, found = LinearModel.settings_from_data(settings, zoo_splits(seed))
    assert [c["hysteresis"] for c in candidates] == [cell], found
    assert found["hysteresis"]["by"] == "data test"


@pytest.mark.parametrize("settings", [{"hysteresis": "auto", "effects": []},
                                      {"hysteresis": "auto", "effects": ["hysteresis", "rate"]},
                                      {"hysteresis": "bouc_wen", "effects": ["hysteresis"]}])
def test_without_a_cell_to_choose_the_settings_pass_as_they_are(settings):
    """No hysteresis declared, a rate-dependent cell (Bouc–Wen only) or a cell set."""
    splits = zoo_splits(PRANDTL_ISHLINSKII_PLANT)
    assert LinearModel.settings_from_data(settings, splits) == ([settings], {})


def test_a_csv_run_trains_the_chosen_cell_and_names_it(tmp_path):
    files = export_zoo_plant(PRANDTL_ISHLINSKII_PLANT, tmp_path / "data", max_test_samples=1000)
    cfg = compose("model=linear", "model.effects=[hysteresis,asymmetry]", "model.grow=false",
                  "data=csv",
                  f"data.train={files['train']}", f"data.val={files['val']}",
                  f"data.test=[{files['test'][0]}]", *QUICK)
    train(cfg, tmp_path / "run")
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["chosen_from_data"]["hysteresis"]["chosen"] == "prandtl_ishlinskii"
    model = load_model(tmp_path / "run" / "model.ckpt")
    assert model.hparams["hysteresis"] == "prandtl_ishlinskii"
    cell = model.input_blocks[0]["hysteresis"]
    assert isinstance(cell, PlayCell)
    assert cell.square_weight is not None  # asymmetry shares the cell


def linear_model(effects: list[str], cell: str) -> LinearModel:
    """``model=linear`` with ``effects`` and ``model.hysteresis=cell``, built on a zoo plant's
    recordings (augmented as a run augments them)."""
    splits = zoo_splits(PRANDTL_ISHLINSKII_PLANT)
    augmented, context = augment_splits(splits, effects)
    return build_model({"name": "linear", "effects": effects, "hysteresis": cell},
                       WindowDataModule(augmented, scaling="standard"),
                       trained_on={"fs": splits.train[0].fs},
                       feature_context=context_to_dict(context), n_base_inputs=1)


def test_the_loop_tries_both_cells_when_it_adds_hysteresis_and_keeps_the_fitted_one():
    auto = {"hysteresis": "auto", "effects": ["hysteresis"]}
    cells = {v["hysteresis"] for v in LinearModel.refit_variants(auto, None, "hysteresis")}
    assert cells == {"bouc_wen", "prandtl_ishlinskii"}
    rate = {**auto, "effects": ["hysteresis", "rate"]}
    (variant,) = LinearModel.refit_variants(rate, None, "hysteresis")
    declared = [get_effect(e) for e in rate["effects"]]
    assert input_cell_kind(variant, declared) == "bouc_wen"
    fitted = linear_model(["hysteresis"], "prandtl_ishlinskii")
    after = LinearModel.refit_variants({**auto, "effects": ["hysteresis", "creep"]}, fitted,
                                       "creep")
    assert [v["hysteresis"] for v in after] == ["prandtl_ishlinskii"]
    assert isinstance(fitted.input_blocks[0]["hysteresis"], PlayCell)
    rate_model = linear_model(["rate"], "prandtl_ishlinskii")
    assert isinstance(rate_model.input_blocks[0]["hysteresis"], HysteresisCell)
    # a cell that asymmetry brought is fitted: hysteresis added to it keeps the cell's kind
    # (the other kind would start from a cell at zero, not from the fitted model)
    asymmetric = linear_model(["asymmetry"], "prandtl_ishlinskii")
    assert isinstance(asymmetric.input_blocks[0]["hysteresis"], PlayCell)
    grown = LinearModel.refit_variants({**auto, "effects": ["asymmetry", "hysteresis"]},
                                       asymmetric, "hysteresis")
    assert [v["hysteresis"] for v in grown] == ["prandtl_ishlinskii"]


def test_a_value_that_is_no_cell_is_refused_with_the_choices():
    with pytest.raises(ConfigError, match="model.hysteresis='foo'") as error:
        linear_model(["hysteresis"], "foo")
    for choice in ("bouc_wen", "prandtl_ishlinskii", "auto"):
        assert f"'{choice}'" in str(error.value)
