"""Build `DatasetSplits` and DataModules from a ``data`` config node (Hydra or plain dict)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hydra.errors import InstantiationException
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.data.datamodules import WindowDataModule
from hysteresis_lab.data.scaling import ScalingSettings
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.data.windows import Layout, WindowSpec
from hysteresis_lab.errors import ConfigError, HysteresisLabError

# data.splits._target_ may name any loader in this package (Hydra 1.5 requires a whitelist).
WHITELIST = ("hysteresis_lab.*",)


def _as_dict(cfg: Mapping[str, Any] | DictConfig) -> dict[str, Any]:
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    return dict(cfg)


def build_splits(data_cfg: Mapping[str, Any] | DictConfig) -> DatasetSplits:
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


def window_spec(data_cfg: Mapping[str, Any] | DictConfig) -> WindowSpec:
    """The regression window ``data_cfg.window`` describes (checked)."""
    window = _as_dict(data_cfg).get("window", {}) or {}
    unknown = set(window) - {"na", "nb", "nk"}
    if unknown:
        raise ConfigError(
            f"unknown key(s) {sorted(unknown)} in data.window. Fix: use na, nb and nk."
        )
    return WindowSpec(**window)


def build_datamodule(
    data_cfg: Mapping[str, Any] | DictConfig,
    layout: Layout,
    seed: int = 0,
    splits: DatasetSplits | None = None,
) -> WindowDataModule:
    """A `WindowDataModule` for ``data_cfg`` in the layout the model needs."""
    cfg = _as_dict(data_cfg)
    scaling = ScalingSettings.from_config(cfg.get("scaling"))
    window = window_spec(cfg)
    return WindowDataModule(
        splits if splits is not None else build_splits(cfg),
        window=window,
        layout=layout,
        scaling=scaling.mode,
        u_scale=scaling.u_scale,
        y_scale=scaling.y_scale,
        val_fraction=cfg.get("val_fraction", 0.1),
        batch_size=cfg.get("batch_size", 128),
        seed=seed,
        num_workers=cfg.get("num_workers", 0),
    )
