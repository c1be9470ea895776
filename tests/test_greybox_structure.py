"""The grey-box's input delay and number of modes chosen from the data (``model.delay=auto``,
``model.n_modes=auto``, the defaults): the chain's response fitted to the training data's best
linear approximation (`select_chain_structure`), explicit settings kept as given."""

from __future__ import annotations

import numpy as np
import pytest

from hysteresis_lab.blocks.estimate import select_chain_structure
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model
from hysteresis_lab.models.io import load_model, save_model
from hysteresis_lab.physics.filters import first_order_lowpass, mode_filter
from hysteresis_lab.signals import multisine
from hysteresis_lab.sim.default_dataset import make_default_dataset

FS = 20_000.0


def linear_chain(delay: int, modes: list[tuple[float, float, float]],
                 amplifier_hz: float = 8000.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A multisine (0-1 kHz, 2 s) through an amplifier lag, ``delay`` samples and modes
    ``(frequency, damping, share of the static gain)``, with a little sensor noise."""
    u = multisine(40_000, FS, n_components=1000, f_max=1000.0, seed=seed)
    x = first_order_lowpass(u, FS, 1.0 / (2.0 * np.pi * amplifier_hz))
    x = np.r_[np.zeros(delay), x[: len(x) - delay]]
    y = 0.2 * sum(w * mode_filter(x, FS, f, z) for f, z, w in modes)
    return u, y + 0.01 * np.random.default_rng(seed).standard_normal(len(y))


@pytest.mark.parametrize("delay", [0, 3, 5])
def test_auto_delay_recovers_the_plants_delay(delay):
    """The amplifier lag makes up for a shorter delay but not a longer one: the delay is the
    last before the misfit jumps, whatever the lag."""
    u, y = linear_chain(delay, [(600.0, 0.03, 1.0)], amplifier_hz=3000.0 + 1000.0 * delay)
    structure = select_chain_structure(u, y, FS)
    assert structure.delay == delay, structure.misfits
    assert structure.frequencies_hz[0] == pytest.approx(600.0, rel=0.02)


def test_auto_mode_count_finds_two_modes_on_a_two_mode_plant():
    u, y = linear_chain(2, [(400.0, 0.02, 0.6), (750.0, 0.03, 0.4)])
    structure = select_chain_structure(u, y, FS)
    assert structure.n_modes == 2, structure.misfits
    np.testing.assert_allclose(structure.frequencies_hz, [400.0, 750.0], rtol=0.02)
    np.testing.assert_allclose(structure.weights, [0.6, 0.4], atol=0.05)
    assert structure.delay == 2


def test_auto_mode_count_keeps_one_mode_on_a_one_mode_plant():
    u, y = linear_chain(2, [(400.0, 0.02, 1.0)])
    structure = select_chain_structure(u, y, FS)
    assert structure.n_modes == 1, structure.misfits
    assert structure.delay == 2


def positioner(delay: int):
    """The bundled positioner (hysteresis and all) with ``delay`` samples of input delay,
    creep off; 0.4 s of multisine to train on."""
    effects = {"creep": {"enabled": False}, "input_delay": {"samples": delay}}
    return make_default_dataset(effects=effects, n_train=8000, test_frequencies=(10.0, 100.0),
                                max_test_samples=2000, val_samples=4000)


def test_the_greybox_takes_the_delay_from_the_data_and_saves_it(tmp_path):
    """With the defaults (auto) the started model holds the plant's delay, records it in its
    settings, and a saved model is rebuilt with it."""
    data = positioner(delay=3)
    dm = WindowDataModule(data, scaling="paper")
    model = build_model({"name": "greybox"}, dm, trained_on={"fs": data.fs})
    model.initialise_from_recordings(dm.splits.train)
    assert model.delay.samples == 3
    assert model.hparams["delay"] == 3
    assert isinstance(model.hparams["n_modes"], int) and model.mode.n_modes == \
        model.hparams["n_modes"]
    loaded = load_model(save_model(model, tmp_path / "model"))
    assert loaded.delay.samples == 3 and loaded.mode.n_modes == model.mode.n_modes
    for a, b in zip(free_run(model, dm.splits.test, dm.window),
                    free_run(loaded, dm.splits.test, dm.window), strict=True):
        np.testing.assert_array_equal(a, b)


def test_explicit_delay_and_modes_are_kept():
    data = positioner(delay=3)
    dm = WindowDataModule(data, scaling="paper")
    model = build_model({"name": "greybox", "delay": 1, "n_modes": 2}, dm,
                        trained_on={"fs": data.fs})
    model.initialise_from_recordings(dm.splits.train)
    assert model.delay.samples == 1 and model.mode.n_modes == 2
    assert model.hparams["delay"] == 1 and model.hparams["n_modes"] == 2


def test_a_grown_stage_takes_the_structure_of_the_model_it_grows_from():
    """A warm start (a growth stage, a loop round) with ``auto`` settings takes the fitted
    model's delay and modes instead of choosing again."""
    data = positioner(delay=3)
    dm = WindowDataModule(data, scaling="paper")
    fitted = build_model({"name": "greybox", "hysteresis": "none"}, dm,
                         trained_on={"fs": data.fs})
    fitted.initialise_from_recordings(dm.splits.train)
    grown = build_model({"name": "greybox"}, dm, trained_on={"fs": data.fs})
    grown.warm_start_from(fitted)
    assert grown.delay.samples == fitted.delay.samples == 3
    assert grown.mode.n_modes == fitted.mode.n_modes
    assert grown.hparams["delay"] == 3


def test_data_that_do_not_show_a_delay_keep_the_former_default():
    """Where the misfit jumps at no delay tried (an output unrelated to the input), nothing
    says the delay: one sample, as before ``auto``, not the longest tried."""
    rng = np.random.default_rng(0)
    u, y = rng.standard_normal(20_000), rng.standard_normal(20_000)
    assert select_chain_structure(u, y, FS).delay == 1


@pytest.mark.parametrize(("seed", "first_mode_hz"), [(2, 3462.0), (9, 673.0)])
def test_a_mode_above_the_band_is_read_off_its_peak_not_the_bands_edge(seed, first_mode_hz):
    """Above the excited band the output's power is largest at the band's edge, where a
    hysteresis loop's distortion spreads; a mode shows as a peak standing out there: the
    first such peak is the mode (zoo plant 2: one mode at 3.46 kHz; plant 9: modes at 673
    and 1252 Hz, the multisine ending at 500 Hz)."""
    from hysteresis_lab.blocks.estimate import estimate_mode
    from hysteresis_lab.sim.zoo import draw_effects

    effects = draw_effects(seed)
    modes = sorted(effects[f"mode{k}"]["frequency_hz"] for k in (1, 2, 3)
                   if effects[f"mode{k}"].get("enabled"))
    assert modes[0] == pytest.approx(first_mode_hz, rel=1e-3) and modes[0] > 600.0
    train = make_default_dataset(effects, seed=0, max_test_samples=10).train[0]
    frequency, _ = estimate_mode(train.u[:, 0], train.y[:, 0], train.fs)
    assert frequency == pytest.approx(first_mode_hz, rel=0.03)
