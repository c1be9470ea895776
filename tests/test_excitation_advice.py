"""The loop's advice where an effect cannot be judged for lack of excitation: the simulator's
clipping amplifier, which the validation multisine barely reaches and every test sine does."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import hysteresis_lab as hl
from hysteresis_lab.data.factory import build_splits
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.loop.advice import excitation_advice
from hysteresis_lab.loop.data import loop_data
from hysteresis_lab.loop.diagnosis.excitation import (
    UNDER_EXCITED_RATIO,
    between_frequencies,
    dominant_frequency,
    recommend_recordings,
)
from hysteresis_lab.loop.diagnosis.ranking import EffectScore
from hysteresis_lab.loop.driver import LoopSettings, run_loop
from hysteresis_lab.loop.report import loop_markdown
from hysteresis_lab.models.augment import feature_context
from hysteresis_lab.run_folder import LoopFolder
from hysteresis_lab.signals import multisine, sine
from hysteresis_lab.sim.default_dataset import make_default_dataset
from loop_notebook import check_loop_notebook

#: the simulator with the amplifier's clipping the one effect beyond linear dynamics
CLIPPING = ("data.effects.hysteresis.enabled=false", "data.effects.creep.enabled=false",
            "data.effects.saturation.enabled=true")
#: the undeclared-effects study's measurement: a score above loop.min_score, not significant
UNJUDGED = EffectScore("saturation", 0.138, 0.9996, False, "saturation")


def advice_for(*overrides: str, score: EffectScore = UNJUDGED) -> tuple[list[dict], DataSpec]:
    """The loop's advice on the simulator's data composed with ``overrides``."""
    spec = DataSpec.from_config(hl.compose("data=default", *CLIPPING, *overrides).data)
    splits = build_splits(spec)
    data = loop_data(splits, spec, 3)
    context = feature_context(data.fit.train)
    return excitation_advice([score], data, spec, context, 0.05, 1.0), spec


@pytest.fixture(scope="module")
def clipping_advice() -> tuple[list[dict], DataSpec]:
    return advice_for()


def test_an_unjudged_effect_the_tests_drive_harder_gets_recordings_to_add(clipping_advice):
    (advice,), _ = clipping_advice
    assert advice["effect"] == "saturation"
    assert advice["identification"] > UNDER_EXCITED_RATIO < advice["diagnosis"]
    assert advice["amplitude"] == [pytest.approx(100.0)]
    tests = {0.1, 1, 10, 50, 100, 150, 200, 250, 300, 400, 450, 500}
    added = set(advice["train_hz"]) | set(advice["val_hz"])
    assert added and not added & tests and not set(advice["train_hz"]) & set(advice["val_hz"])
    assert min(added) < 1 and max(added) > 400  # the tests' whole band, 0.1-500 Hz
    assert advice["identification_after"] <= UNDER_EXCITED_RATIO
    assert advice["diagnosis_after"] <= UNDER_EXCITED_RATIO
    # the simulator's validation multisine is identification data too: the folds hold out
    # blocks of every recording, so the added sines go to training
    assert advice["override"][0].startswith("data.splits.train_sines=[")
    assert "not judged for lack of excitation" in advice["advice"]
    assert " ".join(advice["override"]) in advice["advice"]


def test_the_recommended_override_is_accepted_and_ends_the_advice(clipping_advice):
    (advice,), _ = clipping_advice
    again, spec = advice_for(*advice["override"])
    assert again == []  # the data now drive the clipping as the tests do
    splits = build_splits(spec)
    assert [r.name for r in splits.train][1:] == [f"train_sine_{f:g}Hz"
                                                 for f in advice["train_hz"]]
    assert [r.name for r in splits.val] == ["multisine_validation", *(
        f"val_sine_{f:g}Hz" for f in advice["val_hz"])]
    assert max(np.max(np.abs(r.u)) for r in splits.val) == pytest.approx(100.0)


def test_a_significant_or_small_score_gets_no_advice():
    for score in (EffectScore("saturation", 0.138, 1e-6, True, "named"),
                  EffectScore("saturation", 0.01, 0.9, False, "below loop.min_score")):
        assert advice_for(score=score)[0] == []


def test_a_diagnosis_named_in_data_diagnose_gets_the_validation_sines_too():
    # (a validation recording is identification data, which the folds diagnose: only test
    # recordings or files are named in data.diagnose)
    # a diagnosis on a test that clips as the others do needs training sines only
    (advice,), _ = advice_for("data.diagnose=[sine_500Hz]")
    assert advice["val_hz"] == [] and advice["diagnosis"] <= UNDER_EXCITED_RATIO
    assert [o.split("=")[0] for o in advice["override"]] == ["data.splits.train_sines"]


def _recorded(u: np.ndarray, name: str, fs: float = 2000.0) -> Recording:
    return Recording(u=u, y=np.clip(u, -0.9, 0.9), fs=fs, name=name)


def test_recorded_data_get_a_sentence_on_what_to_record():
    """A CSV user's data: a multisine that rarely clips to train on (the loop holds out its
    end), sines that clip to test on."""
    train = _recorded(multisine(8000, fs=2000.0, amplitude=1.0, seed=1), "run")
    tests = [_recorded(sine(f, fs=2000.0, amplitude=1.0, n_periods=2), f"sine{f:g}")
             for f in (1.0, 10.0)]
    splits = DatasetSplits(name="csv", train=[train], val=[], test=tests)
    spec = DataSpec.from_config(hl.compose("data=csv", "data.train=run.csv").data)
    data = loop_data(splits, spec, 3)
    context = feature_context(data.fit.train)
    (advice,) = excitation_advice([UNJUDGED], data, spec, context, 0.05, 1.0)
    assert advice["override"] is None and list(advice["band_hz"]) == [1.0, 10.0]
    assert advice["val_hz"] == [] and advice["train_hz"] == [0.71, 3.2, 14.0]
    # the held-out ends of the added recordings reach the clipping as the tests do
    assert advice["diagnosis_after"] <= UNDER_EXCITED_RATIO
    assert "Record inputs of ±1 V peak in 1-10 Hz" in advice["advice"]
    assert "as extra data.train files (the loop's folds hold out a block of each)" in (
        advice["advice"])
    # where data.diagnose names a recording that barely clips, some of them go there
    quiet = _recorded(sine(3.0, fs=2000.0, amplitude=0.5, n_periods=2), "quiet")
    spec = DataSpec.from_config(hl.compose("data=csv", "data.train=run.csv",
                                           "data.diagnose=[quiet]").data)
    named = loop_data(dataclasses.replace(splits, test=[*tests, quiet]), spec, 3)
    (advice,) = excitation_advice([UNJUDGED], named, spec, feature_context(named.fit.train),
                                  0.05, 1.0)
    assert advice["val_hz"] and f"those at {advice['val_hz'][0]:g}" in advice["advice"]
    assert "in data.diagnose (the recordings the diagnosis reads)" in advice["advice"]


def test_the_report_page_says_what_to_add(clipping_advice):
    (advice,), _ = clipping_advice
    rmse = {"rmse_free_run": 1.0, "rmse_one_step": 1.0, "r2_free_run": 0.9}
    report = {"units": {"y": "um"}, "data": "default", "model": "linear",
              "start": {"model": "linear", "effects": []}, "result": 0,
              "roles": {"train": ["t"], "validation": [], "diagnosis": [], "test": ["sine"]},
              "rounds": [{"effects": [], "tests": {"sine": rmse}, "mean_rmse_free_run": 1.0,
                          "mean_rmse_one_step": 1.0, "added": None,
                          "diagnosis": [UNJUDGED.to_dict()], "under_excited": [advice],
                          "held_out": {"loss": 0.5, "rmse": {}, "diverging": []},
                          "note": "no significant missing effect"}]}
    page = loop_markdown(report)
    assert "### Not judged: recordings to add" in page
    assert f"  - rerun with: `{' '.join(advice['override'])}`" in page


def test_frequencies_between_the_driving_tests_and_the_dominant_line():
    assert between_frequencies([0.1, 1, 10, 50], [1]) == [0.32, 3.2]
    assert between_frequencies([0, 10], [10]) == [7.1, 14.0]  # a held input has no line
    assert between_frequencies([1, 10, 100], [1, 10, 100]) == [3.2, 32.0]
    assert dominant_frequency(sine(5.0, fs=1000.0, n_periods=2), 1000.0) == pytest.approx(5.0)
    assert dominant_frequency(np.zeros(100), 1000.0) == 0.0


def test_added_sines_never_clash_with_tests_or_each_other():
    with pytest.raises(ConfigError, match="val_sines .* also test frequencies"):
        make_default_dataset(max_test_samples=400, val_sines=[10.0])
    with pytest.raises(ConfigError, match="both train_sines and val_sines"):
        make_default_dataset(max_test_samples=400, train_sines=[3.0], val_sines=[3.0])
    plain = make_default_dataset(max_test_samples=400, val_samples=400)
    more = make_default_dataset(max_test_samples=400, val_samples=400, val_sines=[3.0])
    assert [r.name for r in more.val] == ["multisine_validation", "val_sine_3Hz"]
    np.testing.assert_array_equal(more.val[0].y, plain.val[0].y)  # the others unchanged
    np.testing.assert_array_equal(more.test[0].y, plain.test[0].y)


def test_no_advice_where_the_identification_data_drive_the_operators_as_the_tests_do():
    rec = _recorded(sine(2.0, fs=2000.0, n_periods=2), "sine")
    context = feature_context([rec])
    assert recommend_recordings("saturation", [rec], [rec], [rec], context) is None


@pytest.mark.parametrize("plant_alpha", [None, 1.0])
def test_the_loop_reports_the_recordings_to_add(tmp_path, plant_alpha):
    """Round 0 of the loop on short simulator records with the amplifier clipping: the 1 s
    validation multisine passes 70 V a few times, the 10 and 100 Hz test sines every cycle.
    With the plain diagnosis (``loop.diagnosis_through_dynamics=false``: read through the
    model's dynamics, the clipping is named on these records) the clipping's score reaches
    loop.min_score without significance at loop.alpha, and the report (JSON, page, log) says
    which sines to add, nothing else changed. At the default ``loop.plant_alpha=1`` the
    positioner's prior makes it significant (the folds would judge it), and the advice
    still stands: the data alone did not decide it."""
    spec = DataSpec.from_config(hl.compose("data=default", *CLIPPING).data)
    effects = {"hysteresis": {"enabled": False}, "creep": {"enabled": False},
               "saturation": {"enabled": True}}
    data = make_default_dataset(effects=effects, n_train=8000, test_frequencies=(10.0, 100.0),
                                max_test_samples=3000, val_samples=20000)
    trainer = TrainerSettings(max_epochs=5, accelerator="cpu", devices=1,
                              enable_progress_bar=False, enable_model_summary=False)
    # the advice is checked, not the fit: no L-BFGS polish
    report = run_loop({"name": "linear", "effects": [], "lr": 0.02, "polish": False}, spec,
                      trainer, data, tmp_path,
                      LoopSettings(max_rounds=0, diagnosis_through_dynamics=False,
                                   plant_alpha=plant_alpha),
                      use_tensorboard=False, plots=False)
    first = report["rounds"][0]
    score = next(d for d in first["diagnosis"] if d["effect"] == "saturation")
    assert score["score"] >= 0.05 and score["p_value"] > 0.01
    assert score["significant"] == (plant_alpha is not None) == score.get("by_plant_prior", False)
    advice = {a["effect"]: a for a in first["under_excited"]}["saturation"]
    assert advice["identification"] > UNDER_EXCITED_RATIO
    assert advice["override"][0].startswith("data.splits.train_sines=")
    page = LoopFolder(tmp_path).report_md.read_text()
    assert f"rerun with: `{' '.join(advice['override'])}`" in page
    check_loop_notebook(tmp_path)
    unjudged = {d["effect"] for d in first["diagnosis"] if d["tested"] and d["predictable"]
                and (not d["significant"] or d.get("by_plant_prior")) and d["score"] >= 0.05}
    assert {a["effect"] for a in first["under_excited"]} <= unjudged
