"""Export a trained network with its normalisation to ONNX (physical units in and out).

Each model class says what it writes (`ModelContract.export_onnx`): a NARX network its one-step
file (`export_narx`), a state-space model that and its simulation step (`export_state_space_step`),
a physical chain its simulation step (`export_chain_step`). This module imports no model class.
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path

import torch
from torch import nn

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.models.interface import ModelContract

log = logging.getLogger(__name__)


class PhysicalModel(nn.Module):
    """``(u_past [V] (B, nb, nu), y_past [µm] (B, na, ny)) -> y [µm] (B, ny)``."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, u_past: torch.Tensor, y_past: torch.Tensor) -> torch.Tensor:
        return self.model.predict_physical(u_past, y_past)


class PhysicalStep(nn.Module):
    """A state-space model's step: ``(state (B, nx), u [V] (B, nu)) -> (y [µm] (B, ny),
    next state (B, nx))``; ``y`` is the output of ``state``, the input drives the next one."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, state: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        m = self.model
        y = m.unscale_output(m.output(state))
        return y, m.transition(state, (u - m.u_offset) / m.u_scale)


class ChainStep(nn.Module):
    """A physical chain's step (`PhysicalChainModule.step_physical`): ``(state (B, nx),
    u [V] (B, n_base_inputs)) -> (y [µm] (B, ny), next state (B, nx))``, float64."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, state: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.model.step_physical(state, u)


def export_onnx(model: ModelContract, path: Path | str, opset: int = 17) -> Path:
    """Write ``model`` as ONNX with a dynamic batch axis; returns the path of the file that
    simulates or predicts with it.

    A NARX network gets the one-step file (past inputs and outputs to the next output). A
    state-space model (`StateSpaceModule`) also gets ``<stem>_step.onnx``, its simulation
    step: the one-step file's encoder gives the initial state (``encode``), the step file
    runs it forward from the input alone. A physical chain (the grey-box, the linear model)
    is an output-error model, whose one-step prediction is its free run: it gets only
    ``<stem>_step.onnx`` (`export_chain_step`), and that path is returned. A model outside
    these (the SVM) is refused with a fix.
    """
    if not isinstance(model, ModelContract):
        raise ConfigError(
            f"{type(model).__name__} cannot be exported to ONNX here; only the networks can. "
            "Fix: share the SVM's model.skops file (load it with hysteresis_lab.models.io)."
        )
    return model.export_onnx(path, opset)


def export_narx(model: nn.Module, path: Path | str, opset: int = 17) -> Path:
    """Write a NARX network's one-step prediction as ONNX (`PhysicalModel`); returns the path."""
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


def export_state_space_step(model: nn.Module, path: Path, opset: int = 17) -> Path:
    """Write a state-space model's simulation step (`PhysicalStep`) as ONNX; returns the path."""
    state = model.encode(torch.zeros(2, model.n_features))
    torch.onnx.export(
        PhysicalStep(model), (state.detach(), torch.zeros(2, model.nu)), str(path),
        input_names=["state", "u"], output_names=["y", "next_state"],
        dynamic_axes={name: {0: "batch"} for name in ("state", "u", "y", "next_state")},
        opset_version=opset, dynamo=False,
    )
    log.info("exported the simulation step of %s to %s", type(model).__name__, path)
    return path


def export_chain_step(model: nn.Module, path: Path | str, opset: int = 17) -> Path:
    """Write a physical chain's simulation step as ONNX; returns the path.

    Inputs ``state`` (B, nx) and ``u`` (B, n_base_inputs, the measured inputs in their
    units), outputs ``y`` (B, ny, the output at the sample of ``u``) and ``next_state``, all
    float64 with a dynamic batch axis. The state at rest (zero input, as every recording
    starts) is zeros; its columns are ``model.state_names()``, stored in the file's metadata
    as ``state_names`` (JSON). Stepping from ``initial_state`` (metadata, JSON: zeros, or the
    learned shared initial state, `PhysicalChainModule.initial_state`) over a recording gives
    the model's free run.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    model = model.cpu().eval()
    try:
        names = model.state_names()
    except NotImplementedError:
        raise ConfigError(
            f"{type(model).__name__} has no one-sample step (chain_step, state_names), so its "
            "simulation step cannot be exported to ONNX. Fix: implement them (see "
            "hysteresis_lab.models.physical_chain), or share its model.ckpt "
            "(hysteresis_lab.models.io.load_model)."
        ) from None
    state = torch.zeros(2, len(names), dtype=torch.float64)
    u = torch.zeros(2, model.n_base_inputs, dtype=torch.float64)
    with torch.no_grad(), warnings.catch_warnings():
        # the blocks' shapes and coefficients are constants of the step (`frozen`)
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        torch.onnx.export(
            ChainStep(model), (state, u), str(path), input_names=["state", "u"],
            output_names=["y", "next_state"],
            dynamic_axes={name: {0: "batch"} for name in ("state", "u", "y", "next_state")},
            opset_version=opset, dynamo=False,
        )
    start = model.initial_state().tolist()
    _add_metadata(path, {"state_names": json.dumps(names), "state_at_rest": "zeros",
                         "initial_state": json.dumps(start), "model": type(model).__name__})
    log.info("exported the simulation step of %s (%d states) to %s", type(model).__name__,
             len(names), path)
    return path


def _add_metadata(path: Path, entries: dict[str, str]) -> None:
    """Store ``entries`` in an ONNX file's ``metadata_props``."""
    import onnx

    proto = onnx.load(str(path))
    for key, value in entries.items():
        prop = proto.metadata_props.add()
        prop.key, prop.value = key, value
    onnx.save(proto, str(path))
