"""Export a trained network with its normalisation to ONNX (physical units in and out)."""

from __future__ import annotations

import logging
from pathlib import Path

import torch
from torch import nn

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.base import NarxModule

log = logging.getLogger(__name__)


class PhysicalModel(nn.Module):
    """``(u_past [V] (B, nb, nu), y_past [µm] (B, na, ny)) -> y [µm] (B, ny)``."""

    def __init__(self, model: NarxModule) -> None:
        super().__init__()
        self.model = model

    def forward(self, u_past: torch.Tensor, y_past: torch.Tensor) -> torch.Tensor:
        return self.model.predict_physical(u_past, y_past)


def export_onnx(model: object, path: Path | str, opset: int = 17) -> Path:
    """Write ``model`` as ONNX with a dynamic batch axis; returns the path."""
    if not isinstance(model, NarxModule):
        raise ConfigError(
            f"{type(model).__name__} cannot be exported to ONNX here; only the networks can. "
            "Fix: share the SVM's model.skops file (load it with hysteresis_lab.models.io)."
        )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    wrapper = PhysicalModel(model.cpu().eval())
    window = model.window
    u_past = torch.zeros(2, window.nb, model.nu)
    y_past = torch.zeros(2, window.na, model.ny)
    torch.onnx.export(
        wrapper, (u_past, y_past), str(path), input_names=["u_past", "y_past"],
        output_names=["y"], dynamic_axes={"u_past": {0: "batch"}, "y_past": {0: "batch"},
                                          "y": {0: "batch"}},
        opset_version=opset, dynamo=False,
    )
    log.info("exported %s to %s", type(model).__name__, path)
    return path
