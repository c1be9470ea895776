"""Data sets register like models: a real plugin distribution (a ``*.dist-info`` with
``entry_points.txt`` on ``sys.path``, no mocks) adds a data set that ``load_benchmark``,
``data=<name>``, the CLI and the accuracy table all find; a broken one disables only itself."""

from __future__ import annotations

import json
import logging
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import run_app
from hysteresis_lab import plugins
from hysteresis_lab.api import compose, load_data
from hysteresis_lab.data.benchmarks import available_benchmarks, load_benchmark
from hysteresis_lab.data.registry import GROUP, available_datasets, get_dataset
from hysteresis_lab.errors import DataError
from hysteresis_lab.evaluation.accuracy_table import (
    cell_from_metrics,
    scored_rows,
    table_datasets,
    write_results,
)

MODULE = "tiny_data_plug"
#: the plugin's module: a loader of a first-order system's step-sine data, and its config
PLUGIN_SOURCE = '''
import numpy as np
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.registry import Dataset
from hysteresis_lab.data.splits import DatasetSplits

FS = 200.0


def _recording(freq, gain, name):
    t = np.arange(800) / FS
    u = np.sin(2 * np.pi * freq * t) + 0.3 * np.sign(np.sin(2 * np.pi * 0.7 * t))
    y = np.zeros_like(u)
    for k in range(1, len(u)):
        y[k] = 0.9 * y[k - 1] + 0.1 * gain * u[k - 1]
    return Recording(u=u, y=y, fs=FS, name=name, u_units="V", y_units="um")


def load_tiny(root=None, gain=1.0):
    return DatasetSplits(
        "tiny",
        train=[_recording(1.0, gain, "tiny_train")],
        test=[_recording(f, gain, f"tiny_{g}_{f:g}") for g in ("low", "high") for f in (0.5, 3.0)],
        metadata={"reference": {"published": 0.5}, "reference_units": "um"},
    )


TINY = Dataset(load_tiny, title="Tiny plugin data (data=tiny)",
               test_groups={"low": "tiny_low_", "high": "tiny_high_"})
'''
#: conf/data/tiny.yaml of the plugin: the registry's loader through load_benchmark
PLUGIN_CONFIG = """defaults:
  - _window
  - _self_

name: tiny
scaling:
  mode: standard
splits:
  _target_: hysteresis_lab.data.benchmarks.load_benchmark
  name: tiny
  gain: 2.0
"""


def install(root: Path, package: str, entries: dict[str, dict[str, str]]) -> Path:
    """A distribution ``package`` in ``root`` registering ``entries`` (group -> name -> value)."""
    dist = root / f"{package.replace('-', '_')}-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package}\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("\n".join(
        f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in names.items())
        for group, names in entries.items()))
    return root


@pytest.fixture
def tiny_plugin(tmp_path, monkeypatch) -> Path:
    """The ``tiny-data`` plugin: a loader module and its data config, on ``sys.path``."""
    root = tmp_path / "site"
    package = root / MODULE
    (package / "conf" / "data").mkdir(parents=True)
    (package / "__init__.py").write_text(PLUGIN_SOURCE)
    (package / "conf" / "__init__.py").write_text("")
    (package / "conf" / "data" / "tiny.yaml").write_text(PLUGIN_CONFIG)
    install(root, "tiny-data", {GROUP: {"tiny": f"{MODULE}:TINY"},
                                "hysteresis_lab.configs": {"tiny_data": f"{MODULE}.conf"}})
    monkeypatch.syspath_prepend(str(root))
    yield root
    for name in [m for m in sys.modules if m.startswith(MODULE)]:
        del sys.modules[name]  # the next test's plugin is another folder


@pytest.fixture
def broken(tmp_path, monkeypatch) -> Path:
    """A distribution ``broken-data`` whose data-set module raises on import."""
    root = tmp_path / "broken"
    root.mkdir()
    (root / "broken_data_plug.py").write_text('raise ImportError("broken on purpose")\n')
    install(root, "broken-data", {GROUP: {"wobble": "broken_data_plug:WOBBLE"}})
    monkeypatch.syspath_prepend(str(root))
    monkeypatch.setattr(plugins, "_WARNED", set())  # this test sees its own first warning
    return root


def test_the_bundled_data_sets_are_registered_entry_points():
    assert available_datasets() == available_benchmarks() == [
        "bouc_wen", "cascaded_tanks", "emps", "fsm_piezo_mirror", "piezo_p885"]
    assert get_dataset("fsm_piezo_mirror").config_name("fsm_piezo_mirror") == "fsm"
    assert get_dataset("emps").config_name("emps") == "emps"
    # the accuracy table's data sets are the simulator and the registry's, by data= name
    assert table_datasets() == ["default", "bouc_wen", "cascaded_tanks", "emps", "fsm", "p885"]


def test_an_unknown_name_is_one_line_listing_the_registered_ones():
    with pytest.raises(DataError) as info:
        load_benchmark("silverbox")
    message = str(info.value)
    assert "\n" not in message
    assert "unknown dataset 'silverbox'" in message and "Fix: " in message
    for name in available_datasets():
        assert f"'{name}'" in message


def test_a_plugin_data_set_loads_by_name_and_by_its_data_config(tiny_plugin):
    assert "tiny" in available_datasets() and "tiny" in available_benchmarks()
    direct = load_benchmark("tiny", gain=2.0)
    assert [r.name for r in direct.test] == ["tiny_low_0.5", "tiny_low_3", "tiny_high_0.5",
                                             "tiny_high_3"]
    cfg = compose("data=tiny")
    assert cfg.data.name == "tiny" and cfg.data.splits.gain == 2.0
    splits = load_data(cfg)
    for a, b in zip(splits.train + splits.test, direct.train + direct.test, strict=True):
        assert np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y)
    # the config's option reached the loader: twice the default gain
    plain = load_benchmark("tiny")
    assert np.allclose(splits.train[0].y, 2.0 * plain.train[0].y)
    assert not np.allclose(plain.train[0].y, 0.0)


def test_a_plugin_data_set_joins_the_accuracy_table(tiny_plugin, tmp_path):
    assert table_datasets()[-1] == "tiny"
    metrics = {"tests": {f"tiny_{g}_{f}": {"rmse_free_run": v, "rmse_one_step": v / 10}
                         for g, v in (("low", 0.2), ("high", 0.4)) for f in ("0.5", "3")},
               "units": {"y": "um"}, "train_seconds": 5.0}
    path = tmp_path / "run" / "metrics.json"
    path.parent.mkdir()
    path.write_text(json.dumps(metrics))
    assert [r["test"] for r in scored_rows("tiny", metrics)] == ["low", "high"]
    _, md = write_results([cell_from_metrics("ffnn", "tiny", path, [], commit="c", date="d")],
                          {"command": "x", "commit": "c", "date": "d"}, tmp_path / "results")
    page = md.read_text()
    assert "## Tiny plugin data (data=tiny)" in page and "published [um]" in page
    assert "| ffnn | low | 0.2 | 0.02 | 0.5 |" in page


@pytest.mark.slow
def test_a_plugin_data_set_trains_through_the_cli(tiny_plugin, tmp_path):
    env = {"PYTHONPATH": os.pathsep.join([str(tiny_plugin), os.environ.get("PYTHONPATH", "")])}
    proc = run_app("train", "data=tiny", "model=ffnn", "trainer.max_epochs=1",
                   "trainer.enable_progress_bar=false", "logger=none", "plots=false",
                   f"hydra.run.dir={tmp_path}/run", env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["data"] == "tiny"
    assert list(metrics["tests"]) == [r.name for r in load_benchmark("tiny").test]


def test_a_broken_data_set_plugin_is_left_out_with_one_warning(broken, caplog):
    with caplog.at_level(logging.WARNING):
        names = available_datasets()
        assert available_datasets() == names
    assert "wobble" not in names and "emps" in names
    warnings = [r.getMessage() for r in caplog.records if "broken-data" in r.getMessage()]
    assert len(warnings) == 1
    assert warnings[0].startswith("plugin 'broken-data' (entry point wobble = "
                                  f"broken_data_plug:WOBBLE in {GROUP}) fails to load")
    assert len(load_benchmark("emps").test) == 1  # the others still load
    with pytest.raises(DataError, match=r"dataset 'wobble' cannot be used: plugin 'broken-data'"
                       r".*ImportError: broken on purpose\. Fix: "):
        load_benchmark("wobble")


def test_an_entry_point_that_names_no_loader_is_left_out_and_named_when_asked(
    tmp_path, monkeypatch, caplog
):
    root = tmp_path / "odd"
    root.mkdir()
    (root / "odd_data_plug.py").write_text("NOT_A_LOADER = 3\n")
    install(root, "odd-data", {GROUP: {"odd": "odd_data_plug:NOT_A_LOADER"}})
    monkeypatch.syspath_prepend(str(root))
    monkeypatch.setattr(plugins, "_WARNED", set())
    with caplog.at_level(logging.WARNING):
        assert "odd" not in available_datasets() and "emps" in available_datasets()
    warnings = [r.getMessage() for r in caplog.records if "odd-data" in r.getMessage()]
    assert len(warnings) == 1 and "neither a Dataset nor a loader" in warnings[0]
    with pytest.raises(DataError, match=r"dataset 'odd' cannot be used: plugin 'odd-data'.*"
                       r"neither a Dataset nor a loader\. Fix: point the entry point"):
        load_benchmark("odd")
