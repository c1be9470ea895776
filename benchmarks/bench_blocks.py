"""Time the grey-box blocks: `simulate_chain` steps/s (free run) and the torch chain's
forward + backward pass on a training batch.

Run with ``python benchmarks/bench_blocks.py`` (the numba kernels are warmed up first).
"""

from __future__ import annotations

import argparse
import logging
import time
import timeit
from collections.abc import Callable

import numpy as np
import torch

from hysteresis_lab.blocks import (
    BlockChain,
    BoucWen,
    CreepBank,
    Delay,
    FirstOrderLag,
    SecondOrderMode,
    simulate_chain,
)
from hysteresis_lab.signals import multisine


def _fastest(task: Callable[[], object]) -> float:
    """Smallest wall-clock time (s) of 5 calls (`timeit.repeat`)."""
    return min(timeit.repeat(task, number=1, repeat=5))


log = logging.getLogger("bench_blocks")

FS = 20_000.0


def default_chain() -> BlockChain:
    """The simulator's default chain in scaled units (u / 100 V, y / 20 µm)."""
    return BlockChain(FirstOrderLag(FS, 5000.0), Delay(1), BoucWen(1.15, 0.32, 2.0, 0.6),
                      CreepBank(FS, weights=0.015), SecondOrderMode(FS, 900.0, 0.03))


def run(n_free: int = 200_000, batch: int = 64, segment: int = 2000) -> dict[str, float]:
    """``steps_per_s`` of `simulate_chain` on one recording of ``n_free`` samples and the
    seconds of one forward + backward pass (float32) on ``batch`` segments of ``segment``."""
    chain = default_chain()
    params = chain.export()
    start = time.perf_counter()
    simulate_chain(np.zeros((1, 10)), params)  # JIT compile (or load from cache)
    log.info("warm-up (JIT compile / cache load): %.3f s", time.perf_counter() - start)
    u = multisine(n_free, fs=FS, amplitude=1.0, seed=0)[None]
    free_s = _fastest(lambda: simulate_chain(u, params))

    model = chain.float()
    rng = np.random.default_rng(0)
    starts = rng.integers(0, n_free - segment, batch)
    u_batch = torch.tensor(np.stack([u[0, s : s + segment] for s in starts]), dtype=torch.float32)
    y_batch = torch.tensor(simulate_chain(u_batch.double().numpy(), params), dtype=torch.float32)

    def step() -> None:
        model.zero_grad()
        torch.mean((model(u_batch) - y_batch) ** 2).backward()

    step()
    train_s = _fastest(step)
    return {"steps_per_s": n_free / free_s, "free_run_s": free_s, "train_step_s": train_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--threads", type=int, default=None,
                        help="torch threads (on a busy machine 1 avoids spin-wait contention)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.threads:
        torch.set_num_threads(args.threads)
    log.info("torch threads: %d", torch.get_num_threads())
    r = run()
    log.info("simulate_chain, 1 x 200,000 samples: %.4f s = %.3g steps/s", r["free_run_s"],
             r["steps_per_s"])
    log.info("torch chain forward + backward, 64 x 2,000 samples (float32): %.1f ms",
             1e3 * r["train_step_s"])


if __name__ == "__main__":
    main()
