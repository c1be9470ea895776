"""Check that command-line overrides keep the type of the packaged value they replace.

The configs are plain YAML, so OmegaConf takes ``training.lr=abc`` or ``loop.warm_start=maybe``
as strings and the mistake surfaces later as a traceback deep inside a library (or, worse, a
truthy string silently counts as ``true``). Before a command does any work, every value an
override changed is compared with the value the packaged configs give the same key (composed
with the same group choices: ``model=lstm``, ``experiment=paper`` ...): a number must stay a
number (a whole number where the packaged value is one: layer counts, epochs, lags), a switch
``true``/``false``, a list a list, a group of settings a group. Keys whose
packaged value is a string, or ``null`` (bar those in `NULLABLE_NUMBERS`), are not checked
(their type is open).

A group choice (``model=<name>``, ``data=<name>``) is checked before Hydra composes anything:
an unknown name is one line that lists the public choices (not the ``_``-prefixed internal
entries such as ``_network``) and the fix. The console apps and `hysteresis_lab.api.compose`
run the same two checks (`check_group_choices`, `check_overrides`).

Training settings moved from ``model`` to their own group (``training``); an override of
one under its old name (``model.lr=1e-4``) is rewritten to the new key before Hydra composes
(`renamed_overrides`), with one deprecation warning naming it.
"""

from __future__ import annotations

import logging
import sys
import warnings
from typing import Any

from hydra import compose
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override, OverrideType
from omegaconf import DictConfig, ListConfig, OmegaConf

from hysteresis_lab.errors import ConfigError, HysteresisLabError
from hysteresis_lab.models.settings import TRAINING_SETTINGS

log = logging.getLogger(__name__)

NUMBER = "a number"
WHOLE = "a whole number"
#: keys whose packaged value is null (off / automatic) but which take a number when set,
#: with the kind of number they take
NULLABLE_NUMBERS = {
    "n_step": WHOLE, "training.lr": NUMBER, "training.weight_decay": NUMBER,
    "training.horizon": WHOLE, "training.simulation_lr": NUMBER,
    "training.simulation_epochs": WHOLE, "training.patience": WHOLE,
    "training.refit_lr": NUMBER, "trainer.gradient_clip_val": NUMBER, "data.fs": NUMBER,
    "data.splits.train_sine_amplitude": NUMBER,
}

#: a value to show in the fix for a nullable key whose null means "the model's own"
NULLABLE_EXAMPLES = {
    "training.lr": "0.001", "training.weight_decay": "0.0", "training.horizon": "200",
    "training.simulation_epochs": "5", "training.simulation_lr": "0.0001",
    "training.patience": "10", "training.refit_lr": "0.0001",
}
#: keys whose packaged value is a number but which also take other types (Lightning's
#: ``devices`` takes "auto" or a list of device indices)
OPEN_KEYS = frozenset({"trainer.devices"})


def _kind(value: Any) -> str | None:
    """The type an override must keep, in words; None where any type goes."""
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, int):
        return WHOLE
    if isinstance(value, float):
        return NUMBER
    if isinstance(value, list | ListConfig):
        return "a list"
    if isinstance(value, dict | DictConfig):
        return "a group of settings"
    return None


def _keeps(expected: str, value: Any) -> bool:
    """Is ``value`` of the kind ``expected``? A whole number is a number too."""
    kind = _kind(value)
    return kind == expected or (expected == NUMBER and kind == WHOLE)


def _fix(key: str, reference: Any) -> str:
    if isinstance(reference, DictConfig):
        first = next(iter(reference), "name")
        return f"set one of its settings, e.g. {key}.{first}=..."
    if isinstance(reference, ListConfig):
        return f"{key}=[a,b] (brackets even for one item: {key}=[a])"
    if isinstance(reference, bool):
        return f"{key}={str(reference).lower()} (true or false)"
    return f"{key}={reference}"


def type_mismatches(cfg: DictConfig, reference: DictConfig, keys: list[str]) -> list[str]:
    """One message per key of ``keys`` whose value in ``cfg`` is not of the type its value in
    ``reference`` (the packaged config) has."""
    problems = []
    for key in keys:
        if key in OPEN_KEYS:
            continue
        packaged = OmegaConf.select(reference, key, default=None)
        value = OmegaConf.select(cfg, key, default=None)
        if packaged is None and key in NULLABLE_NUMBERS:
            expected = NULLABLE_NUMBERS[key]
            if value is not None and not _keeps(expected, value):
                example = NULLABLE_EXAMPLES.get(key, "null")
                problems.append(
                    f"{key}={value!r} must be {expected} or null. Fix: e.g. {key}={example}")
            continue
        expected = _kind(packaged)
        if expected is None or value is None or _keeps(expected, value):
            continue
        if isinstance(value, DictConfig | ListConfig):
            value = OmegaConf.to_container(value)
        problems.append(f"{key}={value!r} must be {expected}. Fix: {_fix(key, packaged)}")
    return problems


def check_override_types(cfg: DictConfig) -> None:
    """Raise `ConfigError` naming every override of the running Hydra app that changed a
    value's type. Does nothing outside a Hydra app."""
    if HydraConfig.initialized():
        check_overrides(cfg, HydraConfig.get())


def check_overrides(cfg: DictConfig, hydra_cfg: DictConfig) -> None:
    """Raise `ConfigError` naming every override that changed a value's type: the task
    overrides, group choices and search path read from ``hydra_cfg`` (the ``hydra`` node of
    the composed config: `HydraConfig` in an app, ``return_hydra_config`` in the API).
    Needs an initialised Hydra (an app, or ``initialize_config_module``)."""
    choices = {
        group: choice
        for group, choice in hydra_cfg.runtime.choices.items()
        if not group.startswith("hydra/")
    }
    parsed = OverridesParser.create().parse_overrides(list(hydra_cfg.overrides.task))
    keys = [
        o.key_or_group
        for o in parsed
        if o.type == OverrideType.CHANGE
        and o.package is None
        and o.key_or_group not in choices
        and not o.key_or_group.startswith("hydra.")
    ]
    if not keys:
        return
    selections = [
        f"{group}={choice}"
        for group, choice in choices.items()
        if choice is not None and "@" not in group
    ]
    # the search path as the command set it (experiment=best_<study> lives on it)
    search_path = [o for o in hydra_cfg.overrides.hydra if o.startswith("hydra.searchpath")]
    try:
        reference = compose(
            config_name=hydra_cfg.job.config_name, overrides=selections + search_path
        )
    except Exception as exc:  # no reference, no check: never block a run the app accepted
        log.debug("override types not checked: the packaged config did not compose (%s)", exc)
        return
    problems = type_mismatches(cfg, reference, keys)
    if problems:
        raise ConfigError("invalid override(s): " + "; ".join(problems))


def _group_choices(overrides: list[str]) -> list[Override]:
    """The overrides that may choose a config group (``key=value``, value a plain name)."""
    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except Exception:  # Hydra reports a malformed override itself
        return []
    return [
        o for o in parsed
        if o.type in (OverrideType.CHANGE, OverrideType.ADD) and o.package is None
        and "." not in o.key_or_group and not o.key_or_group.startswith("hydra")
        and isinstance(o.value(), str)
    ]


def check_group_choices(config_name: str, overrides: list[str]) -> None:
    """Raise `ConfigError` for a group choice that names no config (``model=doesnotexist``):
    one line listing the public choices and the fix. Run before composing: Hydra's own
    message lists internal entries and exits 1 with no fix."""
    choices = _group_choices(overrides)
    if not choices:
        return
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra._internal.utils import create_config_search_path

    loader = ConfigLoaderImpl(create_config_search_path("pkg://hysteresis_lab.conf"))
    search_path = [o for o in overrides if o.startswith("hydra.searchpath")]
    for override in choices:
        group, name = override.key_or_group, override.value()
        with warnings.catch_warnings():  # outputs/optuna/best is missing until a sweep ends
            warnings.simplefilter("ignore", UserWarning)
            try:
                options = loader.get_group_options(group, config_name=config_name,
                                                   overrides=search_path)
            except Exception as exc:  # no catalogue, no check: Hydra reports what it finds
                log.debug("group choice %s not checked (%s)", group, exc)
                continue
        public = [o for o in options if not o.startswith("_")]
        if not public or name in options:  # not a group (seed=1), or a known choice
            continue
        plugin = ("; a plugin's model needs its package installed (it registers its config "
                  "under the 'hysteresis_lab.configs' entry points)" if group == "model" else "")
        raise ConfigError(
            f"unknown {group} '{name}'. Valid: {', '.join(public)}. Fix: {group}=<one of "
            f"those>, e.g. {group}={public[0]}{plugin}."
        )


def renamed_overrides(overrides: list[str]) -> list[str]:
    """``overrides`` with each training setting given under its old name (``model.lr=1e-4``,
    also ``+model.lr=...``) under its new one (``training.lr=1e-4``), one deprecation
    warning per rewritten override."""
    renamed = []
    for override in overrides:
        prefix = override[: len(override) - len(override.lstrip("+~"))]
        key, sep, value = override[len(prefix):].partition("=")
        group, _, name = key.partition(".")
        if group == "model" and name in TRAINING_SETTINGS:
            new = f"training.{name}{sep}{value}"
            log.warning("model.%s is deprecated: training settings have their own group. "
                        "Fix: %s", name, new)
            override = ("~" if prefix.startswith("~") else "") + new
        renamed.append(override)
    return renamed


def rename_command_line_overrides() -> None:
    """`renamed_overrides` on a console app's command line (``sys.argv``), before Hydra
    reads it."""
    sys.argv[1:] = renamed_overrides(sys.argv[1:])


def exit_on_unknown_choice(config_name: str, argv: list[str] | None = None) -> None:
    """`check_group_choices` on a console app's command line: one logged line and exit
    status 2 (as `report_errors`) where a group choice is unknown."""
    overrides = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
    try:
        check_group_choices(config_name, overrides)
    except HysteresisLabError as exc:
        logging.getLogger("hysteresis_lab").error("%s", exc)
        sys.exit(2)
