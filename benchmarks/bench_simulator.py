"""Time the simulated positioner: the default data set (best of 3) and simulator samples/s.

Run with ``python benchmarks/bench_simulator.py``; the Bouc-Wen JIT is warmed up first.
"""

from __future__ import annotations

import logging
import time
import timeit
from collections.abc import Callable

import numpy as np

from hysteresis_lab.signals import multisine
from hysteresis_lab.sim import Positioner
from hysteresis_lab.sim.default_dataset import make_default_dataset


def _fastest(task: Callable[[], object]) -> float:
    """Smallest wall-clock time (s) of 3 calls (`timeit.repeat`)."""
    return min(timeit.repeat(task, number=1, repeat=3))


log = logging.getLogger("bench_simulator")

FS = 20_000.0


def run() -> list[tuple[str, int, float]]:
    """Rows (case, samples, seconds) of the benchmark."""
    start = time.perf_counter()
    Positioner().simulate(np.zeros(100), FS)  # JIT compile (or load from cache)
    log.info("warm-up (JIT compile / cache load): %.3f s", time.perf_counter() - start)

    data = make_default_dataset()
    n_dataset = sum(rec.n_samples for rec in [*data.train, *data.test])
    u = multisine(1_000_000, fs=FS, seed=0)
    positioner = Positioner()
    everything = Positioner({name: {"enabled": True} for name in positioner.config.to_dict()})
    return [
        ("make_default_dataset()", n_dataset, _fastest(make_default_dataset)),
        ("simulate 1e6 samples (defaults)", len(u), _fastest(lambda: positioner.simulate(u, FS))),
        ("simulate 1e6 samples (all blocks on)", len(u),
         _fastest(lambda: everything.simulate(u, FS))),
    ]


def main() -> None:
    rows = run()
    log.info("%-38s %10s %10s %14s", "case", "samples", "best [s]", "samples/s")
    for case, n, seconds in rows:
        log.info("%-38s %10d %10.4f %14.3g", case, n, seconds, n / seconds)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main()
