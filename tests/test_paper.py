"""How the paper experiment spreads its models over processes."""

import pytest

from hysteresis_lab.errors import ConfigError
from hysteresis_lab.paper import available_cores, plan_workers

CPU = {"accelerator": "cpu"}


def test_auto_uses_one_process_per_core_up_to_the_models():
    cores = available_cores()
    processes, threads = plan_workers(4, CPU)
    assert processes == min(4, cores)
    if processes > 1:
        assert threads == max(1, cores // processes)
    assert plan_workers(1, CPU) == (1, None)


def test_explicit_workers_are_capped_by_the_models():
    assert plan_workers(4, CPU, workers=1) == (1, None)
    processes, threads = plan_workers(2, CPU, workers=8)
    assert processes == 2 and threads >= 1


@pytest.mark.parametrize("workers", [0, -1, "two", 1.5, True])
def test_bad_workers_value_says_how_to_fix_it(workers):
    with pytest.raises(ConfigError, match="paper.workers"):
        plan_workers(4, CPU, workers=workers)
