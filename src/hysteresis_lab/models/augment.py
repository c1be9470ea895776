"""Give recordings the extra input channels of declared effects (computed from ``u`` alone)."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import DataError

log = logging.getLogger(__name__)


def feature_context(recordings: Sequence[Recording]) -> FeatureContext:
    """Operator settings fixed from the training recordings (saved with the model)."""
    u_amplitude = np.max([np.max(np.abs(r.u), axis=0) for r in recordings], axis=0)
    return FeatureContext(
        fs=recordings[0].fs,
        u_amplitude=np.where(u_amplitude > 0, u_amplitude, 1.0),
        duration_s=max(r.duration for r in recordings),
        y_low=np.min([np.min(r.y, axis=0) for r in recordings], axis=0),
        y_high=np.max([np.max(r.y, axis=0) for r in recordings], axis=0),
        dy_low=np.min([_steps(r.y).min(axis=0) for r in recordings], axis=0),
        dy_high=np.max([_steps(r.y).max(axis=0) for r in recordings], axis=0),
    )


def warn_unshown(
    effects: Sequence[str], ctx: FeatureContext, settings: dict[str, Any] | None = None
) -> list[str]:
    """Log a warning for each declared effect the training data of ``ctx`` cannot show
    (`Effect.unshown`: creep's slow filters on a short record; ``settings``: the model's
    config); return the lines."""
    lines = [line for name in effects if (line := get_effect(name).unshown(ctx, settings))]
    for line in lines:
        log.warning(line)
    return lines


def _steps(y: np.ndarray) -> np.ndarray:
    """The output's steps from one sample to the next, (T - 1, ny) (a row of zeros for a
    recording of one sample)."""
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    return np.diff(y, axis=0) if len(y) > 1 else np.zeros_like(y)


def context_to_dict(ctx: FeatureContext) -> dict[str, Any]:
    values = {
        "fs": ctx.fs,
        "u_amplitude": np.asarray(ctx.u_amplitude).tolist(),
        "duration_s": ctx.duration_s,
    }
    if ctx.y_low is not None and ctx.y_high is not None:
        values.update(y_low=np.asarray(ctx.y_low).tolist(), y_high=np.asarray(ctx.y_high).tolist())
    if ctx.dy_low is not None and ctx.dy_high is not None:
        values.update(dy_low=np.asarray(ctx.dy_low).tolist(),
                      dy_high=np.asarray(ctx.dy_high).tolist())
    return values


def context_from_dict(values: dict[str, Any]) -> FeatureContext:
    def optional(key: str) -> np.ndarray | None:
        return np.asarray(values[key], dtype=float) if values.get(key) is not None else None

    return FeatureContext(
        float(values["fs"]),
        np.asarray(values["u_amplitude"], dtype=float),
        float(values["duration_s"]),
        optional("y_low"),
        optional("y_high"),
        optional("dy_low"),
        optional("dy_high"),
    )


def augment(
    rec: Recording, effects: Sequence[str], ctx: FeatureContext, n_base_inputs: int | None = None
) -> Recording:
    """``rec`` with each effect's operators of its first ``n_base_inputs`` inputs appended."""
    if not effects:
        return rec
    n_base = rec.nu if n_base_inputs is None else n_base_inputs
    if rec.nu != n_base:
        raise DataError(
            f"has {rec.nu} inputs; the model's effects expect {n_base} measured ones.",
            source=f"recording '{rec.name}'",
            fix="give the recordings the inputs the model was trained on",
        )
    if not np.isclose(rec.fs, ctx.fs):
        raise DataError(
            f"is sampled at {rec.fs:g} Hz but the model's effect operators were "
            f"built for {ctx.fs:g} Hz.",
            source=f"recording '{rec.name}'",
            fix="resample the recording to the training rate",
        )
    columns, names = [rec.u], list(rec.u_names)
    for name in effects:
        features = get_effect(name).features(rec.u, ctx)
        columns.append(features)
        names += [f"{name}_{j}" for j in range(features.shape[1])]
    return dataclasses.replace(rec, u=np.column_stack(columns), u_names=tuple(names))


def augment_splits(
    splits: DatasetSplits, effects: Sequence[str], ctx: FeatureContext | None = None
) -> tuple[DatasetSplits, FeatureContext]:
    """Every recording of ``splits`` augmented; the context comes from the training set."""
    ctx = ctx or feature_context(splits.train)
    if not effects:
        return splits, ctx

    def each(recs: list[Recording]) -> list[Recording]:
        return [augment(r, effects, ctx) for r in recs]

    metadata = {**splits.metadata, "n_base_inputs": splits.nu, "effects": list(effects)}
    return dataclasses.replace(
        splits,
        train=each(splits.train),
        val=each(splits.val),
        test=each(splits.test),
        metadata=metadata,
    ), ctx


def for_model(model: Any, recordings: Sequence[Recording]) -> list[Recording]:
    """Recordings with the extra input channels that a loaded ``model`` reads: its effects'
    operators, then its baseline's free run (`hysteresis_lab.models.baseline`)."""
    effects = list(model.hparams.get("effects") or [])
    augmented = list(recordings)
    if effects:
        ctx = context_from_dict(model.hparams["feature_context"])
        augmented = [augment(r, effects, ctx) for r in recordings]
    baseline = getattr(model, "baseline", None)
    if baseline is not None:
        augmented = baseline.append_to(augmented, recordings)
    return augmented
