"""The extra input channels a model reads beside its measured inputs (data augmentation).

Two kinds, appended in this order to the measured inputs ``u``:

* the operators of the effects the model declares (``model.effects``), computed from ``u``
  alone with settings fixed from the training recordings (`feature_context`, saved with the
  model: `context_to_dict`);
* the free run of a fitted baseline model (``model.baseline=<run folder or model file>``,
  `Baseline`), one channel per output. A physical model that extrapolates (the grey-box's
  Bouc–Wen cell, the linear model with its catalogue effects) then carries what the
  identification data barely show, and the network learns what the physics lacks (the
  physics-guided networks of Bolderman et al., IEEE TCST 2024, and the model augmentation of
  Hoekstra et al., 2024). SUBNET's linear start then fits a linear model of the inputs and the
  baseline's output: training begins near the baseline. The baseline's file travels inside
  the network's saved model (`Baseline.to_checkpoint`), so a loaded model recomputes its
  baseline channels on any recording without the original run folder.

`for_model` gives recordings both kinds, as a loaded model reads them. Reading a baseline's
model file is `hysteresis_lab.models.io`'s (`load_baseline`, `baseline_of`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import get_effect
from hysteresis_lab.errors import DataError
from hysteresis_lab.models.interface import SystemModel

log = logging.getLogger(__name__)

#: the ``model`` config key naming the baseline
SETTING = "baseline"
#: prefix of the input channels the baseline adds
CHANNEL_PREFIX = "baseline_"
#: reads a model file (`hysteresis_lab.models.io.load_model`, which imports this module)
ModelLoader = Callable[[Path], SystemModel]


def input_peaks(recordings: Sequence[Recording]) -> np.ndarray:
    """Each input channel's peak ``max |u|`` over ``recordings`` (1 where it is 0)."""
    peaks = np.max([np.max(np.abs(r.u), axis=0) for r in recordings], axis=0)
    return np.where(peaks > 0, peaks, 1.0)


def feature_context(recordings: Sequence[Recording]) -> FeatureContext:
    """Operator settings fixed from the training recordings (saved with the model)."""
    return FeatureContext(
        fs=recordings[0].fs,
        u_amplitude=input_peaks(recordings),
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


@dataclass(frozen=True)
class ModelData:
    """A data set as a model reads it: ``measured`` (as recorded), ``inputs`` (the same with
    the model's extra input channels, what it trains and is scored on), the effects'
    operator ``context`` fixed from the training recordings, the ``effects`` whose operators
    are inputs, and the ``baseline`` whose free run is an input (None: none)."""

    measured: DatasetSplits
    inputs: DatasetSplits
    context: FeatureContext
    effects: tuple[str, ...] = ()
    baseline: Baseline | None = None

    @classmethod
    def of(
        cls, measured: DatasetSplits, effects: Sequence[str], baseline: Baseline | None = None,
        settings: dict[str, Any] | None = None,
    ) -> ModelData:
        """``measured`` for a model declaring ``effects`` (and reading ``baseline``); with
        the model's config ``settings``, a warning for each effect the training data cannot
        show (`warn_unshown`)."""
        context = feature_context(measured.train)
        if settings is not None:
            warn_unshown(effects, context, settings)
        return cls(measured, measured, context, baseline=baseline).with_effects(effects)

    def with_effects(self, effects: Sequence[str]) -> ModelData:
        """The same measured data for a model declaring ``effects`` (a growth stage)."""
        inputs, _ = augment_splits(self.measured, effects, self.context)
        if self.baseline is not None:
            inputs = self.baseline.append_to_splits(inputs, self.measured)
        return dataclasses.replace(self, inputs=inputs, effects=tuple(effects))

    def derived_settings(self) -> dict[str, Any]:
        """The model parameters that come from this data (`trained_on`, and for extra
        input channels the effects' ``feature_context``, ``n_base_inputs`` and the
        ``baseline_channels``, one per output)."""
        inputs = self.inputs
        derived: dict[str, Any] = {"trained_on": trained_on(inputs)}
        if self.effects:
            derived.update(feature_context=context_to_dict(self.context),
                           n_base_inputs=inputs.metadata["n_base_inputs"])
        if self.baseline is not None:  # its free run: the last channels, one per output
            derived.update(n_base_inputs=inputs.metadata["n_base_inputs"],
                           baseline_channels=inputs.ny)
        return derived


def trained_on(data: DatasetSplits) -> dict[str, Any]:
    """What a model keeps of its training data to refuse data it cannot score: the sampling
    rate (its lags span a fixed number of samples) and the physical units (its scaler works
    in them); and whether every recording starts from one shared unknown state, with the
    longest training recording's length for the burn-in to it, and whether the output
    integrates (only where the data set says so, so other models keep the settings they
    had); and each input's peak ``u_amplitude`` (what the training data swept)."""
    shared = {"shared_initial_state": True,
              "burn_in_samples": max(r.n_samples for r in data.train)} \
        if data.shared_initial_state else {}
    integrates = {"output_integrates": True} if data.output_integrates else {}
    return {"fs": data.fs, **{f"{k}_units": v for k, v in data.units.items()}, **shared,
            **integrates, "u_amplitude": input_peaks(data.train).tolist()}


def for_model(model: Any, recordings: Sequence[Recording]) -> list[Recording]:
    """Recordings with the extra input channels that a loaded ``model`` reads: its effects'
    operators, then its baseline's free run (`Baseline`)."""
    effects = list(model.hparams.get("effects") or [])
    augmented = list(recordings)
    if effects:
        ctx = context_from_dict(model.hparams["feature_context"])
        augmented = [augment(r, effects, ctx) for r in recordings]
    if model.baseline is not None:  # `ModelContract.baseline`
        augmented = model.baseline.append_to(augmented, recordings)
    return augmented


@dataclass
class Baseline:
    """A fitted model whose free run becomes extra input channels of another model.

    ``payload``: the bytes of its model file (``suffix`` ``.ckpt`` or ``.skops``);
    ``source``: where it was read from (for messages and reports).
    """

    model: SystemModel
    payload: bytes
    suffix: str
    source: str

    @classmethod
    def read(cls, file: Path, load_model: ModelLoader) -> Baseline:
        """The fitted model saved in ``file`` (read by ``load_model``) as a baseline."""
        return cls(load_model(file), file.read_bytes(), file.suffix, str(file))

    @classmethod
    def from_checkpoint(cls, entry: Mapping[str, Any], load_model: ModelLoader) -> Baseline:
        """The baseline stored by `to_checkpoint` inside another model's checkpoint (its model
        file read by ``load_model``)."""
        payload = entry["data"].numpy().tobytes()
        suffix = str(entry["suffix"])
        with tempfile.TemporaryDirectory() as folder:
            file = Path(folder) / f"baseline{suffix}"
            file.write_bytes(payload)
            model = load_model(file)
        return cls(model, payload, suffix, str(entry.get("source", "")))

    def to_checkpoint(self) -> dict[str, Any]:
        """Plain entries (loadable with ``weights_only=True``) that `from_checkpoint` reads."""
        data = torch.frombuffer(bytearray(self.payload), dtype=torch.uint8).clone()
        return {"data": data, "suffix": self.suffix, "source": self.source}

    @property
    def digest(self) -> str:
        """SHA-256 of the baseline's file: a finished fit is reused only with the same one."""
        return hashlib.sha256(self.payload).hexdigest()

    @property
    def n_inputs(self) -> int:
        """The measured inputs the baseline reads."""
        hparams = getattr(self.model, "hparams", {}) or {}
        return int(hparams.get("n_base_inputs") or hparams.get("nu") or self.model.nu)

    def channels_for(self, recordings: Sequence[Recording]) -> list[np.ndarray]:
        """The baseline's free run (T, ny) on each recording (its measured inputs only)."""
        from hysteresis_lab.evaluation.predict import free_run

        if not recordings:
            return []
        for rec in recordings:
            if rec.nu != self.n_inputs:
                raise DataError(
                    f"has {rec.nu} measured input(s); the baseline {self.source} reads "
                    f"{self.n_inputs}.",
                    source=f"recording '{rec.name}'",
                    fix="use a baseline fitted on the same inputs as this data set",
                )
        runs = free_run(self.model, for_model(self.model, recordings), self.model.window)
        for rec, y in zip(recordings, runs, strict=True):
            if not np.all(np.isfinite(y)):
                raise DataError(
                    f"the baseline {self.source} diverges in free run on it.",
                    source=f"recording '{rec.name}'",
                    fix="refit the baseline (a stable model) or leave model.baseline unset",
                )
        return runs

    def append_to(
        self, recordings: Sequence[Recording], measured: Sequence[Recording]
    ) -> list[Recording]:
        """``recordings`` with the baseline's free run of each ``measured`` recording (the
        same recordings before any other channel was added) as extra input channels."""
        runs = self.channels_for(measured)
        return [
            dataclasses.replace(
                rec, u=np.column_stack([rec.u, y]),
                u_names=(*rec.u_names, *(f"{CHANNEL_PREFIX}{name}" for name in rec.y_names)),
            )
            for rec, y in zip(recordings, runs, strict=True)
        ]

    def append_to_splits(self, data: DatasetSplits, measured: DatasetSplits) -> DatasetSplits:
        """Every recording of ``data`` with its baseline channels (see `append_to`)."""
        log.info("baseline %s: its free run is an input of the model", self.source)
        return dataclasses.replace(
            data,
            train=self.append_to(data.train, measured.train),
            val=self.append_to(data.val, measured.val),
            test=self.append_to(data.test, measured.test),
            metadata={"n_base_inputs": measured.nu, **data.metadata, SETTING: self.source},
        )

