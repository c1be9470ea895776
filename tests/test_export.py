"""ONNX export: physical units in and out, parity with onnxruntime."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import optional_dependency
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.fitting import build_model
from narx import CONFIGS, datamodule_for, narx_data


@pytest.mark.parametrize("name", ["ffnn", "lstm", "cnn"])
def test_onnx_export_matches_pytorch(name, tmp_path):
    ort = optional_dependency("onnxruntime")
    from hysteresis_lab.models.export import export_onnx

    dm = datamodule_for(name, narx_data(n=300))
    model = build_model(CONFIGS[name], dm).eval()
    path = export_onnx(model, tmp_path / f"{name}.onnx")
    session = ort.InferenceSession(str(path))
    rng = np.random.default_rng(1)
    for batch in (1, 7):  # dynamic batch axis
        u = rng.normal(scale=50.0, size=(batch, dm.window.nb, 1)).astype(np.float32)
        y = rng.normal(scale=5.0, size=(batch, dm.window.na, 1)).astype(np.float32)
        onnx_out = session.run(None, {"u_past": u, "y_past": y})[0]
        with torch.no_grad():
            torch_out = model.predict_physical(torch.from_numpy(u), torch.from_numpy(y)).numpy()
        assert onnx_out.shape == (batch, 1)
        np.testing.assert_allclose(onnx_out, torch_out, atol=1e-4)


def test_svm_is_not_exportable():
    from hysteresis_lab.models.export import export_onnx

    svm = build_model(CONFIGS["svm"], datamodule_for("svm", narx_data(n=300)))
    with pytest.raises(ConfigError, match="skops"):
        export_onnx(svm, "unused.onnx")


def _perturbed(model: torch.nn.Module, seed: int = 0) -> torch.nn.Module:
    """Every parameter moved off its start (effect weights start at zero, where a block's
    step would go untested)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.2 * torch.randn(p.shape, generator=gen, dtype=p.dtype))
    return model


def _step_through(path, recording) -> np.ndarray:
    """The exported step run over a recording's inputs from the state every recording starts
    from (the file's ``initial_state``: zeros, the state at rest, unless the model learned a
    shared initial state)."""
    import json

    ort = optional_dependency("onnxruntime")
    session = ort.InferenceSession(str(path))
    meta = session.get_modelmeta().custom_metadata_map
    names = json.loads(meta["state_names"])
    state = np.asarray(json.loads(meta["initial_state"]), dtype=np.float64)[None]
    assert state.shape == (1, len(names))
    outputs = []
    for u in recording.u:
        y, state = session.run(None, {"state": state, "u": u[None].astype(np.float64)})
        outputs.append(y[0])
    return np.array(outputs)


#: cases trained on data whose recordings all start from one unknown state
SHARED_START = ("linear_shared_start", "greybox_shared_start", "linear_output_stage_shared_start")
CHAIN_CASES = {
    "greybox": ({"name": "greybox"}, 1, 1),
    "greybox_creep_resonance": ({"name": "greybox", "effects": ["creep", "resonance"]}, 1, 1),
    "greybox_prandtl_ishlinskii": ({"name": "greybox", "hysteresis": "prandtl_ishlinskii",
                                    "delay": 3}, 1, 1),
    "greybox_residual": ({"name": "greybox", "residual_neurons": 4}, 1, 1),
    "linear": ({"name": "linear"}, 1, 1),
    "linear_effects": ({"name": "linear", "effects": ["saturation", "dead_zone", "backlash",
                                                      "hysteresis", "rate", "creep", "resonance",
                                                      "nonlinear_feedback", "overflow"]}, 1, 1),
    "linear_rate": ({"name": "linear", "effects": ["rate"]}, 1, 1),
    "linear_nonlinear_feedback": ({"name": "linear", "effects": ["nonlinear_feedback"]}, 1, 1),
    "linear_shared_start": ({"name": "linear", "effects": ["backlash", "nonlinear_feedback",
                                                          "overflow"]}, 1, 1),
    "greybox_shared_start": ({"name": "greybox"}, 1, 1),
    "linear_mimo": ({"name": "linear", "order": 3, "delay": 0}, 3, 2),
    "linear_mimo_effects": ({"name": "linear", "order": 2,
                             "effects": ["hysteresis", "creep", "overflow"]}, 2, 2),
    "linear_mimo_feedback": ({"name": "linear", "order": 2, "delay": 0,
                              "effects": ["nonlinear_feedback"]}, 2, 2),
    "linear_output_stage": ({"name": "linear", "feedback_on": "output_stage", "order": 3,
                             "effects": ["hysteresis", "nonlinear_feedback", "overflow"]}, 1, 1),
    "linear_mimo_output_stage": ({"name": "linear", "order": 2, "feedback_on": "output_stage",
                                  "effects": ["nonlinear_feedback", "overflow"]}, 2, 2),
    "linear_output_stage_plain": ({"name": "linear", "feedback_on": "output_stage",
                                   "delay": 0}, 1, 1),
    "linear_output_stage_shared_start": ({"name": "linear", "feedback_on": "output_stage",
                                          "effects": ["nonlinear_feedback", "overflow"]}, 1, 1),
    "linear_integrator": ({"name": "linear", "integrator": True}, 1, 1),
    "linear_integrator_effects": ({"name": "linear", "integrator": True, "order": 3,
                                   "effects": ["hysteresis", "nonlinear_feedback", "overflow",
                                               "resonance"]}, 1, 1),
    "linear_mimo_integrator": ({"name": "linear", "integrator": True, "order": 2,
                                "effects": ["nonlinear_feedback"]}, 2, 2),
}


@pytest.mark.parametrize("case", sorted(CHAIN_CASES))
def test_a_physical_chain_steps_in_onnx_as_it_simulates(case, tmp_path):
    """The grey-box and the linear model export their simulation step; stepped from the
    file's initial state (zeros, or a learned shared initial state) over a recording, it
    reproduces the model's own free run."""
    optional_dependency("onnxruntime")
    from hysteresis_lab.evaluation.predict import free_run
    from hysteresis_lab.models.augment import augment_splits, context_to_dict
    from hysteresis_lab.models.export import export_onnx

    config, nu, ny = CHAIN_CASES[case]
    splits = narx_data(n=600, nu=nu, ny=ny)
    extra = {}
    if config.get("effects"):  # as the pipeline builds it: the effect channels beside u
        augmented, context = augment_splits(splits, config["effects"])
        extra = {"feature_context": context_to_dict(context), "n_base_inputs": nu}
        dm = datamodule_for(config["name"], augmented)
    else:
        dm = datamodule_for(config["name"], splits)
    shared = {"shared_initial_state": True} if case in SHARED_START else {}
    model = build_model(config, dm, trained_on={"fs": 100.0, **shared}, **extra)
    assert (model.start_input is not None) == bool(shared)
    rec = splits.train[0]
    model.initialise_from_data(rec.u[:, 0] if nu == 1 else rec.u, rec.y[:, 0] if ny == 1
                               else rec.y, rec.fs)
    model = _perturbed(model).eval()
    if shared:  # the start is not rest, so stepping from zeros would not reproduce the run
        assert float(model.initial_state().abs().max()) > 1e-3
    path = export_onnx(model, tmp_path / f"{case}.onnx")
    assert path.name == f"{case}_step.onnx"
    test = splits.test[0]  # the step reads the measured inputs alone
    expected = free_run(model, [dm.splits.test[0]], dm.window)[0]
    produced = _step_through(path, test)
    assert produced.shape == expected.shape == (test.n_samples, ny)
    ft = dm.window.first_target
    # a shared start is the state after a burn-in of a few hundred samples, whose rounding
    # (the step's form against the whole-recording filters) the first samples still carry
    tolerance = 1e-8 if shared else 1e-9
    np.testing.assert_allclose(produced[ft:], expected[ft:], rtol=0,
                               atol=tolerance * np.max(np.abs(expected)))
