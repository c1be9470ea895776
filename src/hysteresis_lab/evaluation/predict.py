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

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.windows import WindowSpec, assemble, make_windows
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.kernels.interface import sequence_masks
from hysteresis_lab.models.interface import SystemModel


def _check(model: Any, recordings: Sequence[Recording], window: WindowSpec) -> None:
    if not recordings:
        raise DataError("there are no recordings to predict.", fix="supply test recordings")
    own = model.window
    if own != window:
        raise ConfigError(
            f"the model was built for lags na={own.na}, nb={own.nb}, nk={own.nk} but the data "
            f"window is na={window.na}, nb={window.nb}, nk={window.nk}. Fix: evaluate with the "
            "model's window (hysteresis_lab.models.io.model_window(model))."
        )
    trained_on = dict(model.hparams or {}).get("trained_on") or {}
    for rec in recordings:
        _check_recorded_like_training(rec, trained_on)
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


def _check_recorded_like_training(rec: Recording, trained_on: dict[str, Any]) -> None:
    """Refuse a recording at another sampling rate or in other units than the model's
    training data (models saved before they kept these are not checked)."""
    fs = trained_on.get("fs")
    if fs and not np.isclose(rec.fs, fs, rtol=1e-6):
        raise DataError(
            f"is sampled at {rec.fs:g} Hz but the model was trained at {fs:g} Hz: its lags "
            "span a fixed number of samples, so it would see another time scale.",
            source=f"recording '{rec.name}'",
            fix=f"resample the recording to {fs:g} Hz, or train a model on data at {rec.fs:g} Hz",
        )
    trained = (trained_on.get("u_units"), trained_on.get("y_units"))
    if None not in trained and (rec.u_units, rec.y_units) != trained:
        raise DataError(
            f"is in u [{rec.u_units}], y [{rec.y_units}] but the model was trained on u "
            f"[{trained[0]}], y [{trained[1]}]: its scaling works in those units.",
            source=f"recording '{rec.name}'",
            fix=f"convert the recording to {trained[0]} and {trained[1]} (for CSV files that "
            f"are already in them: data.units.u={trained[0]} data.units.y={trained[1]})",
        )


def one_step(
    model: SystemModel,
    recordings: Sequence[Recording],
    window: WindowSpec,
    batch_size: int = 65_536,
) -> list[np.ndarray]:
    """Predict each sample from measured past inputs and outputs (a model that does not read
    measured outputs, ``predicts_from_outputs = False``, predicts by its free run)."""
    _check(model, recordings, window)
    if not model.predicts_from_outputs:
        return free_run(model, recordings, window)
    s = model.scaler
    outputs = []
    for rec in recordings:
        w = make_windows(rec, window, dtype=np.float64)
        x = assemble(
            (w.u_past - s.u_offset) / s.u_scale, (w.y_past - s.y_offset) / s.y_scale, model.layout
        ).astype(np.float32)
        predicted = np.empty((len(w), rec.ny))
        for start in range(0, len(x), batch_size):
            chunk = x[start : start + batch_size]
            predicted[start : start + batch_size] = model.predict_scaled(chunk)
        y_hat = np.array(rec.y, dtype=float)
        y_hat[window.first_target :] = predicted * s.y_scale + s.y_offset
        outputs.append(y_hat)
    return outputs


def free_run(
    model: SystemModel,
    recordings: Sequence[Recording],
    window: WindowSpec,
    device: str | torch.device | None = None,
    fast: bool = True,
) -> list[np.ndarray]:
    """Simulate every recording from its input alone, all in one batch.

    ``fast=False`` skips the model's NumPy free-run kernel (reference path for tests).
    """
    _check(model, recordings, window)
    starts = [[0] for _ in recordings]
    return _simulate(model, recordings, window, starts, device, fast)


def restarted_free_runs(
    model: SystemModel,
    recordings: Sequence[Recording],
    window: WindowSpec,
    start: int,
    device: str | torch.device | None = None,
) -> list[np.ndarray]:
    """Free runs that read their state afresh from the measured outputs before sample
    ``start`` (> ``window.first_target``) and simulate from there; before ``start`` each is
    the free run from the recording's first samples."""
    _check(model, recordings, window)
    starts = [[0, start - window.first_target] for _ in recordings]
    return _simulate(model, recordings, window, starts, device)


def check_n_step(n: int | None) -> None:
    """Raise `DataError` unless ``n`` is a valid n-step horizon (None: no n-step scores)."""
    whole = isinstance(n, int | float) and not isinstance(n, bool) and float(n).is_integer()
    if n is not None and not (whole and n >= 1):
        raise DataError(
            f"n_step={n} must be a whole number >= 1 (or null: no n-step scores).",
            fix="e.g. n_step=100",
        )


def n_step(
    model: SystemModel,
    recordings: Sequence[Recording],
    window: WindowSpec,
    n: int,
    device: str | torch.device | None = None,
    fast: bool = True,
) -> list[np.ndarray]:
    """Free runs of ``n`` samples, each restarted from the measured outputs.

    Segment ``i`` predicts samples ``ft + i*n .. ft + (i+1)*n - 1`` (``ft = first_target``)
    from the measured outputs before it and its own predictions within it, so its last sample
    is an ``n``-step-ahead prediction. ``n = 1`` equals `one_step`; ``n >= N`` equals
    `free_run`.
    """
    check_n_step(n)
    _check(model, recordings, window)
    starts = [list(range(0, rec.n_samples, n)) for rec in recordings]
    return _simulate(model, recordings, window, starts, device, fast)


def _simulate(
    model: Any,
    recordings: Sequence[Recording],
    window: WindowSpec,
    restarts: list[list[int]],
    device: str | torch.device | None,
    fast: bool = True,
) -> list[np.ndarray]:
    """Batched simulation; at each sample in ``restarts`` the output history is re-measured.

    Recordings run longest first, so the ones still running are always the leading rows
    (finished ones drop out of the batch instead of being simulated on padding).
    """
    s = model.scaler
    ft = window.first_target
    order = sorted(range(len(recordings)), key=lambda i: -recordings[i].n_samples)
    recs = [recordings[i] for i in order]
    lengths = np.array([rec.n_samples for rec in recs])
    length, batch = int(lengths[0]), len(recs)
    u = np.zeros((batch, length, model.nu))
    y_meas = np.zeros((batch, length, model.ny))
    for b, rec in enumerate(recs):
        u[b, : rec.n_samples] = (rec.u - s.u_offset) / s.u_scale
        y_meas[b, : rec.n_samples] = (rec.y - s.y_offset) / s.y_scale
    reset = np.zeros((length, batch), dtype=bool)
    for b, position in enumerate(order):
        for p in restarts[position]:
            if p > 0 and p + ft < lengths[b]:
                reset[p + ft, b] = True  # from here on the lags are re-measured
    active = np.searchsorted(-lengths, -np.arange(length), side="left")  # rows with len > k
    y = _run(model, u, y_meas, reset, active, window, device, fast)
    out = [np.empty(0)] * batch
    for b, position in enumerate(order):
        out[position] = y[b, : lengths[b]] * s.y_scale + s.y_offset
    return out


def _on_cpu(model: SystemModel, device: str | torch.device | None) -> bool:
    return torch.device(device if device is not None else model.device).type == "cpu"


def _run(
    model: Any,
    u: np.ndarray,
    y_meas: np.ndarray,
    reset: np.ndarray,
    active: np.ndarray,
    window: WindowSpec,
    device: str | torch.device | None,
    fast: bool = True,
) -> np.ndarray:
    """Scaled simulation of all rows: measured lags up to ``first_target``, then predictions."""
    if model.simulates_recordings:  # a state-space model runs its own state
        model_device = model.device
        model.to(torch.device(device) if device is not None else model_device)
        try:
            lengths = (active[None, :] > np.arange(u.shape[0])[:, None]).sum(axis=1)
            return model.simulate_recordings(u, y_meas, reset, window, lengths)
        finally:
            model.to(model_device)
    u, term = model.free_run_split(u)  # see NarxModule.free_run_split
    kernel = model.free_run_kernel(u, window) if fast and _on_cpu(model, device) else None
    if kernel is not None and not (kernel.stateful and reset.any()):
        return _loop_kernel(_with_term(kernel, term), y_meas, reset, active, window)
    if not model.is_network:
        return _loop_kernel(_GenericKernel(model, u, window), y_meas, reset, active, window)
    return _loop_torch(model, u, y_meas, reset, active, window, device, term)


class _PlusInputTerm:
    """A kernel whose every step adds a precomputed, input-only term (the linear effect path)."""

    def __init__(self, kernel: Any, term: np.ndarray) -> None:
        self.kernel, self.term, self.stateful = kernel, term, kernel.stateful

    def step(self, k: int, n: int, y: np.ndarray) -> np.ndarray:
        return self.kernel.step(k, n, y) + self.term[:n, k]


class _PlusInputTermAtOnce(_PlusInputTerm):
    """The same for a kernel that runs every step at once and takes the term itself."""

    def run_all(self, y: np.ndarray, active: np.ndarray, first_target: int) -> np.ndarray:
        return self.kernel.run_all(y, active, first_target, term=self.term)


def _with_term(kernel: Any, term: np.ndarray | None) -> Any:
    if term is None:
        return kernel
    return (_PlusInputTermAtOnce if hasattr(kernel, "run_all") else _PlusInputTerm)(kernel, term)


class _GenericKernel:
    """Fallback step for a NumPy model: assemble the regressor, call ``predict_scaled``."""

    stateful = False

    def __init__(self, model: Any, u: np.ndarray, window: WindowSpec) -> None:
        self.model, self.u, self.window = model, u, window

    def step(self, k: int, n: int, y: np.ndarray) -> np.ndarray:
        w = self.window
        u_past = self.u[:n, k - w.nk - w.nb + 1 : k - w.nk + 1]
        return self.model.predict_scaled(assemble(u_past, y[:n, k - w.na : k], "flat"))


def _loop_kernel(
    kernel: Any, y_meas: np.ndarray, reset: np.ndarray, active: np.ndarray, window: WindowSpec
) -> np.ndarray:
    """Run ``kernel.step`` over all samples; ``y`` holds the lag history (re-measured at
    restarts), ``out`` the predictions. A kernel with ``run_all`` runs a restart-free
    simulation in one call (see `hysteresis_lab.kernels.interface.FreeRunKernel`)."""
    ft, na = window.first_target, window.na
    run_all = getattr(kernel, "run_all", None)
    if run_all is not None and not reset.any():
        return run_all(y_meas.copy(), active, ft)
    y = y_meas.copy()
    out = y_meas.copy()
    restart_steps = set(np.flatnonzero(reset.any(axis=1)).tolist())
    for k in range(ft, y.shape[1]):
        n = int(active[k])
        if k in restart_steps:
            rows = reset[k]
            y[rows, k - na : k] = y_meas[rows, k - na : k]
        y[:n, k] = out[:n, k] = kernel.step(k, n, y)
    return out


def _loop_torch(
    model: Any,
    u: np.ndarray,
    y_meas: np.ndarray,
    reset: np.ndarray,
    active: np.ndarray,
    window: WindowSpec,
    device: str | torch.device | None,
    term: np.ndarray | None = None,
) -> np.ndarray:
    """Generic torch loop (GPU, or any plugin network): preassembled scaled lags, ``net`` only.

    For the sequence layout one feature array ``F[:, s] = [u[s-nk+1], y[s]]`` holds every
    regressor: the one of step ``k`` is the view ``F[:, k-L : k]`` (masked where ``na`` or
    ``nb`` is shorter than ``L``).
    """
    ft, na, nb, nk, length = window.first_target, window.na, window.nb, window.nk, window.seq_len
    nu = u.shape[2]
    device = torch.device(device) if device is not None else model.device
    original = model.device
    net = model.net
    model.to(device)
    restart_steps = set(np.flatnonzero(reset.any(axis=1)).tolist())
    try:
        with torch.inference_mode():
            y_meas_t = torch.as_tensor(y_meas, dtype=torch.float32, device=device)
            out = y_meas_t.clone()
            mask = torch.as_tensor(reset, device=device)
            term_t = (
                None if term is None
                else torch.as_tensor(term, dtype=torch.float32, device=device)
            )
            if model.layout == "sequence":
                pad = length + 1  # F index = sample index + pad
                feats = torch.zeros(u.shape[0], u.shape[1] + pad, nu + y_meas.shape[2],
                                    device=device)
                u_t = torch.as_tensor(u, dtype=torch.float32, device=device)
                # F[:, s + pad, :nu] = u[s - nk + 1]
                first = max(0, nk - 1)
                stop = u.shape[1] + nk - 1
                feats[:, first + pad : min(stop, u.shape[1]) + pad, :nu] = u_t[
                    :, first - nk + 1 : min(stop, u.shape[1]) - nk + 1
                ]
                feats[:, pad : pad + ft, nu:] = y_meas_t[:, :ft]
                m_u, m_y = (torch.as_tensor(m, dtype=torch.float32, device=device)
                            for m in sequence_masks(window))
                seq_mask = torch.cat(
                    [m_u[:, None].expand(length, nu),
                     m_y[:, None].expand(length, y_meas.shape[2])], 1
                )
                masked = not bool(seq_mask.all())
                for k in range(ft, u.shape[1]):
                    n = int(active[k])
                    if k in restart_steps:
                        rows = mask[k]
                        feats[rows, k - na + pad : k + pad, nu:] = y_meas_t[rows, k - na : k]
                    x = feats[:n, k - length + pad : k + pad]
                    prediction = net(x * seq_mask if masked else x)
                    if term_t is not None:
                        prediction = prediction + term_t[:n, k]
                    feats[:n, k + pad, nu:] = prediction
                    out[:n, k] = prediction
            else:
                u_t = torch.as_tensor(u, dtype=torch.float32, device=device)
                y_t = y_meas_t.clone()
                for k in range(ft, u.shape[1]):
                    n = int(active[k])
                    if k in restart_steps:
                        rows = mask[k]
                        y_t[rows, k - na : k] = y_meas_t[rows, k - na : k]
                    x = assemble(u_t[:n, k - nk - nb + 1 : k - nk + 1], y_t[:n, k - na : k],
                                 "flat")
                    prediction = net(x)
                    if term_t is not None:
                        prediction = prediction + term_t[:n, k]
                    y_t[:n, k] = prediction
                    out[:n, k] = prediction
            return out.double().cpu().numpy()
    finally:
        model.to(original)

