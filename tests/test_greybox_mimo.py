"""The grey-box on MIMO data: per input an amplifier, delay and hysteresis cell, then shared
modes with a residue per output and input. It trains on a small 2x2 system, saves, loads and
exports like the one-axis model, grows a mode in the loop without changing what it simulates,
and one input and output stay exactly the model they were."""

from __future__ import annotations

import lightning as L
import numpy as np
import pytest
import torch
from scipy import signal

from conftest import optional_dependency
from hysteresis_lab.blocks.estimate import estimate_modes
from hysteresis_lab.blocks.linear import mode_coefficients
from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.io import load_model, save_model

TRAINER = TrainerSettings(max_epochs=4, accelerator="cpu", enable_progress_bar=False,
                          enable_model_summary=False)
FS = 1000.0
MODES_HZ = (60.0, 190.0)  # the structure's two modes, shared by every pair
RESIDUES = np.array([[[1.0, 0.3], [0.4, -0.2]],   # (output, input, mode)
                     [[-0.5, 0.2], [1.2, 0.4]]])
OFFSETS = np.array([0.5, -1.0])


def hysteretic_stroke(u: np.ndarray, width: float = 0.4) -> np.ndarray:
    """``0.7 u + 0.3 play(u)`` per column, a play operator of half-width ``width``, delayed
    by one sample (the amplifier's)."""
    play = np.zeros_like(u)
    last = np.zeros(u.shape[1])
    for k, v in enumerate(u):
        last = np.clip(last, v - width, v + width)
        play[k] = last
    x = 0.7 * u + 0.3 * play
    return np.vstack([np.zeros((1, u.shape[1])), x[:-1]])


def two_by_two(n_rec: int, n: int, seed: int) -> list[Recording]:
    """A 2-input, 2-output positioner by hand: per input a hysteretic stroke, then two
    lightly damped modes with a residue per output and input, an offset per output and a
    little noise; band-limited random inputs from rest."""
    rng = np.random.default_rng(seed)
    shaping = signal.butter(2, 300.0, fs=FS)
    modes = [[c.numpy() for c in mode_coefficients(torch.tensor(f), torch.tensor(0.05), FS)]
             for f in MODES_HZ]
    out = []
    for r in range(n_rec):
        u = signal.lfilter(*shaping, rng.normal(size=(n, 2)), axis=0)
        u /= u.std(axis=0)
        x = hysteretic_stroke(u)
        responses = np.stack([signal.lfilter(b, a, x, axis=0) for b, a in modes], axis=-1)
        y = np.einsum("tjm,ojm->to", responses, RESIDUES) + OFFSETS
        y += 0.005 * rng.normal(size=y.shape)
        out.append(Recording(u=u, y=y, fs=FS, name=f"mimo{seed}_{r}"))
    return out


@pytest.fixture(scope="module")
def mimo_data():
    splits = DatasetSplits("mimo", train=two_by_two(3, 1500, 0), test=two_by_two(1, 1500, 1))
    return splits, WindowDataModule(splits, scaling="standard")


@pytest.fixture(scope="module")
def fitted(mimo_data, tmp_path_factory):
    splits, dm = mimo_data
    L.seed_everything(0)
    model = build_model({"name": "greybox", "n_modes": 2}, dm, trained_on={"fs": FS})
    return fit(model, dm, TRAINER, tmp_path_factory.mktemp("greybox_mimo")).model


def rmse_per_output(predicted: np.ndarray, rec: Recording, start: int) -> np.ndarray:
    return np.sqrt(np.mean((predicted[start:] - rec.y[start:]) ** 2, axis=0))


def test_the_mimo_modes_are_read_off_the_frequency_response(mimo_data):
    splits, _ = mimo_data
    freqs, damps = estimate_modes([r.u for r in splits.train], [r.y for r in splits.train],
                                  FS, n_modes=2, fmin=10.0)
    np.testing.assert_allclose(freqs, MODES_HZ, rtol=0.05)
    assert np.all((damps > 0.01) & (damps < 0.2)), damps


def test_a_mimo_greybox_trains_and_simulates_every_output(fitted, mimo_data):
    """Shapes per output and input; its free run of a new recording is far closer than the
    best constant (each output's mean)."""
    splits, dm = mimo_data
    assert fitted.dynamics.residues.shape == (2, 2, 2)
    assert len(fitted.amplifiers) == len(fitted.cells) == 2
    rec = splits.test[0]
    predicted = free_run(fitted, [rec], dm.window)[0]
    assert predicted.shape == rec.y.shape
    ft = dm.window.first_target
    constant = rec.y[ft:].std(axis=0)
    errors = rmse_per_output(predicted, rec, ft)
    assert np.all(errors < 0.15 * constant), (errors, constant)
    frequencies = fitted.physical_parameters()["dynamics"]["frequency_hz"]
    np.testing.assert_allclose(np.sort(frequencies), MODES_HZ, rtol=0.05)


def test_its_linear_weights_are_the_least_squares_ones_after_training(fitted, mimo_data):
    """Residues, feedthrough and offsets are solved, not stepped: the trained model's are
    the least-squares fit given its other parameters, and every parameter trains again
    afterwards (requires_grad restored)."""
    splits, _ = mimo_data
    kept = [p.detach().clone() for p in fitted._linear_weights()]
    fitted._fit_linear_weights([r.u for r in splits.train], [r.y for r in splits.train])
    for before, after in zip(kept, fitted._linear_weights(), strict=True):
        torch.testing.assert_close(after.detach(), before, rtol=1e-6, atol=1e-9)
    assert all(p.requires_grad for p in fitted.parameters())


def test_a_saved_mimo_greybox_loads_and_simulates_the_same(fitted, mimo_data, tmp_path):
    splits, dm = mimo_data
    loaded = load_model(save_model(fitted, tmp_path / "model"))
    np.testing.assert_array_equal(free_run(fitted, splits.test, dm.window)[0],
                                  free_run(loaded, splits.test, dm.window)[0])


def test_the_mimo_greybox_steps_in_onnx_as_it_simulates(fitted, mimo_data, tmp_path):
    ort = optional_dependency("onnxruntime")
    from hysteresis_lab.models.export import export_onnx

    splits, dm = mimo_data
    session = ort.InferenceSession(str(export_onnx(fitted, tmp_path / "greybox.onnx")))
    rec = splits.test[0]
    state = np.zeros((1, len(fitted.state_names())))
    produced = np.empty_like(rec.y)
    for k, u in enumerate(rec.u[:400]):
        produced[k], state = session.run(None, {"state": state, "u": u[None]})
    expected = free_run(fitted, [rec], dm.window)[0]
    ft = dm.window.first_target
    np.testing.assert_allclose(produced[ft:400], expected[ft:400], rtol=0,
                               atol=1e-9 * np.max(np.abs(expected)))


def test_a_grown_mimo_greybox_starts_where_the_fitted_one_is(fitted, mimo_data):
    """The loop adds creep and a mode (``resonance``): the new blocks start at zero weight,
    so the grown model simulates what the fitted one did."""
    splits, dm = mimo_data
    grown = build_model({"name": "greybox", "n_modes": 2, "effects": ["creep", "resonance"]},
                        dm, trained_on={"fs": FS}, feature_context={})
    grown.warm_start_from(fitted)
    assert grown.dynamics.n_modes == 3 and "dynamics.residues" in grown._new_entries
    np.testing.assert_allclose(free_run(grown, splits.test, dm.window)[0],
                               free_run(fitted, splits.test, dm.window)[0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("settings", [{"n_modes": 0}, {"n_modes": 1, "effects": ["creep"],
                                                      "hysteresis": "prandtl_ishlinskii"}])
def test_its_simulation_step_reproduces_its_free_run(mimo_data, settings):
    """Without modes (feedthrough only) and with creep and play operators: stepping the
    physical chain sample by sample from zeros gives the whole-recording simulation."""
    splits, dm = mimo_data
    model = build_model({"name": "greybox", **settings}, dm, trained_on={"fs": FS},
                        feature_context={})
    model.initialise_from_recordings(splits.train)
    with torch.no_grad():
        if hasattr(model, "creeps"):  # creep at work (it starts at zero weight)
            for creep in model.creeps:
                creep.weights.fill_(0.05)
        rec = splits.test[0]
        expected = free_run(model, [rec], dm.window)[0][:300]
        state = torch.zeros(1, len(model.state_names()), dtype=torch.float64)
        produced = []
        for u in torch.as_tensor(rec.u[:300]):
            y, state = model.step_physical(state, u[None])
            produced.append(y[0].numpy())
    ft = dm.window.first_target
    np.testing.assert_allclose(np.array(produced)[ft:], expected[ft:], rtol=0,
                               atol=1e-9 * np.max(np.abs(expected)))


def test_settings_a_mimo_greybox_cannot_take_are_refused(mimo_data):
    _, dm = mimo_data
    with pytest.raises(ConfigError, match=r"residual_neurons=8 with 2 inputs and 2 outputs"):
        build_model({"name": "greybox", "residual_neurons": 8}, dm)
    with pytest.raises(ConfigError, match=r"effects \['drift'\]"):
        build_model({"name": "greybox", "effects": ["drift"]}, dm, feature_context={})
    with pytest.raises(ConfigError, match=r"model.n_modes=40 \(0-32\)"):
        build_model({"name": "greybox", "n_modes": 40}, dm)


def test_data_with_other_channels_than_the_model_are_refused(fitted, mimo_data):
    _, dm = mimo_data
    rec = two_by_two(1, 300, 4)[0]
    one_input = Recording(u=rec.u[:, :1], y=rec.y, fs=FS, name="one_input")
    with pytest.raises(DataError, match=r"1 input\(s\) and 2 output\(s\) but the model "
                                        r"expects 2 and 2"):
        free_run(fitted, [one_input], dm.window)


def test_one_input_and_output_keep_the_single_axis_model():
    """SISO data build the one-axis chain (its parameters as before, no MIMO blocks), and
    the start from all recordings is the start from the longest one, as training made it."""
    recordings = two_by_two(2, 1200, 3)
    siso = [Recording(u=r.u[: 800 + 400 * i, :1], y=r.y[: 800 + 400 * i, :1], fs=FS,
                      name=r.name) for i, r in enumerate(recordings)]
    dm = WindowDataModule(DatasetSplits("siso", train=siso, test=siso[:1]), scaling="standard")
    models = [build_model({"name": "greybox"}, dm, trained_on={"fs": FS}) for _ in range(2)]
    assert {name.split(".")[0] for name, _ in models[0].named_parameters()} == \
        {"amplifier", "hysteresis", "gain", "mode", "offset"}
    models[0].initialise_from_recordings(siso)
    longest = siso[-1]
    models[1].initialise_from_data(longest.u[:, 0], longest.y[:, 0], FS)
    for a, b in zip(models[0].state_dict().values(), models[1].state_dict().values(),
                    strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert float(models[0].gain) != 1.0  # it was initialised
