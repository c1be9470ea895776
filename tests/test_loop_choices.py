"""What the loop tries next and at which refit rates: an effect the folds rejected is not
tried again; a model whose fits end with the L-BFGS polish refits at one rate, then at a
tenth of it only where that refit fails the folds."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from hysteresis_lab.loop.diagnosis.ranking import EffectScore
from hysteresis_lab.loop.driver import (
    LoopSettings,
    _choose_next_effect,
    _LoopState,
    _refit_rate_stages,
)
from hysteresis_lab.models.spec import ModelSpec


def _next_round(rejected: set[str]) -> dict:
    """The entry `_choose_next_effect` writes after a model=linear round whose diagnosis
    puts overflow far above a feedback law (both act on the output: no excitation to read),
    with ``rejected`` the effects the folds rejected in earlier rounds."""
    run = SimpleNamespace(
        model=ModelSpec.from_config({"name": "linear", "effects": ["backlash"]}),
        settings=LoopSettings(),
        data_spec=SimpleNamespace(plant=None),
        data=SimpleNamespace(fit=SimpleNamespace(output_integrates=False)),
    )
    diagnosis = [EffectScore("overflow", 0.5, 1e-6, True, "clipped peaks"),
                 EffectScore("nonlinear_feedback", 0.1, 1e-4, True, "a level law")]
    state = _LoopState(effects=["backlash"], diagnosis=diagnosis, rejected=rejected)
    state.kept = [None, None]  # the start and the round that kept backlash
    entry: dict = {}
    assert _choose_next_effect(run, state, entry)
    assert state.trying == [entry["added"]]
    return entry


def test_an_effect_the_folds_rejected_is_not_tried_again():
    assert _next_round(rejected=set())["added"] == "overflow"
    # rejected before backlash was kept, it still scores highest: the next one is tried
    assert _next_round(rejected={"overflow"})["added"] == "nonlinear_feedback"


@pytest.mark.parametrize(("model", "training", "factors", "stages"), [
    # polished (the packaged configs' model.polish): the first rate, a tenth where it fails
    ({"name": "linear", "polish": True}, {}, None, [[1e-3], [1e-4]]),
    ({"name": "greybox", "polish": True}, {}, None, [[1e-3], [1e-4]]),
    ({"name": "linear", "polish": True}, {"refit_lr": 5e-4}, None, [[5e-4]]),
    ({"name": "linear", "polish": False}, {}, None, [[1e-4, 1e-3]]),  # both at once
    ({"name": "ffnn"}, {}, None, [[1e-4, 1e-3]]),
    ({"name": "linear", "polish": True}, {}, (0.1, 1.0), [[1e-4, 1e-3]]),  # set: as set
])
def test_refit_rates_one_after_the_other_where_the_polish_ends_each_fit(
        model, training, factors, stages):
    spec = ModelSpec.from_config(model)
    settings = LoopSettings(refit_lr_factors=factors)
    found = _refit_rate_stages(spec, spec.training_settings({"lr": 1e-3, **training}), settings)
    assert [pytest.approx(stage) for stage in stages] == found
