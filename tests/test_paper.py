"""How the paper experiment spreads its models over processes."""

import os

import pytest

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.lightning_trainer import TrainerSettings
from hysteresis_lab.workflows import paper
from hysteresis_lab.workflows.paper import available_cores, plan_workers

CPU = TrainerSettings(accelerator="cpu")


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="Linux only")
def test_available_cores_are_the_ones_this_process_may_use():
    assert available_cores() == len(os.sched_getaffinity(0))


@pytest.mark.parametrize(
    ("cores", "n_models", "expected"),
    [
        (16, 4, (4, 4)),  # one process per model, the cores shared out
        (6, 4, (4, 1)),
        (2, 4, (2, 1)),  # one process per core
        (3, 2, (2, 1)),
        (1, 4, (1, None)),  # one process: torch's own threads
        (8, 1, (1, None)),
    ],
)
def test_auto_uses_one_process_per_core_up_to_the_models(monkeypatch, cores, n_models, expected):
    monkeypatch.setattr(paper, "available_cores", lambda: cores)  # a machine of that size
    assert plan_workers(n_models, CPU) == expected


def test_explicit_workers_are_capped_by_the_models(monkeypatch):
    monkeypatch.setattr(paper, "available_cores", lambda: 8)
    assert plan_workers(4, CPU, workers=1) == (1, None)
    assert plan_workers(2, CPU, workers=8) == (2, 4)
    assert plan_workers(4, CPU, workers=3) == (3, 2)
    monkeypatch.setattr(paper, "available_cores", lambda: 2)
    assert plan_workers(4, CPU, workers=4) == (4, 1)  # at least one thread each


@pytest.mark.parametrize("workers", [0, -1, "two", 1.5, True])
def test_bad_workers_value_says_how_to_fix_it(workers):
    with pytest.raises(ConfigError, match=rf"paper\.workers={workers!r} is invalid\. Fix: 'auto'"):
        plan_workers(4, CPU, workers=workers)
