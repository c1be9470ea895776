"""The trainer factory: every Lightning `Trainer` of the package is built by `build_trainer`
from a typed `TrainerSettings` (the ``trainer`` config, ``conf/trainer/default.yaml``), made
once where a run starts (`TrainerSettings.from_config`)."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import lightning as L
from lightning.pytorch.callbacks import TQDMProgressBar
from lightning.pytorch.callbacks.progress.tqdm_progress import Tqdm, convert_inf
from omegaconf import DictConfig, OmegaConf

#: batches between progress-bar refreshes (a refresh per batch would slow a small network down)
PROGRESS_BAR_REFRESH_BATCHES = 20


@dataclass(frozen=True)
class TrainerSettings:
    """Lightning ``Trainer`` arguments of the ``trainer`` config.

    Each field's default is Lightning's own, so a setting the config leaves out behaves as
    Lightning decides; ``extra`` carries any other ``Trainer`` argument a config adds
    (``+trainer.num_sanity_val_steps=0``), passed on unchecked (Lightning refuses unknown
    ones, see `hysteresis_lab.fitting.check_trainer_settings`). ``configured``: the fields
    the config set (all of them for settings made in code), so that `to_config` gives back
    the config itself, which fit records fingerprint (`hysteresis_lab.fit_record`).
    """

    max_epochs: int | None = None
    accelerator: str = "auto"
    devices: int | str | list[int] = "auto"
    precision: int | str | None = None
    log_every_n_steps: int | None = None
    #: not False: a progress bar refreshed every `PROGRESS_BAR_REFRESH_BATCHES` batches
    enable_progress_bar: bool | None = None
    enable_model_summary: bool | None = None
    deterministic: bool | str | None = None
    gradient_clip_val: float | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    configured: frozenset[str] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.configured is None:
            object.__setattr__(self, "configured", frozenset(_field_names()))

    @classmethod
    def from_config(
        cls, cfg: Mapping[str, Any] | DictConfig | TrainerSettings
    ) -> TrainerSettings:
        """Settings from a ``trainer`` config node (resolved when a Hydra node); settings
        pass through."""
        if isinstance(cfg, TrainerSettings):
            return cfg
        if isinstance(cfg, DictConfig):
            cfg = OmegaConf.to_container(cfg, resolve=True)  # type: ignore[assignment]
        names = _field_names()
        known = {str(k): v for k, v in cfg.items() if k in names}
        extra = {str(k): v for k, v in cfg.items() if k not in names}
        return cls(**known, extra=extra, configured=frozenset(known))

    def to_config(self) -> dict[str, Any]:
        """The ``trainer`` config these settings came from: the fields it set and ``extra``
        (what a fit record fingerprints; `from_config` of it gives these settings back)."""
        values = {name: getattr(self, name) for name in sorted(self.configured or ())}
        return copy.deepcopy({**values, **self.extra})

    def with_changes(self, **changes: Any) -> TrainerSettings:
        """A copy with ``changes`` (set in its config, too); names that are not fields go to
        ``extra``."""
        names = _field_names()
        extra = {**self.extra, **{k: v for k, v in changes.items() if k not in names}}
        known = {k: v for k, v in changes.items() if k in names}
        configured = frozenset(self.configured or ()) | frozenset(known)
        return dataclasses.replace(self, **known, extra=extra, configured=configured)

    def evaluation_device(self) -> str:
        """The device free-run simulation uses: the GPU when training may use one and it
        exists."""
        import torch

        if str(self.accelerator) in {"auto", "gpu", "cuda"} and torch.cuda.is_available():
            return "cuda"
        return "cpu"

    @property
    def shows_progress(self) -> bool:
        """Whether a run shows progress bars (training's and scoring's): unless these
        settings turn Lightning's off."""
        return self.enable_progress_bar is not False

    def trainer_arguments(self) -> dict[str, Any]:
        """The keyword arguments of ``lightning.Trainer``."""
        values = {name: getattr(self, name) for name in _field_names()}
        return {**values, **self.extra}


class EpochProgressBar(TQDMProgressBar):
    """Lightning's progress bar as one line per fit: the epochs (``Epoch k/N``, ``Free-run
    epoch k/N`` on the free-run error) with the
    losses; no separate bars for the sanity check and the validation passes (the fits here
    validate only to measure a loss), no logger version among the losses."""

    def init_sanity_tqdm(self) -> Tqdm:
        return Tqdm(disable=True)

    def init_validation_tqdm(self) -> Tqdm:
        return Tqdm(disable=True)  # the validation loss shows on the epoch bar

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        bar = self.train_progress_bar
        total = f"/{trainer.max_epochs}" if trainer.max_epochs and trainer.max_epochs > 0 else ""
        stage = "Free-run epoch" if getattr(pl_module, "simulation_mode", False) else "Epoch"
        bar.set_description(f"{stage} {trainer.current_epoch + 1}{total}", refresh=False)
        bar.reset(total=convert_inf(self.total_train_batches))

    def get_metrics(self, trainer: L.Trainer, pl_module: L.LightningModule) -> dict[str, Any]:
        metrics = super().get_metrics(trainer, pl_module)
        metrics.pop("v_num", None)
        return metrics


def _field_names() -> set[str]:
    return {f.name for f in dataclasses.fields(TrainerSettings)} - {"extra", "configured"}


def build_trainer(
    settings: TrainerSettings,
    callbacks: Sequence[L.Callback] = (),
    module: L.LightningModule | None = None,
    **overrides: Any,
) -> L.Trainer:
    """A Lightning ``Trainer`` from ``settings`` (for ``module``: see `_clipping_in_module`);
    ``overrides`` (one stage's logger, checkpointing, root folder) win over them. Its
    progress bar, when enabled, refreshes every `PROGRESS_BAR_REFRESH_BATCHES` batches and
    shows the epochs only (`EpochProgressBar`)."""
    if module is not None:
        settings = _clipping_in_module(module, settings)
    arguments = {**settings.trainer_arguments(), **overrides}
    all_callbacks = list(callbacks)
    if arguments.get("enable_progress_bar") is not False:
        all_callbacks.append(EpochProgressBar(refresh_rate=PROGRESS_BAR_REFRESH_BATCHES))
    return L.Trainer(**arguments, callbacks=all_callbacks)


def _clipping_in_module(module: L.LightningModule, settings: TrainerSettings) -> TrainerSettings:
    """Under manual optimisation (`NarxModule`) the module clips the gradients and the
    Trainer must not: hand ``gradient_clip_val`` (and ``gradient_clip_algorithm``) over."""
    if module.automatic_optimization:
        return settings
    extra = dict(settings.extra)
    algorithm = extra.pop("gradient_clip_algorithm", None)
    value = settings.gradient_clip_val
    module.gradient_clipping = (float(value), algorithm) if value else None
    return dataclasses.replace(settings, gradient_clip_val=None, extra=extra)
