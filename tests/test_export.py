"""ONNX export: physical units in and out, parity with onnxruntime."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import optional_dependency
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.training import build_model
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
