"""NARX regression windows: past inputs and past outputs -> the next output.

For a target sample ``k`` the regressors are the inputs ``u[k-nk-nb+1 .. k-nk]`` and the
outputs ``y[k-na .. k-1]`` (oldest first). With the defaults ``na = nb = 10, nk = 1`` these
are the study's "10 past inputs and 10 past outputs".

Two layouts of the same numbers:

* ``flat`` (FFNN): one vector ``[u lags (nb*nu) | y lags (na*ny)]`` per target;
* ``sequence`` (LSTM/CNN): ``max(na, nb)`` time steps of ``nu + ny`` features, oldest step
  first; step ``j`` from the end holds ``u[k-nk-j]`` and ``y[k-1-j]``; lags beyond ``nb`` or
  ``na`` are zero.

`assemble` works on NumPy arrays and torch tensors alike, so training windows and the
free-run simulator build regressors with one and the same function.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, TypeVar

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.errors import ConfigError, DataError

Layout = Literal["flat", "sequence"]
LAYOUTS: tuple[str, ...] = ("flat", "sequence")

ArrayT = TypeVar("ArrayT")


@dataclass(frozen=True)
class WindowSpec:
    """Lag structure of a NARX regressor: ``na`` past outputs, ``nb`` past inputs, delay ``nk``."""

    na: int = 10
    nb: int = 10
    nk: int = 1

    def __post_init__(self) -> None:
        for name, value, low in (("na", self.na, 0), ("nb", self.nb, 1), ("nk", self.nk, 0)):
            if not isinstance(value, int | np.integer) or value < low:
                raise ConfigError(
                    f"window {name}={value!r} is invalid: it must be an integer >= {low}. "
                    f"Fix: set data.window.{name} to such a value."
                )

    @property
    def first_target(self) -> int:
        """Index of the first sample whose regressors all lie inside the recording."""
        return max(self.na, self.nb + self.nk - 1)

    @property
    def seq_len(self) -> int:
        return max(self.na, self.nb)

    def n_features(self, nu: int, ny: int, layout: Layout) -> int:
        """Width of one regressor: the vector length (flat) or features per step (sequence)."""
        check_layout(layout)
        return self.nb * nu + self.na * ny if layout == "flat" else nu + ny


def check_layout(layout: str) -> None:
    if layout not in LAYOUTS:
        raise ConfigError(f"unknown window layout '{layout}'. Fix: use one of {list(LAYOUTS)}.")


def assemble(u_past: ArrayT, y_past: ArrayT, layout: Layout) -> ArrayT:
    """Build regressors from ``u_past`` (B, nb, nu) and ``y_past`` (B, na, ny), oldest first.

    Returns (B, nb*nu + na*ny) for ``flat`` or (B, max(na, nb), nu + ny) for ``sequence``.
    Accepts NumPy arrays or torch tensors (the result has the same type).
    """
    check_layout(layout)
    batch, nb, nu = u_past.shape
    _, na, ny = y_past.shape
    if _is_torch(u_past):
        import torch

        cat, zeros = torch.cat, lambda shape: u_past.new_zeros(shape)
    else:
        cat = np.concatenate

        def zeros(shape):
            return np.zeros(shape, dtype=u_past.dtype)

    if layout == "flat":
        return cat([u_past.reshape(batch, nb * nu), y_past.reshape(batch, na * ny)], 1)
    length = max(na, nb)
    if nb < length:
        u_past = cat([zeros((batch, length - nb, nu)), u_past], 1)
    if na < length:
        y_past = cat([zeros((batch, length - na, ny)), y_past], 1)
    return cat([u_past, y_past], 2)


def _is_torch(value: object) -> bool:
    return type(value).__module__.startswith("torch")


@dataclass(frozen=True)
class Windows:
    """Regression windows of one or more recordings (all arrays share the first axis)."""

    u_past: np.ndarray  # (M, nb, nu)
    y_past: np.ndarray  # (M, na, ny)
    target: np.ndarray  # (M, ny)
    index: np.ndarray  # (M,) target sample index inside its recording
    recording: np.ndarray  # (M,) position of the source recording in the list given

    def __len__(self) -> int:
        return int(self.target.shape[0])

    def regressors(self, layout: Layout) -> np.ndarray:
        return assemble(self.u_past, self.y_past, layout)

    def take(self, rows: np.ndarray) -> Windows:
        return Windows(
            self.u_past[rows], self.y_past[rows], self.target[rows], self.index[rows],
            self.recording[rows],
        )


def make_windows(
    recordings: Recording | list[Recording], spec: WindowSpec, dtype: type = np.float32
) -> Windows:
    """Cut every recording into regression windows; windows never cross recording boundaries."""
    recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
    if not recs:
        raise DataError("no recordings to cut into windows.", fix="supply at least one recording")
    parts = []
    for position, rec in enumerate(recs):
        n_targets = rec.n_samples - spec.first_target
        if n_targets <= 0:
            raise DataError(
                f"has {rec.n_samples} samples, but the regression window needs "
                f"{spec.first_target + 1} (na={spec.na}, nb={spec.nb}, nk={spec.nk}).",
                source=f"recording '{rec.name}'",
                fix="use a longer recording or smaller data.window.na / nb / nk",
            )
        k = np.arange(spec.first_target, rec.n_samples)
        # sliding_window_view(a, w, axis=0)[i] covers a[i : i + w] (window axis last).
        u_win = sliding_window_view(rec.u, spec.nb, axis=0)  # (N-nb+1, nu, nb)
        u_past = u_win[k - spec.nk - spec.nb + 1].transpose(0, 2, 1)
        if spec.na > 0:
            y_win = sliding_window_view(rec.y, spec.na, axis=0)
            y_past = y_win[k - spec.na].transpose(0, 2, 1)
        else:
            y_past = np.zeros((len(k), 0, rec.ny))
        parts.append(
            (u_past.astype(dtype), y_past.astype(dtype), rec.y[k].astype(dtype), k,
             np.full(len(k), position))
        )
    return Windows(*(np.concatenate(p) for p in zip(*parts, strict=True)))
