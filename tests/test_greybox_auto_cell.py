"""``model.hysteresis=auto``: the grey-box's hysteresis cell chosen from the training data.

On zoo plants (`hysteresis_lab.sim.zoo`) whose cells the data test tells apart clearly, it
chooses play operators for a Prandtl–Ishlinskii plant and Bouc–Wen for a Bouc–Wen plant; a
run through ``data=csv`` trains the chosen cell, names it and the test's numbers in
``metrics.json`` and exports to ONNX; where the test leaves the choice open, both cells are
fitted and the lower validation loss is kept; MIMO data keep the default cell; a value that
is no cell is refused with the choices."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import optional_dependency
from hysteresis_lab.api import compose, train
from hysteresis_lab.blocks import BoucWen, PlayOperators
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.fitting import build_model
from hysteresis_lab.models import greybox_cell
from hysteresis_lab.models.greybox import HYSTERESIS, GreyBox
from hysteresis_lab.models.io import load_model
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.sim.zoo import draw_effects, export_zoo_plant

#: zoo plants whose cell the data test tells apart by a wide margin (held-out misfit of
#: Bouc–Wen over play operators about 8 and 0.5)
PRANDTL_ISHLINSKII_PLANT = 5
BOUC_WEN_PLANT = 6
AUTO = {"hysteresis": "auto", "delay": "auto", "n_modes": "auto"}
#: a run as short as it can be: the choice is what is checked, not the fit
QUICK = ("trainer.max_epochs=1", "model.recording_repeats=1", "logger=none", "plots=false",
         "trainer.enable_progress_bar=false")


def zoo_splits(seed: int) -> DatasetSplits:
    """Plant ``seed``'s study recordings (training multisine, validation realisation, short
    test sines)."""
    return make_default_dataset(draw_effects(seed), seed=0, val_samples=20_000,
                                max_test_samples=1000)


def zoo_cell(seed: int) -> str:
    return draw_effects(seed)["hysteresis"]["cell"]


@pytest.mark.parametrize(("seed", "cell"), [(PRANDTL_ISHLINSKII_PLANT, "prandtl_ishlinskii"),
                                            (BOUC_WEN_PLANT, "bouc_wen")])
def test_auto_chooses_the_plants_cell_from_the_data(seed, cell):
    assert zoo_cell(seed) == cell
    candidates, found = GreyBox.settings_from_data(AUTO, zoo_splits(seed))
    assert [c["hysteresis"] for c in candidates] == [cell], found
    assert found["hysteresis"]["chosen"] == cell
    assert found["hysteresis"]["by"] == "data test"
    misfits = found["hysteresis"]["held_out_misfit"]
    other = "bouc_wen" if cell == "prandtl_ishlinskii" else "prandtl_ishlinskii"
    # the chosen cell explains the plant clearly better than the other and than no cell
    assert misfits[cell] < greybox_cell.CLEAR_RATIO * misfits[other], misfits
    assert misfits[cell] < greybox_cell.CLEAR_RATIO * misfits["none"], misfits


def test_other_settings_pass_as_they_are():
    splits = zoo_splits(BOUC_WEN_PLANT)
    settings = {**AUTO, "hysteresis": "prandtl_ishlinskii"}
    assert GreyBox.settings_from_data(settings, splits) == ([settings], {})


def csv_run(tmp_path, seed: int, *overrides: str, cell: str = "auto"):
    """``model=greybox model.hysteresis=<cell>`` on zoo plant ``seed`` through ``data=csv``."""
    files = export_zoo_plant(seed, tmp_path / "data", max_test_samples=1000)
    cfg = compose("model=greybox", f"model.hysteresis={cell}", "data=csv",
                  f"data.train={files['train']}", f"data.val={files['val']}",
                  f"data.test=[{','.join(files['test'][:2])}]", *QUICK, *overrides)
    train(cfg, tmp_path / "run")
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    return metrics, load_model(tmp_path / "run" / "model.ckpt")


def test_a_csv_run_trains_the_chosen_cell_names_it_and_exports_it(tmp_path):
    """Through the user-CSV path: play operators on the Prandtl–Ishlinskii plant, in the
    saved model, named with the test's numbers in metrics.json; the model steps in ONNX."""
    metrics, model = csv_run(tmp_path, PRANDTL_ISHLINSKII_PLANT)
    chosen = metrics["chosen_from_data"]["hysteresis"]
    assert chosen["chosen"] == "prandtl_ishlinskii", chosen
    assert chosen["by"] == "data test"
    assert set(chosen["held_out_misfit"]) == {"none", "bouc_wen", "prandtl_ishlinskii"}
    assert model.hparams["hysteresis"] == "prandtl_ishlinskii"
    assert isinstance(model.hysteresis, PlayOperators)
    ort = optional_dependency("onnxruntime")
    from hysteresis_lab.models.export import export_onnx

    session = ort.InferenceSession(str(export_onnx(model, tmp_path / "greybox.onnx")))
    state = np.zeros((1, len(model.state_names())), dtype=np.float64)
    output, state = session.run(None, {"state": state, "u": np.zeros((1, 1))})
    assert np.all(np.isfinite(output))


def test_where_the_test_leaves_it_open_both_cells_are_fitted_and_the_better_kept(
        tmp_path, monkeypatch):
    """With the test's margin out of reach it decides nothing: both cells are fitted in the
    run's candidates folder and the one with the lower validation loss is the run's model."""
    monkeypatch.setattr(greybox_cell, "CLEAR_RATIO", 1e-9)
    metrics, model = csv_run(tmp_path, BOUC_WEN_PLANT, "model.grow=false")
    chosen = metrics["chosen_from_data"]
    assert chosen["hysteresis"]["by"] == "validation free-run loss"
    losses = chosen["candidates_validation_loss"]
    assert set(losses) == {"hysteresis=bouc_wen", "hysteresis=prandtl_ishlinskii"}
    kept = min(losses, key=losses.get)
    assert chosen["kept"] == kept
    assert metrics["val_mse_scaled"] == pytest.approx(losses[kept])
    assert model.hparams["hysteresis"] == kept.removeprefix("hysteresis=")
    for label in losses:
        assert (tmp_path / "run" / "grow" / "candidates" / label / "checkpoints").is_dir()


def test_the_candidates_fit_the_chain_without_a_cell_once(tmp_path, monkeypatch):
    """Both cells grow from the chain without its cell: that stage is fitted once, in the
    first candidate's folder, and the second candidate grows from a copy of it to the same
    model as when that cell is fitted on its own."""
    monkeypatch.setattr(greybox_cell, "CLEAR_RATIO", 1e-9)
    grown = ("model.grow=true", "model.effects=[]")
    metrics, _ = csv_run(tmp_path / "auto", BOUC_WEN_PLANT, *grown)
    losses = metrics["chosen_from_data"]["candidates_validation_loss"]
    first, second = losses  # in the order they were fitted
    candidates = tmp_path / "auto" / "run" / "grow" / "candidates"
    assert (candidates / first / "grow" / "0_linear" / "checkpoints").is_dir()
    assert (candidates / second / "grow").is_dir()
    assert not (candidates / second / "grow" / "0_linear").exists()
    alone, _ = csv_run(tmp_path / "alone", BOUC_WEN_PLANT, *grown,
                       cell=second.removeprefix("hysteresis="))
    assert alone["val_mse_scaled"] == pytest.approx(losses[second], rel=1e-9)


def test_mimo_data_keep_the_default_cell():
    rng = np.random.default_rng(0)
    recordings = [Recording(u=rng.normal(size=(500, 2)), y=rng.normal(size=(500, 2)),
                            fs=1000.0, name=f"mimo{k}") for k in range(2)]
    splits = DatasetSplits("mimo", train=recordings[:1], test=recordings[1:])
    candidates, found = GreyBox.settings_from_data(AUTO, splits)
    assert [c["hysteresis"] for c in candidates] == ["bouc_wen"]
    assert found["hysteresis"]["chosen"] == "bouc_wen"
    model = build_model({"name": "greybox", "hysteresis": "auto"},
                        WindowDataModule(splits, scaling="standard"), trained_on={"fs": 1000.0})
    assert model.hparams["hysteresis"] == "bouc_wen"
    assert all(isinstance(cell, BoucWen) for cell in model.cells)


def test_a_model_built_directly_chooses_when_it_reads_the_data():
    """Built and initialised without a run (the Python API), ``auto`` takes the cell with the
    lower held-out misfit of the test on the training recording."""
    splits = zoo_splits(PRANDTL_ISHLINSKII_PLANT)
    model = build_model({"name": "greybox", "hysteresis": "auto"},
                        WindowDataModule(splits, scaling="standard"),
                        trained_on={"fs": splits.train[0].fs})
    model.initialise_from_recordings(splits.train)
    assert model.hparams["hysteresis"] == "prandtl_ishlinskii"
    assert isinstance(model.hysteresis, PlayOperators)


def test_a_value_that_is_no_cell_is_refused_with_the_choices_before_training(tmp_path):
    """Through a run it is refused before its first stage (the chain without a cell) trains;
    built directly, by the model."""
    with pytest.raises(ConfigError, match="model.hysteresis='foo'") as error:
        csv_run(tmp_path, BOUC_WEN_PLANT, "model.hysteresis=foo")
    for choice in HYSTERESIS:
        assert f"'{choice}'" in str(error.value)
    assert "auto" in HYSTERESIS
    assert not (tmp_path / "run" / "grow").exists()
    splits = zoo_splits(BOUC_WEN_PLANT)
    with pytest.raises(ConfigError, match="model.hysteresis='foo'"):
        build_model({"name": "greybox", "hysteresis": "foo"},
                    WindowDataModule(splits, scaling="standard"), trained_on={"fs": 20_000.0})
