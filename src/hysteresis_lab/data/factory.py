"""Build `DatasetSplits` from a ``data`` config (a Hydra node, a plain dict or its `DataSpec`)
and DataModules from a `DataSpec`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hydra.errors import InstantiationException
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.spec import DataSpec, window_spec
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import Layout
from hysteresis_lab.errors import ConfigError, HysteresisLabError

__all__ = ["WHITELIST", "build_datamodule", "build_splits", "window_spec"]

# data.splits._target_ may name any loader in this package (Hydra 1.5 requires a whitelist).
WHITELIST = ("hysteresis_lab.*",)


def _as_dict(cfg: Mapping[str, Any] | DictConfig | DataSpec) -> dict[str, Any]:
    if isinstance(cfg, DataSpec):
        return cfg.to_config()
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    return dict(cfg)


def build_splits(data_cfg: Mapping[str, Any] | DictConfig | DataSpec) -> DatasetSplits:
    """Load the data set that ``data_cfg.splits`` (a ``_target_`` node) describes."""
    cfg = _as_dict(data_cfg)
    splits_cfg = cfg.get("splits")
    if not isinstance(splits_cfg, Mapping) or "_target_" not in splits_cfg:
        raise ConfigError(
            f"data config '{cfg.get('name', '?')}' has no 'splits._target_'. Fix: choose a data "
            "config such as data=default, data=csv or data=fsm, or add a splits node."
        )
    try:
        splits = instantiate(splits_cfg, _convert_="all", _execution_whitelist_=WHITELIST)
    except InstantiationException as exc:
        cause = exc.__cause__
        if isinstance(cause, HysteresisLabError):
            raise cause from None
        raise ConfigError(f"could not load data '{cfg.get('name', '?')}': {exc}") from None
    if not isinstance(splits, DatasetSplits):
        raise ConfigError(
            f"data.splits._target_ returned {type(splits).__name__}, not DatasetSplits."
        )
    return splits


def build_datamodule(
    data: DataSpec,
    layout: Layout,
    seed: int = 0,
    splits: DatasetSplits | None = None,
) -> WindowDataModule:
    """A `WindowDataModule` for the data set ``data`` (``splits`` when given, else loaded)
    in the layout the model needs."""
    scaling = data.scaling
    return WindowDataModule(
        splits if splits is not None else build_splits(data),
        window=data.window,
        layout=layout,
        scaling=scaling.mode,
        u_scale=scaling.u_scale,
        y_scale=scaling.y_scale,
        val_fraction=data.val_fraction,
        batch_size=data.batch_size,
        seed=seed,
        num_workers=data.num_workers,
    )
