"""Export a trained network with its normalisation to ONNX (physical units in and out)."""

from __future__ import annotations

import logging
from pathlib import Path

import torch
from torch import nn

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.base import NarxModule
from hysteresis_lab.models.state_space import StateSpaceModule

log = logging.getLogger(__name__)


class PhysicalModel(nn.Module):
    """``(u_past [V] (B, nb, nu), y_past [µm] (B, na, ny)) -> y [µm] (B, ny)``."""

    def __init__(self, model: NarxModule) -> None:
        super().__init__()
        self.model = model

    def forward(self, u_past: torch.Tensor, y_past: torch.Tensor) -> torch.Tensor:
        return self.model.predict_physical(u_past, y_past)


class PhysicalStep(nn.Module):
    """A state-space model's step: ``(state (B, nx), u [V] (B, nu)) -> (y [µm] (B, ny),
    next state (B, nx))``; ``y`` is the output of ``state``, the input drives the next one."""

    def __init__(self, model: StateSpaceModule) -> None:
        super().__init__()
        self.model = model

    def forward(self, state: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        m = self.model
        y = m.unscale_output(m.output(state))
        return y, m.transition(state, (u - m.u_offset) / m.u_scale)


def export_onnx(model: object, path: Path | str, opset: int = 17) -> Path:
    """Write ``model`` as ONNX with a dynamic batch axis; returns the path.

    The file maps past inputs and outputs to the next output (one-step prediction). A
    state-space model (`StateSpaceModule`) also gets ``<stem>_step.onnx``, its simulation
    step: the one-step file's encoder gives the initial state (``encode``), the step file
    runs it forward from the input alone.
    """
    if getattr(model, "whole_recordings", False):
        raise ConfigError(
            f"{type(model).__name__} is not exported to ONNX: its blocks run as compiled "
            "recursions over whole recordings, which ONNX does not express. Fix: share its "
            "model.ckpt (hysteresis_lab.models.io.load_model) or its physical_parameters()."
        )
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
    if isinstance(model, StateSpaceModule):
        _export_step(model, path.with_name(f"{path.stem}_step.onnx"), opset)
    return path


def _export_step(model: StateSpaceModule, path: Path, opset: int) -> None:
    state = model.encode(torch.zeros(2, model.n_features))
    torch.onnx.export(
        PhysicalStep(model), (state.detach(), torch.zeros(2, model.nu)), str(path),
        input_names=["state", "u"], output_names=["y", "next_state"],
        dynamic_axes={name: {0: "batch"} for name in ("state", "u", "y", "next_state")},
        opset_version=opset, dynamo=False,
    )
    log.info("exported the simulation step of %s to %s", type(model).__name__, path)
