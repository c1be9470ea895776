"""Honest evaluation: one-step-ahead prediction, free-run simulation and n-step prediction.

* ``one_step``: the regressors hold the *measured* past outputs (the study's mode).
* ``free_run``: the model feeds back its own predictions; only the first
  ``window.first_target`` samples come from the measurement (initial conditions). All
  recordings run together in one batch (padded to the longest) on the model's device.
* ``n_step``: free runs restarted from the measurement every ``n`` samples.

Every function returns one array (N, ny) per recording in physical units; the first
``first_target`` samples are the measured initial conditions.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.scaling import Scaler
from hysteresis_lab.data.windows import WindowSpec, assemble, make_windows
from hysteresis_lab.errors import DataError

Step = Callable[[Any], Any]


def _check(model: Any, recordings: Sequence[Recording], window: WindowSpec) -> None:
    for rec in recordings:
        if (rec.nu, rec.ny) != (model.nu, model.ny):
            raise DataError(
                f"has {rec.nu} input(s) and {rec.ny} output(s) but the model expects "
                f"{model.nu} and {model.ny}.",
                source=f"recording '{rec.name}'",
                fix="score the model on data with the channels it was trained on (and the same "
                "model.effects)",
            )
        if rec.n_samples <= window.first_target:
            raise DataError(
                f"has {rec.n_samples} samples; at least {window.first_target + 1} are needed.",
                source=f"recording '{rec.name}'",
                fix="use a longer recording",
            )


def _scaler(model: Any) -> Scaler:
    if isinstance(model, torch.nn.Module):
        return Scaler(
            *(
                getattr(model, k).detach().cpu().numpy().astype(float)
                for k in ("u_offset", "u_scale", "y_offset", "y_scale")
            )
        )
    return model.scaler


def _numpy_step(model: Any) -> Step | None:
    """A NumPy function scaled regressors -> scaled outputs, when the model offers one."""
    if isinstance(model, torch.nn.Module):
        fast = getattr(model, "numpy_forward", None)
        return fast() if fast is not None else None
    fast = getattr(model, "fast_predictor", None)
    return fast() if fast is not None else model.predict_scaled


def one_step(
    model: Any, recordings: Sequence[Recording], window: WindowSpec, batch_size: int = 65_536
) -> list[np.ndarray]:
    """Predict each sample from measured past inputs and outputs."""
    _check(model, recordings, window)
    s = _scaler(model)
    outputs = []
    for rec in recordings:
        w = make_windows(rec, window, dtype=np.float64)
        x = assemble(
            (w.u_past - s.u_offset) / s.u_scale, (w.y_past - s.y_offset) / s.y_scale, model.layout
        ).astype(np.float32)
        predicted = np.empty((len(w), rec.ny))
        for start in range(0, len(x), batch_size):
            chunk = x[start : start + batch_size]
            predicted[start : start + batch_size] = _forward_batch(model, chunk)
        y_hat = np.array(rec.y, dtype=float)
        y_hat[window.first_target :] = predicted * s.y_scale + s.y_offset
        outputs.append(y_hat)
    return outputs


def _forward_batch(model: Any, x: np.ndarray) -> np.ndarray:
    if isinstance(model, torch.nn.Module):
        device = next(model.parameters()).device
        with torch.inference_mode():
            return model(torch.from_numpy(x).to(device)).double().cpu().numpy()
    return model.predict_scaled(x)


def free_run(
    model: Any,
    recordings: Sequence[Recording],
    window: WindowSpec,
    device: str | torch.device | None = None,
) -> list[np.ndarray]:
    """Simulate every recording from its input alone, all in one batch."""
    _check(model, recordings, window)
    starts = [[0] for _ in recordings]
    return _simulate(model, recordings, window, starts, device)


def n_step(
    model: Any,
    recordings: Sequence[Recording],
    window: WindowSpec,
    n: int,
    device: str | torch.device | None = None,
) -> list[np.ndarray]:
    """Free runs of ``n`` samples, each restarted from measured outputs (k-step-ahead)."""
    if n < 1:
        raise DataError(f"n_step={n} must be >= 1.", fix="set n_step to a positive integer")
    _check(model, recordings, window)
    starts = [list(range(0, rec.n_samples, n)) for rec in recordings]
    return _simulate(model, recordings, window, starts, device)


def _simulate(
    model: Any,
    recordings: Sequence[Recording],
    window: WindowSpec,
    restarts: list[list[int]],
    device: str | torch.device | None,
) -> list[np.ndarray]:
    """Batched simulation; at each sample in ``restarts`` the output history is re-measured."""
    s = _scaler(model)
    ft, na, nb, nk = window.first_target, window.na, window.nb, window.nk
    length = max(rec.n_samples for rec in recordings)
    batch = len(recordings)
    u = np.zeros((batch, length, model.nu))
    y_meas = np.zeros((batch, length, model.ny))
    for b, rec in enumerate(recordings):
        u[b, : rec.n_samples] = (rec.u - s.u_offset) / s.u_scale
        y_meas[b, : rec.n_samples] = (rec.y - s.y_offset) / s.y_scale
    y = y_meas.copy()  # the first ft samples stay measured; the rest is overwritten
    reset = np.zeros((length, batch), dtype=bool)
    for b, points in enumerate(restarts):
        for p in points:
            reset[p + ft : p + ft + 1, b] = True  # from here on the lags are re-measured
    reset[ft] = True
    numpy_step = _numpy_step(model)
    if numpy_step is not None and (device is None or str(device) == "cpu"):
        y = _loop_numpy(numpy_step, model.layout, u, y, y_meas, reset, ft, na, nb, nk)
    else:
        y = _loop_torch(model, u, y, y_meas, reset, ft, na, nb, nk, device)
    return [y[b, : rec.n_samples] * s.y_scale + s.y_offset for b, rec in enumerate(recordings)]


def _loop_numpy(
    step: Step,
    layout: str,
    u: np.ndarray,
    y: np.ndarray,
    y_meas: np.ndarray,
    reset: np.ndarray,
    ft: int,
    na: int,
    nb: int,
    nk: int,
) -> np.ndarray:
    resets = reset.any(axis=1)
    out = y.copy()  # predictions; ``y`` is the lag history (re-measured at restarts)
    for k in range(ft, u.shape[1]):
        if resets[k] and k > ft:
            rows = reset[k]
            y[rows, k - na : k] = y_meas[rows, k - na : k]
        x = assemble(u[:, k - nk - nb + 1 : k - nk + 1], y[:, k - na : k], layout)
        y[:, k] = out[:, k] = step(x)
    return out


def _loop_torch(
    model: torch.nn.Module,
    u: np.ndarray,
    y: np.ndarray,
    y_meas: np.ndarray,
    reset: np.ndarray,
    ft: int,
    na: int,
    nb: int,
    nk: int,
    device: str | torch.device | None,
) -> np.ndarray:
    device = torch.device(device) if device is not None else next(model.parameters()).device
    original = next(model.parameters()).device
    model.to(device)
    try:
        with torch.inference_mode():
            ut = torch.as_tensor(u, dtype=torch.float32, device=device)
            yt = torch.as_tensor(y, dtype=torch.float32, device=device)
            ymt = torch.as_tensor(y_meas, dtype=torch.float32, device=device)
            resets = reset.any(axis=1)
            mask = torch.as_tensor(reset, device=device)
            out = yt.clone()  # predictions; ``yt`` is the lag history (re-measured at restarts)
            for k in range(ft, u.shape[1]):
                if resets[k] and k > ft:
                    rows = mask[k]
                    yt[rows, k - na : k] = ymt[rows, k - na : k]
                x = assemble(ut[:, k - nk - nb + 1 : k - nk + 1], yt[:, k - na : k], model.layout)
                prediction = model(x)
                yt[:, k] = prediction
                out[:, k] = prediction
            return out.double().cpu().numpy()
    finally:
        model.to(original)
