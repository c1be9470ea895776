"""A broken plugin disables only itself: one warning naming it, everything else runs.

Each test installs a real distribution (a ``*.dist-info`` with ``entry_points.txt`` and a
module whose import raises) on ``sys.path`` or ``PYTHONPATH``, found by the standard
entry-point discovery the registries and the Hydra search-path plugin use.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np
import pytest

from helpers import data_overrides, run_app, small_dataset
from hysteresis_lab import plugins
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.effects.registry import available_effects, get_effect
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.loop.diagnosis.ranking import diagnose
from hysteresis_lab.models.registry import available_models, get_model_class
from hysteresis_lab.signals import sine

MODULE = "broken_plug"
PACKAGE = "broken-plug"
GROUPS = {
    "hysteresis_lab.effects": {"wobble": f"{MODULE}:Wobble"},
    "hysteresis_lab.models": {"wobblenet": f"{MODULE}:WobbleNet"},
    "hysteresis_lab.configs": {"wobble": MODULE},
}
#: the warning each broken entry point gives, once
WARNING = "plugin 'broken-plug' (entry point {name} = {value} in {group}) fails to load"


def install_broken_plugin(root: Path, groups: dict[str, dict[str, str]] = GROUPS) -> Path:
    """A distribution ``broken-plug`` in ``root`` whose module raises on import."""
    root.mkdir(parents=True, exist_ok=True)
    (root / f"{MODULE}.py").write_text('raise ImportError("broken on purpose")\n')
    dist = root / f"{MODULE}-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {PACKAGE}\nVersion: 0.1\n")
    sections = [f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in entries.items())
                for group, entries in groups.items()]
    (dist / "entry_points.txt").write_text("\n".join(sections))
    return root


def warning_of(group: str) -> str:
    (name, value), = GROUPS[group].items()
    return WARNING.format(name=name, value=value, group=group)


def with_plugin(root: Path) -> dict[str, str]:
    """The environment of a console app that finds the plugin (and this checkout's code)."""
    return {"PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}


@pytest.fixture
def broken(tmp_path, monkeypatch) -> Path:
    root = install_broken_plugin(tmp_path / "site")
    monkeypatch.syspath_prepend(str(root))
    monkeypatch.setattr(plugins, "_WARNED", set())  # each test sees its own first warning
    return root


def test_a_broken_effect_is_left_out_of_the_diagnosis_with_one_warning(broken, caplog):
    fs = 2000.0
    recs = [sine(f, fs=fs, n_periods=3) for f in (0.5, 2.0, 8.0)]
    recordings = [Recording(u=u, y=np.zeros(len(u)), fs=fs, name=f"s{i}")
                  for i, u in enumerate(recs)]
    rng = np.random.default_rng(0)
    residuals = [0.01 * rng.standard_normal((r.n_samples, 1)) for r in recordings]
    context = FeatureContext(fs, np.array([100.0]), 6.0)
    with caplog.at_level(logging.WARNING):
        assert "wobble" not in available_effects() and "creep" in available_effects()
        ranked = diagnose(recordings, residuals, context, declared=["hysteresis"])
    assert "wobble" not in [r.effect for r in ranked] and "creep" in [r.effect for r in ranked]
    warnings = [r.getMessage() for r in caplog.records if PACKAGE in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].startswith(warning_of("hysteresis_lab.effects"))
    assert "Fix: " in warnings[0]
    # naming it is an error that says whose it is
    with pytest.raises(ConfigError, match=r"effect 'wobble' cannot be used: plugin 'broken-plug'"
                       r".*ImportError: broken on purpose\. Fix: "):
        get_effect("wobble")


def test_a_broken_model_is_left_out_of_the_catalogue_with_one_warning(broken, caplog):
    with caplog.at_level(logging.WARNING):
        names = available_models()
        assert available_models() == names
    assert "wobblenet" not in names and {"ffnn", "svm"} <= set(names)
    warnings = [r.getMessage() for r in caplog.records if PACKAGE in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].startswith(warning_of("hysteresis_lab.models"))
    with pytest.raises(ConfigError, match=r"model 'wobblenet' is registered by 'broken-plug'"):
        get_model_class("wobblenet")


def test_a_broken_configs_entry_leaves_every_command_working(tmp_path):
    root = install_broken_plugin(tmp_path / "site")
    out = tmp_path / "sine.csv"
    proc = run_app("simulate", "signal.kind=sine", "signal.frequency=100", f"output={out}",
                   env=with_plugin(root))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert out.read_text().startswith("t,u,y")
    assert "Traceback" not in proc.stderr
    assert proc.stderr.count(warning_of("hysteresis_lab.configs")) == 1, proc.stderr


@pytest.mark.slow
def test_a_loop_that_never_names_a_broken_effect_runs_and_reports(tmp_path):
    effect = "hysteresis_lab.effects"
    root = install_broken_plugin(tmp_path / "site", {effect: GROUPS[effect]})
    train, tests = small_dataset(tmp_path, effects={"creep": {"enabled": True}})
    proc = run_app("loop", *data_overrides(train, tests), "model=svm", "model.n_components=100",
                   "model.max_samples=1000", "loop.max_rounds=0", "logger=none", "plots=false",
                   f"hydra.run.dir={tmp_path}/loop", env=with_plugin(root))
    assert proc.returncode == 0, proc.stderr[-3000:]
    log = proc.stdout + proc.stderr
    assert "Traceback" not in log
    assert log.count(warning_of(effect)) == 1, log
    rounds = json.loads((tmp_path / "loop" / "loop_report.json").read_text())["rounds"]
    diagnosed = {d["effect"] for d in rounds[0]["diagnosis"]}
    assert "creep" in diagnosed and "wobble" not in diagnosed
