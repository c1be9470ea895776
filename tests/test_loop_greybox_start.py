"""A grey-box start: the effects its structure always holds are held, never diagnosed or added."""

from __future__ import annotations

from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.loop.driver import LoopSettings, held_effects, run_loop
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.sim.default_dataset import make_default_dataset

TRAINER = TrainerSettings(max_epochs=2, accelerator="cpu", devices=1, enable_progress_bar=False,
                          enable_model_summary=False)


def test_a_greybox_holds_hysteresis_unless_it_has_no_cell():
    cell = ModelSpec.from_config({"name": "greybox", "hysteresis": "bouc_wen"})
    no_cell = ModelSpec.from_config({"name": "greybox", "hysteresis": "none"})
    linear = ModelSpec.from_config({"name": "linear"})
    assert held_effects(cell, ["creep"]) == ["creep", "hysteresis"]
    assert held_effects(cell, ["hysteresis"]) == ["hysteresis"]
    assert held_effects(no_cell, ["creep"]) == ["creep"]
    assert held_effects(linear, []) == []


def test_the_loop_from_a_greybox_does_not_diagnose_the_hysteresis_it_has(tmp_path):
    """The round-0 diagnosis of a grey-box start scores every catalogue effect but the
    hysteresis its cell holds (adding it would refit nothing new)."""
    splits = make_default_dataset(n_train=6000, test_frequencies=(10.0,),
                                  max_test_samples=2000, val_samples=3000)
    model = {"name": "greybox", "effects": [], "hysteresis": "bouc_wen", "recording_repeats": 1}
    report = run_loop(model, DataSpec.from_config({"name": "small"}), TRAINER, splits,
                      tmp_path, LoopSettings(max_rounds=0), use_tensorboard=False, plots=False)
    scored = {d["effect"] for d in report["rounds"][0]["diagnosis"]}
    assert "hysteresis" not in scored
    assert {"creep", "resonance"} <= scored
    assert report["rounds"][0].get("added") != "hysteresis"
