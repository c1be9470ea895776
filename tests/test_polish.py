"""``model.polish``: a physical model's fit ends with an L-BFGS refinement of the kept model.

On a Bouc–Wen zoo plant of exponent above 1 (through ``data=csv``) the polished grey-box has a
lower validation loss than the same run without the polish, its cell learns its exponent
(``model.learn_exponent=polish`` frees it there only) and the polish is in the run's stage
folders; the linear model polishes too; the networks have no such setting; a value that is
no switch is refused with the fix. A warm-started refit (the loop's) is polished too, and a
polished refit must beat its start as any refit must."""

from __future__ import annotations

import json

import pytest

from hysteresis_lab.api import compose, load_data, train
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.fitting import TrainResult
from hysteresis_lab.loop.driver import fit_model
from hysteresis_lab.models.greybox import GreyBox
from hysteresis_lab.models.io import load_model
from hysteresis_lab.run_config import RunConfig
from hysteresis_lab.sim.zoo import draw_effects, export_zoo_plant
from hysteresis_lab.workflows.grow import kept_after_polish, polishes

#: a Bouc–Wen zoo plant whose exponent is well above 1
BOUC_WEN_PLANT = 0
#: a Prandtl–Ishlinskii zoo plant (7 plays, a large loop)
PRANDTL_ISHLINSKII_PLANT = 11
SHORT = ("trainer.max_epochs=15", "model.recording_repeats=4", "logger=none", "plots=false",
         "trainer.enable_progress_bar=false")


def csv_config(tmp_path, model: str, *overrides: str, plant: int = BOUC_WEN_PLANT):
    """A short ``data=csv`` run of ``model`` on a zoo plant's exported recordings."""
    files = export_zoo_plant(plant, tmp_path / "data", max_test_samples=1000)
    return compose(f"model={model}", "data=csv", f"data.train={files['train']}",
                   f"data.val={files['val']}", f"data.test=[{files['test'][0]}]", *SHORT,
                   *overrides)


def csv_run(tmp_path, model: str, *overrides: str,
            plant: int = BOUC_WEN_PLANT) -> tuple[dict, object]:
    cfg = csv_config(tmp_path, model, *overrides, plant=plant)
    train(cfg, tmp_path / "run")
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    return metrics, load_model(tmp_path / "run" / "model.ckpt")


def test_the_polished_greybox_fits_better_with_its_exponent_learned(tmp_path):
    assert draw_effects(BOUC_WEN_PLANT)["hysteresis"]["exponent"] > 1.3
    # the delay fixed: a learned one takes up part of the misfit the exponent is checked on
    cell = ("model.hysteresis=bouc_wen", "model.grow=false", "model.delay_span=0")
    plain, plain_model = csv_run(tmp_path / "plain", "greybox", *cell, "model.polish=false")
    polished, model = csv_run(tmp_path / "polished", "greybox", *cell)
    assert not (tmp_path / "plain" / "run" / "grow" / "polish").exists()
    assert (tmp_path / "polished" / "run" / "grow" / "polish").is_dir()
    assert float(plain_model.hysteresis.exponent) == 1.0
    assert polished["val_mse_scaled"] < 0.9 * plain["val_mse_scaled"]
    assert model.hparams["learn_exponent"] is True  # the polish's cell learns its exponent
    assert model.hysteresis.raw_exponent is not None

    # a warm-started refit (the loop's) is polished too: from the unpolished fit, its
    # exponent leaves 1
    cfg = csv_config(tmp_path / "refit", "greybox", *cell)
    config = RunConfig.from_config(cfg, tmp_path / "refit" / "run")
    refit = fit_model(config, load_data(cfg), config.model, config.training, config.output_dir,
                      warm_start=plain_model, refit="full")
    assert (config.output_dir / "grow" / "polish").is_dir()
    assert refit.improved and refit.model.hparams["learn_exponent"] is True
    assert float(refit.model.hysteresis.exponent) != 1.0


def test_the_linear_model_polishes_too(tmp_path):
    cell = ("model.effects=[hysteresis]", "model.hysteresis=prandtl_ishlinskii",
            "model.grow=false")
    plain, _ = csv_run(tmp_path / "plain", "linear", *cell, "model.polish=false",
                       plant=PRANDTL_ISHLINSKII_PLANT)
    polished, _ = csv_run(tmp_path / "polished", "linear", *cell,
                          plant=PRANDTL_ISHLINSKII_PLANT)
    assert (tmp_path / "polished" / "run" / "grow" / "polish").is_dir()
    assert polished["val_mse_scaled"] < 0.9 * plain["val_mse_scaled"]


def test_only_physical_models_trained_with_adam_polish(tmp_path):
    def config(*overrides: str) -> RunConfig:
        return RunConfig.from_config(compose(*overrides, "data=default"), tmp_path)

    assert polishes(config("model=greybox"))
    assert polishes(config("model=linear"))
    assert not polishes(config("model=greybox", "model.polish=false"))
    assert not polishes(config("model=greybox", "training.optimizer=lbfgs"))
    assert not polishes(config("model=ffnn"))


@pytest.mark.parametrize(("setting", "value"), [("learn_exponent", "polish"),
                                                ("learn_exponent", True),
                                                ("learn_exponent", False)])
def test_the_polish_frees_the_exponent_only_where_it_is_left_to_it(setting, value):
    settings = {"hysteresis": "bouc_wen", setting: value}
    expected = True if value == "polish" else value
    assert GreyBox.polish_settings(settings)[setting] is expected


@pytest.mark.parametrize("override", ["model.polish=maybe", "model.learn_exponent=maybe"])
def test_a_value_that_is_no_switch_is_refused_with_the_fix(tmp_path, override):
    with pytest.raises(ConfigError, match=override.split("=")[0]):
        csv_run(tmp_path, "greybox", override)


def fit_result(loss: float, start: float | None = None, improved: bool = True,
               epochs: int = 7) -> TrainResult:
    """A fit whose kept validation loss is ``loss``; a refit (``start``: its start's loss)
    that kept its start where not ``improved``."""
    refit = None if start is None else {"start": start, "refit": loss if improved else 2 * start}
    return TrainResult(model=object(), val_mse=loss, train_seconds=3.0, improved=improved,
                       refit_validation=refit, epochs={"simulation": epochs})


def test_a_polish_that_lowers_the_loss_is_kept_with_the_adam_fits_epochs():
    fitted = fit_result(1.0)
    polished = fit_result(0.5, start=1.0, epochs=2)
    kept = kept_after_polish(fitted, polished, min_gain=0.0)
    assert kept.model is polished.model
    assert kept.epochs == {"simulation": 7}  # a loop's final refit trains the Adam fit's length
    assert kept.train_seconds == 6.0
    assert kept.refit_validation is None  # fitted from the data: no start to report
    assert kept_after_polish(fitted, fit_result(1.5, start=1.0, improved=False, epochs=2),
                             min_gain=0.0) is fitted


def test_a_polished_refit_must_beat_the_refits_start_by_the_loops_margin():
    """A loop refit that kept its start (loss 1.0) takes a polish only where the polished
    model beats that start by ``min_gain``; it then reports its loss against that start."""
    kept_start = fit_result(1.0, start=1.0, improved=False)
    slightly = fit_result(0.99, start=1.0, epochs=2)
    assert kept_after_polish(kept_start, slightly, min_gain=0.02) is kept_start
    better = fit_result(0.9, start=1.0, epochs=2)
    kept = kept_after_polish(kept_start, better, min_gain=0.02)
    assert kept.model is better.model and kept.improved
    assert kept.refit_validation == {"start": 1.0, "refit": 0.9}
    assert kept.rejected_state is None
