"""Save and load trained models safely: torch ``weights_only`` checkpoints and skops for the SVM;
a saved model read as the baseline of another (`load_baseline`, `baseline_of`)."""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path
from typing import Any

import torch

from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError, DataError
from hysteresis_lab.models.augment import SETTING as BASELINE_SETTING
from hysteresis_lab.models.augment import Baseline
from hysteresis_lab.models.interface import SystemModel
from hysteresis_lab.models.registry import get_model_class
from hysteresis_lab.models.spec import ModelSpec
from hysteresis_lab.run_folder import RunFolder

log = logging.getLogger(__name__)

FORMAT = 1
SAFE_PREFIXES = ("sklearn.", "numpy.", "scipy.", "builtins.")


def _plain(value: Any) -> Any:
    """Hyperparameters as plain Python containers (loadable with ``weights_only=True``)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    return value


def save_model(model: SystemModel, path: Path) -> Path:
    """Write ``model`` next to ``path``: ``.ckpt`` for networks, ``.skops`` for the SVM. A
    path that cannot be written (a file where a folder should be, no permission, a full disk)
    is a `DataError` naming it and the fix."""
    path = Path(path)
    target = path.with_suffix(".ckpt" if model.is_network else ".skops")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _write(model, target)
    except OSError as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(
            f"cannot write the model file ({reason}).",
            source=str(target),
            fix="pass a path in a folder you may write to (e.g. outputs/model), not below "
            "a file or in a read-only place, and check the disk has room",
        ) from None
    return target


def _write(model: SystemModel, target: Path) -> None:
    if model.is_network:
        name = model.registry_name or type(model).__name__
        checkpoint = {
            "format": FORMAT,
            "model_name": name,
            "hyper_parameters": _plain(dict(model.hparams)),
            "state_dict": model.state_dict(),
        }
        if model.baseline is not None:  # the model reads its free run: it travels along
            checkpoint["baseline"] = model.baseline.to_checkpoint()
        try:
            torch.save(checkpoint, target)
        except RuntimeError as exc:  # how torch reports a file it cannot open
            raise OSError(str(exc)) from exc
        return
    import skops.io

    skops.io.dump(model, target)


def load_model(path: Path | str) -> SystemModel:
    """Load a model written by `save_model` (networks with ``weights_only=True``)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(
            "no checkpoint at this path.",
            source=str(path),
            fix="pass the model.ckpt / model.skops written by hysteresis-lab-train",
        )
    if path.suffix == ".skops":
        return _load_skops(path)
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # truncated, not a torch file, or unsafe content
        raise DataError(
            f"the checkpoint is corrupt or not a hysteresis_lab model ({type(exc).__name__}).",
            source=str(path),
            fix="retrain the model (hysteresis-lab-train) or copy the file again",
        ) from None
    if not isinstance(checkpoint, dict) or "model_name" not in checkpoint:
        raise DataError(
            "the file is a torch file but not a hysteresis_lab model checkpoint.",
            source=str(path),
            fix="pass the model.ckpt written by hysteresis-lab-train",
        )
    hparams = _current_names(dict(checkpoint["hyper_parameters"]))
    hparams.pop("model_name", None)
    model = get_model_class(checkpoint["model_name"])(**hparams)
    try:
        model.load_state_dict(checkpoint["state_dict"])
    except RuntimeError as exc:
        raise DataError(
            f"weights do not fit the architecture: {str(exc).splitlines()[0]}",
            source=str(path),
            fix="retrain the model",
        ) from None
    if "baseline" in checkpoint:
        model.baseline = Baseline.from_checkpoint(checkpoint["baseline"], load_model)
    return model.eval()


def _current_names(hparams: dict[str, Any]) -> dict[str, Any]:
    """Settings of checkpoints saved before the training objective was named (``rollout_*``:
    a one-step fit fine-tuned on the free-run error) under their current names."""
    steps = hparams.pop("rollout_steps", None)
    epochs = hparams.pop("rollout_epochs", None)
    lr = hparams.pop("rollout_lr", None)
    if steps:
        hparams.update(objective="simulation", horizon=int(steps), simulation_epochs=epochs,
                       simulation_lr=lr)
    return hparams


def _load_skops(path: Path) -> Any:
    import skops.io

    try:
        untrusted = skops.io.get_untrusted_types(file=path)
    except (zipfile.BadZipFile, OSError, ValueError, KeyError) as exc:
        raise DataError(
            f"the SVM file is corrupt ({type(exc).__name__}).",
            source=str(path),
            fix="retrain the model or copy the file again",
        ) from None
    ours = ("hysteresis_lab.",)
    unsafe = [t for t in untrusted if not t.startswith(SAFE_PREFIXES + ours)]
    if unsafe:
        raise DataError(
            f"the file holds types that are not known to be safe: {unsafe}.",
            source=str(path),
            fix="only load model files you created yourself",
        )
    return skops.io.load(path, trusted=untrusted)


def model_window(model: SystemModel) -> WindowSpec:
    """The regressor lags a loaded model expects."""
    return model.window


def load_baseline(path: str | Path) -> Baseline:
    """The baseline saved at ``path``: a model file or a run folder holding one."""
    path = Path(path).expanduser()
    file = RunFolder(path).model_file() if path.is_dir() else path
    if file is None or not file.is_file():
        raise ConfigError(
            f"model.baseline={str(path)!r}: no fitted model there. Fix: train the "
            "baseline first (e.g. hysteresis-lab-train model=greybox) and pass its run "
            "folder or its model.ckpt."
        )
    return Baseline.read(file, load_model)


def baseline_of(spec: ModelSpec) -> Baseline | None:
    """The baseline a ``model`` config names (None when it names none); refused for a model
    that cannot take extra input channels (the physical models: they are the baselines)."""
    path = spec.settings.get(BASELINE_SETTING)
    if not path:
        return None
    from hysteresis_lab.models.physical_chain import PhysicalChainModule

    if not spec.is_network or issubclass(spec.cls, PhysicalChainModule):
        raise ConfigError(
            f"model.baseline is for the networks (ffnn, lstm, cnn, subnet, plugins); "
            f"{spec.cls.__name__} cannot take a baseline's output as an input. Fix: make "
            "this model the baseline of a network instead (model=subnet model.baseline=<its "
            "run folder>)."
        )
    return load_baseline(str(path))
