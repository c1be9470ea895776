"""Compiled free runs against the NumPy step loops they replace, in one process.

    python benchmarks/bench_compiled_free_run.py
    python benchmarks/bench_compiled_free_run.py --models lstm --rounds 3

For each architecture with a compiled ``run_all`` (LSTM, CNN, SVM), simulates the twelve test
sines of the default data set with the NumPy ``step`` loop and with ``run_all``, alternately,
and reports sequential steps/s (samples of the 200,000-sample 0.1 Hz sine per second) and the
largest difference between the two outputs. Untrained networks (speed does not depend on the
weights); the SVM is fitted (its components come from the data).
"""

from __future__ import annotations

import argparse
import logging
import time
import warnings

import numpy as np
from bench_models import CONFIGS

from hysteresis_lab.data.datamodules import PaperDataModule
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model

log = logging.getLogger("bench_compiled_free_run")


def compare(name: str, rounds: int) -> None:
    layout = "flat" if name == "svm" else "sequence"
    dm = PaperDataModule(layout=layout)
    dm.setup()
    model = build_model(CONFIGS[name], dm)
    if name == "svm":
        model.fit(*dm.scale_windows(dm.train_windows))
    else:
        model = model.eval()
    tests = dm.test_recordings
    longest = max(r.n_samples for r in tests)
    kernel_class = type(model.free_run_kernel(np.zeros((1, 30, model.nu)), dm.window))
    run_all = kernel_class.run_all
    free_run(model, tests[-1:], dm.window)  # compile (or load the cached machine code)
    outputs = {}
    for number in range(rounds):
        for label in ("NumPy step", "compiled"):
            if label == "NumPy step":
                del kernel_class.run_all
            try:
                start = time.perf_counter()
                outputs[label] = free_run(model, tests, dm.window)
                seconds = time.perf_counter() - start
            finally:
                kernel_class.run_all = run_all
            log.info("%s round %d, %-10s: %8.0f steps/s", name, number, label, longest / seconds)
    difference = max(np.abs(a - b).max() for a, b in zip(*outputs.values(), strict=True))
    span = max(np.ptp(a) for a in outputs["NumPy step"])
    log.info("%s: largest |step - compiled| = %.3g (output range %.3g)", name, difference, span)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["lstm", "cnn", "svm"],
                        choices=["lstm", "cnn", "svm"])
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    warnings.filterwarnings("ignore")
    for noisy in ("lightning", "lightning.pytorch", "hysteresis_lab"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    for name in args.models:
        compare(name, args.rounds)


if __name__ == "__main__":
    main()
