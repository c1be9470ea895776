"""`DataSpec`: a ``data`` config as an object, built once where a run starts."""

from __future__ import annotations

import pytest

import hysteresis_lab as hl
from hysteresis_lab.data.factory import build_datamodule
from hysteresis_lab.data.spec import DataSpec
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.workflows.pipeline import plain_dict
from narx import narx_data


def test_a_spec_reads_the_settings_of_a_composed_data_config_and_gives_it_back():
    cfg = hl.compose("data=csv", "data.train=run.csv", "data.window.na=3", "data.batch_size=32",
                     "data.diagnose=[extra.csv]")
    spec = DataSpec.from_config(cfg.data)
    assert spec.name == "csv" and spec.window == WindowSpec(na=3, nb=10, nk=1)
    assert spec.scaling.mode == "standard" and spec.batch_size == 32
    assert spec.val_fraction == 0.1 and spec.num_workers == 0 and spec.diagnose == ("extra.csv",)
    assert spec.recording_options == {"time": "t", "inputs": ["u"], "outputs": ["y"],
                                      "units": {"u": "V", "y": "um"},
                                      "limits": {"u_abs_max": 1e9, "y_abs_max": 1e9,
                                                 "columns": {}}}
    resolved = plain_dict(cfg.data)
    assert spec.to_config() == resolved and spec.to_config()["splits"]["train"] == "run.csv"
    spec.to_config()["window"]["na"] = 99  # a copy: the spec keeps its config
    assert spec.to_config() == resolved and DataSpec.from_config(spec) is spec


def test_a_spec_without_settings_takes_the_defaults_and_the_datamodule_reads_it():
    spec = DataSpec.from_config({"window": {"na": 2, "nb": 2}, "batch_size": 16})
    assert spec.name is None and spec.recording_options == {} and spec.diagnose == ()
    datamodule = build_datamodule(spec, "flat", splits=narx_data(600))
    assert datamodule.window == WindowSpec(na=2, nb=2, nk=1) and datamodule.batch_size == 16


def test_a_malformed_window_is_refused_where_the_spec_is_built():
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['nx'\] in data.window"):
        DataSpec.from_config({"window": {"nx": 2}})
