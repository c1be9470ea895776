"""experiments/undeclared_zoo.py: zoo plants that keep their hysteresis, one undeclared effect
added per cell, judged by the rule of experiments/undeclared_effects.py."""

from __future__ import annotations

import copy
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from hysteresis_lab.api import compose
from hysteresis_lab.effects.registry import available_effects
from hysteresis_lab.sim.default_dataset import make_default_dataset
from hysteresis_lab.sim.zoo import draw_effects

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"
#: a Bouc–Wen plant and a Prandtl–Ishlinskii one of the zoo
BOUC_WEN, PRANDTL = 0, 2
#: the tiny case: a short multisine, a short validation multisine, two short test sines
SMALL = {"n_train": 4000, "test_frequencies": [10, 100], "max_test_samples": 2000,
         "val_samples": 2000}
TINY = ("+data.splits.n_train=4000", "+data.splits.test_frequencies=[10,100]",
        "+data.splits.max_test_samples=2000", "data.splits.val_samples=2000",
        "trainer.max_epochs=2", "training.simulation_epochs=1", "training.refit_lr=0.002",
        # one fit per stage: the cell's bookkeeping is checked here, not the fit's path
        "model.hysteresis=bouc_wen", "model.grow=false", "model.polish=false")


@pytest.fixture(scope="module")
def zoo():
    """The experiment script (it imports undeclared_effects.py beside it by name)."""
    sys.path.insert(0, str(EXPERIMENTS))
    try:
        spec = importlib.util.spec_from_file_location("undeclared_zoo",
                                                      EXPERIMENTS / "undeclared_zoo.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(EXPERIMENTS))


def _data_effects(overrides: list[str]) -> dict:
    cfg = compose(*overrides[1:], config="loop")
    return OmegaConf.to_container(cfg.data.effects, resolve=True)


def test_a_cell_keeps_the_plant_and_its_hysteresis_and_adds_one_effect(zoo):
    """The cell's loop runs on the drawn plant: its hysteresis cell as drawn (declared by the
    start), the effects added in turn off but the cell's own, which is on."""
    drawn = draw_effects(PRANDTL)
    cell = _data_effects(zoo.command(PRANDTL, "creep"))
    assert cell["hysteresis"] == {**cell["hysteresis"], **drawn["hysteresis"]}
    assert cell["creep"]["enabled"]
    assert cell["creep"]["weight_per_decade"] == drawn["creep"]["weight_per_decade"]
    assert not any(cell[b]["enabled"] for b in zoo.EFFECTS if b != "creep")
    base = _data_effects(zoo.command(PRANDTL, None))
    assert not any(base[b]["enabled"] for b in zoo.EFFECTS)
    assert "model.effects=[hysteresis]" in zoo.command(PRANDTL, None)
    assert "loop.max_rounds=0" in zoo.command(PRANDTL, None)


def test_rate_dependence_is_added_to_bouc_wen_plants_only(zoo):
    """The simulator's rate dependence scales the Bouc–Wen alpha: a Prandtl–Ishlinskii plant
    has none, is skipped (and said so), and the next Bouc–Wen seed is taken."""
    assert zoo.added_block(PRANDTL, "rate_dependence") is None
    assert "prandtl_ishlinskii" in zoo.why_skipped(PRANDTL, "rate_dependence")
    seeds = zoo.plants_for("rate_dependence", 3, BOUC_WEN)
    assert all(draw_effects(s)["hysteresis"]["cell"] == "bouc_wen" for s in seeds)
    assert len(set(seeds)) == 3
    assert zoo.plants_for("creep", 3, BOUC_WEN) == [0, 1, 2]


def test_the_asymmetry_is_named_by_catalogue_effects(zoo):
    names = zoo.effect_names("asymmetry")
    assert set(names) <= set(available_effects())
    assert (names == ("asymmetry",)) == ("asymmetry" in available_effects())


@pytest.mark.slow
def test_a_tiny_cell_is_judged_by_the_rule_on_the_effect_s_own_output(zoo, tmp_path):
    """A dead zone added to a small Bouc–Wen zoo plant: the row's effect sizes are the dead
    zone's own output on the tests (rebuilt here from the drawn plant), its masking the base
    start's error over them, its verdict the bundled rule's, which turns to FAIL when the
    refit takes nothing off; the page shows the cell and the pass share."""
    row = zoo.run_cell(BOUC_WEN, "dead_zone", tmp_path, extra=TINY)
    assert "failed" not in row, row.get("failed")
    quiet = {"noise": {"enabled": False}, "quantisation": {"enabled": False}}
    effects = {**zoo.base_effects(BOUC_WEN), **quiet}
    on = make_default_dataset({**effects, "dead_zone": {"enabled": True, "width_v": 10.0}},
                              **SMALL)
    off = make_default_dataset(effects, **SMALL)
    own = {a.name: float(np.sqrt(np.mean((a.y - b.y) ** 2)))
           for a, b in zip(on.test, off.test, strict=True)}
    assert row["effect_size_um"], "a 10 V dead zone on ±100 V sines acts on every test"
    for test, size in row["effect_size_um"].items():
        assert size == pytest.approx(own[test], rel=1e-6)
    base = json.loads((tmp_path / str(BOUC_WEN) / "base" / "row.json").read_text())
    for test, ratio in row["masking"].items():
        assert ratio == pytest.approx(base["tests"][test] / own[test])
    assert base["mean_over_sigma"] == pytest.approx(
        np.mean(list(base["tests"].values())) / draw_effects(BOUC_WEN)["noise"]["rms_um"])

    verdict = sys.modules["undeclared_effects"].verdict
    assert row["verdict"] == verdict(row)
    named = {**copy.deepcopy(row), "top": "dead_zone", "significant": True,
             "predictable": True, "change_pct": dict.fromkeys(row["before"], 0.0)}
    if max(row["ceiling_pct"].values()) > 0:
        assert verdict(named).startswith("FAIL: less than half the ceiling off")
    unnamed = {**named, "top": "creep", "effect_share_max": 0.5}
    assert verdict(unnamed) == "FAIL: not named as the top significant effect"

    page = zoo.render(zoo.kept_rows(tmp_path, tmp_path / "none.json"), [])
    good = int(row["verdict"].startswith("PASS"))
    assert f"**Pass share: {good} of 1 cells" in page
    assert f"| dead_zone | {BOUC_WEN} |" in page
    if not good:
        assert "| FAIL" in page or "| n/a" in page or "| named" in page


def test_a_kept_cell_is_reused_only_with_the_same_settings(zoo, tmp_path):
    """Resuming: a row kept from a run with other added overrides (``--quick`` or not) is
    run again, not mixed into the table."""
    path = tmp_path / "row.json"
    path.write_text(json.dumps({"extra": []}))
    assert zoo._kept(path, ()) and not zoo._kept(path, zoo.QUICK)
    assert not zoo._kept(tmp_path / "missing.json", ())


def test_a_cell_whose_loop_diagnosed_nothing_is_no_pass(zoo):
    """The start diverged on a fold: the loop diagnosed nothing, and the bundled rule, which
    reads an unnamed effect below min_score as held by the start, must not count it."""
    note = "the start model's free run diverges on ['fold 1']"
    row = {"top": None, "top_score": None, "significant": False, "expected": ["creep"],
           "effect_share_max": 0.01, "ceiling_pct": {"sine_0.1Hz": 8.0},
           "effect_size_um": {"sine_0.1Hz": 1.0}, "predictable": True,
           "before": {"sine_0.1Hz": 10.0}, "why_not_refitted": note}
    row["verdict"] = sys.modules["undeclared_effects"].verdict(row)
    assert row["verdict"].startswith("PASS")  # what the rule alone says
    cell = zoo.judged(row, {"tests": {"sine_0.1Hz": 5.0}})
    assert cell["verdict"] == f"no diagnosis: {note}" and not zoo.passed(cell)
    assert cell["masking"] == {"sine_0.1Hz": 5.0}
    assert zoo.statistics([cell, {**cell, "verdict": "PASS"}]) == (1, 2)


def test_a_cell_another_process_runs_is_left_to_it(zoo, tmp_path):
    """Two invocations over the same cells: the second must not empty the first's folder."""
    lock = tmp_path / "creep.running"
    assert zoo._claim(lock)  # this process holds it now
    assert not zoo._claim(lock)  # a live holder
    lock.write_text("999999999")  # a stopped run's lock
    assert zoo._claim(lock)
