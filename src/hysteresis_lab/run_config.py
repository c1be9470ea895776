"""One run as objects: its configs (`RunConfig`, with its `RunSettings`), made once where the
run starts and handed down as they are, and what it produced (`RunResult`).

`hysteresis_lab.workflows.pipeline.run_model` runs a `RunConfig`; the fit
(`hysteresis_lab.fitting.fit_run`), a grown model's stages (`hysteresis_lab.workflows.grow`)
and the scoring (`hysteresis_lab.workflows.run_report`) read it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.evaluation.evaluate import Evaluation, Scoring
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.models.interface import SystemModel
from hysteresis_lab.models.settings import TrainingSettings
from hysteresis_lab.models.spec import ModelSpec


@dataclass
class RunResult:
    """What one trained model produced: its metrics document and validation MSE."""

    document: dict[str, Any]
    val_mse: float
    evaluation: Evaluation
    model: SystemModel
    window: WindowSpec
    improved: bool = True  # False: a warm-started refit kept its start (see fitting.fit)
    #: a warm-started refit's validation loss: {"start": x, "refit": x}
    refit_validation: dict[str, float] | None = None
    #: the metrics document of a refit that lost to its start (what it would have done)
    rejected_refit: dict[str, Any] | None = None


def plain_dict(cfg: Mapping[str, Any] | DictConfig) -> dict[str, Any]:
    """A resolved plain dict of a Hydra config node (or a copy of a mapping)."""
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    return dict(cfg)


@dataclass(frozen=True)
class RunSettings:
    """How one run trains and what it writes, beyond the model, data and trainer configs.

    ``refit``: with a warm start, ``"new_inputs"`` trains only the new input channels' weights
    (`NarxModule.train_new_inputs_only`), ``"full"`` every weight; the start is kept unless
    the refit beats it on validation by more than the share ``min_refit_gain``. ``reuse``: a
    fit that finished in the output folder with the same settings, data and start
    (`hysteresis_lab.fit_record`) is loaded and scored instead of trained. ``resume``: a
    network fit interrupted in the output folder with the same settings, data and start goes
    on from its last checkpoints (`RunFolder.FIT_IN_PROGRESS`); one with other settings is
    refused; without ``resume`` it starts afresh. ``keep_last``: a network trains every
    epoch of each stage and keeps its last weights (`hysteresis_lab.fitting.fit`).
    """

    seed: int = 0
    use_tensorboard: bool = True
    n_steps: int | None = None
    plots: bool = True
    evaluate: bool = True
    refit: str = "full"
    min_refit_gain: float = 0.0
    reuse: bool = False
    resume: bool = True
    initial_state: str = "rest"
    keep_last: bool = False


@dataclass(frozen=True)
class RunConfig:
    """One run, its configs as objects: the ``model`` (a `ModelSpec`), ``data`` (a
    `DataSpec`), ``trainer`` (`TrainerSettings`) and ``training`` (`TrainingSettings`, how a
    network trains), where it writes, and its `RunSettings`. Made once where a run starts
    (`RunConfig.build` from config mappings, `RunConfig.from_config` from a composed
    ``train`` config) and passed on as it is."""

    model: ModelSpec
    data: DataSpec
    trainer: TrainerSettings
    output_dir: Path
    settings: RunSettings = RunSettings()
    #: None: the model's own (`ModelSpec.training_settings`)
    training: TrainingSettings = None  # type: ignore[assignment]
    #: how the run scores its model: the ``n_step`` and ``evaluation`` settings, simulated on
    #: the trainer's device, with its progress bars
    scoring: Scoring = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        if self.training is None:
            object.__setattr__(self, "training", self.model.training_settings())
        settings, trainer = self.settings, self.trainer
        object.__setattr__(self, "scoring", Scoring(
            settings.n_steps, settings.initial_state, trainer.evaluation_device(),
            trainer.shows_progress))

    @classmethod
    def build(
        cls,
        model: Mapping[str, Any] | ModelSpec,
        data: Mapping[str, Any] | DataSpec,
        trainer: Mapping[str, Any] | TrainerSettings,
        output_dir: Path | str,
        training: Mapping[str, Any] | TrainingSettings | None = None,
        **settings: Any,
    ) -> RunConfig:
        """A run of ``model`` on ``data``: each config turned into its object here, once
        (objects pass as they are); ``training``: the ``training`` config (its unset values:
        the model's own defaults) or settings; ``settings``: `RunSettings` by name."""
        spec = model if isinstance(model, ModelSpec) else ModelSpec.from_config(plain_dict(model))
        if not isinstance(training, TrainingSettings):
            training = spec.training_settings(plain_dict(training or {}))
        return cls(spec, DataSpec.from_config(data), TrainerSettings.from_config(trainer),
                   Path(output_dir), RunSettings(**settings), training)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], output_dir: Path) -> RunConfig:
        """The run of a composed ``train`` config (``model``, ``data``, ``trainer``,
        ``training``, ``seed``, ``logger``, ``n_step``, ``plots``, ``evaluate``)."""
        return cls.build(
            cfg["model"], cfg["data"], cfg["trainer"], output_dir, cfg.get("training"),
            seed=cfg["seed"],
            use_tensorboard=bool(cfg["logger"].get("enabled", True)),
            n_steps=cfg.get("n_step"),
            plots=cfg["plots"],
            evaluate=cfg.get("evaluate", True),
            initial_state=str((cfg.get("evaluation") or {}).get("initial_state", "rest")),
            # a sweep's trial starts afresh: a resumed sweep hands its folder (runs/<job>) to
            # another trial, whose interrupted predecessor it must not continue
            resume=(cfg.get("sweep_trial") or {}).get("number") is None,
        )

    @property
    def model_name(self) -> str:
        return self.model.name

    def for_stage(self, settings: Mapping[str, Any], training: TrainingSettings,
                  output_dir: Path, refit: str) -> RunConfig:
        """This run with the model ``settings``, ``training`` settings, folder and refit mode
        of one of its stages (`hysteresis_lab.workflows.grow`)."""
        return dataclasses.replace(
            self, model=self.model.with_settings(settings), training=training,
            output_dir=output_dir, settings=dataclasses.replace(self.settings, refit=refit))
