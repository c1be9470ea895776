"""``data.plant``: the declared kind of plant breaks a tie between effects the evidence does
not tell apart; undeclared, the scores alone decide."""

from __future__ import annotations

import numpy as np
import pytest
from hydra import compose, initialize_config_module

from hysteresis_lab.data.spec import PLANT_KINDS, DataSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.loop.diagnosis.ranking import EffectScore
from hysteresis_lab.loop.driver import LoopSettings, named_group
from hysteresis_lab.loop.plant import PLANT_EFFECTS

SCORES = [EffectScore("overflow", 0.95, 1e-6, True, ""),
          EffectScore("hysteresis", 0.90, 1e-6, True, ""),
          EffectScore("friction", 0.40, 1e-6, True, "")]


def test_a_declared_plant_names_the_effect_that_fits_it_when_the_evidence_ties():
    """Overflow scores highest, hysteresis within the margin: a positioner names hysteresis,
    a tank keeps overflow, undeclared keeps the scores' order; friction, far below, is no
    tie, so a motion plant does not name it."""
    top = SCORES[0]
    assert named_group(SCORES, top, set(), 0.2, 3, None) == ["overflow", "hysteresis"]
    assert named_group(SCORES, top, set(), 0.2, 3, "positioner") == ["hysteresis", "overflow"]
    assert named_group(SCORES, top, set(), 0.2, 3, "tank") == ["overflow", "hysteresis"]
    assert named_group(SCORES, top, set(), 0.2, 3, "motion") == ["overflow", "hysteresis"]


def test_data_plant_is_checked_and_every_bundled_data_set_declares_one():
    assert set(PLANT_EFFECTS) == set(PLANT_KINDS)
    assert DataSpec.from_config({"name": "x", "plant": "tank"}).plant == "tank"
    assert DataSpec.from_config({"name": "x"}).plant is None
    with pytest.raises(ConfigError, match="data.plant=one of"):
        DataSpec.from_config({"name": "x", "plant": "piezo"})
    declared = {}
    with initialize_config_module("hysteresis_lab.conf", version_base=None):
        for name in ("default", "emps", "cascaded_tanks", "bouc_wen", "fsm", "p885", "csv"):
            cfg = compose("loop", overrides=[f"data={name}"])
            declared[name] = cfg.data.plant
    assert declared == {"default": "positioner", "emps": "motion", "cascaded_tanks": "tank",
                        "bouc_wen": "oscillator", "fsm": "positioner", "p885": "positioner",
                        "csv": None}


def test_an_effect_the_tests_drive_beyond_the_identification_data_is_held_back():
    """Tests whose input is three times the identification data's drive the hysteresis
    operators beyond what the data taught: held back, with a reading; at the same amplitude,
    or for an effect without input operators (overflow), nothing is held back."""
    from hysteresis_lab.data.recording import Recording
    from hysteresis_lab.loop.driver import beyond_identification
    from hysteresis_lab.models.augment import feature_context
    from hysteresis_lab.signals import multisine

    u = multisine(2000, fs=100.0, n_components=10, f_max=2.0, seed=1)
    ident = [Recording(u=u, y=u, fs=100.0, name="ident")]
    context = feature_context(ident)
    louder = [Recording(u=3.0 * u, y=u, fs=100.0, name="test")]
    held = beyond_identification("hysteresis", ident, louder, context)
    assert held is not None and held["worst_ratio"] > 2.0 and "less (RMS)" in held["reading"]
    assert beyond_identification("hysteresis", ident, ident, context) is None
    assert beyond_identification("overflow", ident, louder, context) is None


def test_only_an_effect_foreign_to_the_declared_plant_is_held_back_for_excitation(tmp_path):
    """A loop on data whose tests drive the operators three times as hard: declared a tank,
    the significant input effects (foreign to it) are held back and named in the report;
    undeclared, the top one is added as before."""
    from scipy import signal

    from hysteresis_lab.data.recording import Recording
    from hysteresis_lab.data.splits import DatasetSplits
    from hysteresis_lab.lightning_trainer import TrainerSettings
    from hysteresis_lab.loop.driver import LoopSettings, run_loop
    from hysteresis_lab.signals import multisine

    def rec(seed: int, gain: float, name: str) -> Recording:
        u = gain * multisine(1500, fs=100.0, n_components=20, f_max=2.0, seed=seed)
        b, a = signal.butter(2, 1.0, fs=100.0)
        x = signal.lfilter(b, a, np.clip(u, -0.5, 0.5))  # a clipped drive: saturation
        return Recording(u=u, y=x + 0.005 * np.random.default_rng(seed).standard_normal(1500),
                         fs=100.0, name=name)

    splits = DatasetSplits("clip", train=[rec(1, 1.0, "train")], test=[rec(3, 3.0, "test")])
    trainer = TrainerSettings(max_epochs=3, accelerator="cpu", devices=1,
                              enable_progress_bar=False, enable_model_summary=False)
    model = {"name": "linear", "order": 2, "effects": [], "lr": 0.01}
    settings = LoopSettings(max_rounds=0, refit_lr_factors=(1.0,))
    tank = run_loop(model, DataSpec.from_config({"name": "clip", "plant": "tank",
                                                 "scaling": {"mode": "standard"}}),
                    trainer, splits, tmp_path / "tank", settings, use_tensorboard=False,
                    plots=False)
    held = tank["rounds"][0].get("not_added_under_excited", [])
    assert held and all(h["plant"] == "tank" and h["worst_ratio"] > 2.0 for h in held)
    assert "foreign to data.plant=tank" in (tmp_path / "tank" / "loop_report.md").read_text()
    free = run_loop(model, DataSpec.from_config({"name": "clip", "scaling": {"mode": "standard"}}),
                    trainer, splits, tmp_path / "free", settings, use_tensorboard=False,
                    plots=False)
    assert "not_added_under_excited" not in free["rounds"][0]


def test_the_plant_prior_makes_only_the_plants_own_effects_significant_at_its_level():
    """At loop.plant_alpha=0.05 a tank's outflow law at p 0.015 is significant and named
    first; hysteresis at the same p (foreign to a tank) is not; undeclared, nothing
    changes."""
    from hysteresis_lab.loop.plant import with_plant_prior

    scores = [EffectScore("hysteresis", 0.62, 1e-5, True, ""),
              EffectScore("saturation", 0.29, 0.02, False, ""),
              EffectScore("nonlinear_feedback", 0.31, 0.015, False, ""),
              EffectScore("backlash", 0.30, 0.015, False, ""),
              EffectScore("overflow", 0.03, 0.001, False, "")]  # below loop.min_score
    marked = {d.effect: d.significant for d in with_plant_prior(scores, "tank", 0.05, 0.05)}
    assert marked == {"hysteresis": True, "saturation": True, "nonlinear_feedback": True,
                      "backlash": False, "overflow": False}
    assert with_plant_prior(scores, None, 0.05, 0.05) == scores


def test_at_plant_alpha_1_the_plants_own_effects_need_only_reach_min_score():
    """The default loop.plant_alpha=1: a tank's rim that explains 7 % of the residual at
    p 0.29 (too few blocks to be significant) goes to the folds; a foreign effect at the
    same evidence, or the rim below loop.min_score, does not."""
    from hysteresis_lab.loop.plant import with_plant_prior

    scores = [EffectScore("overflow", 0.069, 0.29, False, ""),
              EffectScore("backlash", 0.069, 0.29, False, ""),
              EffectScore("nonlinear_feedback", 0.04, 0.29, False, "")]
    marked = with_plant_prior(scores, "tank", 1.0, 0.05)
    assert {d.effect: d.significant for d in marked} == {
        "overflow": True, "backlash": False, "nonlinear_feedback": False}
    assert "the folds judge it" in marked[0].evidence
    assert LoopSettings(plant_alpha=1.0).plant_alpha == 1.0
    with pytest.raises(ConfigError, match="plant_alpha"):
        LoopSettings(plant_alpha=1.5)
