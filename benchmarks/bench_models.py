"""Speed of the architectures on the default data set (CPU or GPU).

    python benchmarks/bench_models.py                    # CPU, 3 timed epochs per network
    python benchmarks/bench_models.py --device cuda --epochs 5
    python benchmarks/bench_models.py --models subnet greybox --threads 1

Reports per architecture: training seconds per epoch and the extrapolation to the study's
100 epochs (batch 128, 63,000 windows), one-step prediction µs/sample, and free-run speed
over all twelve test sines simulated together (sequential steps/s, i.e. samples of one
signal per second, and recording-samples/s summed over the batch), and the free run of one
recording alone (the 200,000-sample 0.1 Hz sine; the positioner runs at 20 kHz, so 20,000
steps/s is real time). Untrained weights: speed does not depend on the values. The models
trained on the simulation error (subnet, greybox, linear) are timed through `training.fit`, which
trains them on free-run segments / whole recordings.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import tempfile
import time
import warnings
from pathlib import Path

import torch

from hysteresis_lab.data.datamodules import PaperDataModule
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings, build_trainer

log = logging.getLogger("bench_models")

CONFIGS = {
    "ffnn": {"name": "ffnn", "num_layers": 4, "neurons": 100},
    "lstm": {"name": "lstm", "num_layers": 3, "lstm_layers": 2, "units": 66},
    "cnn": {"name": "cnn", "num_layers": 3, "conv_layers": 2, "units": 83, "kernel_size": 5},
    "svm": {"name": "svm", "kernel": "rbf", "C": 10.0, "gamma": 0.1, "n_components": 1000},
    "subnet": {"name": "subnet"},
    "greybox": {"name": "greybox", "effects": []},
    "linear": {"name": "linear"},
}
SIMULATION_TRAINED = ("subnet", "greybox", "linear")


def bench(name: str, device: str, epochs: int,
          max_test_samples: int | None = None) -> dict[str, float]:
    cfg = CONFIGS[name]
    layout = "sequence" if name in ("lstm", "cnn") else "flat"
    dm = PaperDataModule(layout=layout)
    dm.setup()
    model = build_model(cfg, dm, trained_on={"fs": dm.fs})
    row: dict[str, float] = {}
    if name in SIMULATION_TRAINED:
        settings = TrainerSettings(max_epochs=epochs, accelerator=device, devices=1,
                                   enable_progress_bar=False, enable_model_summary=False)
        with tempfile.TemporaryDirectory() as folder:
            result = fit(model, dm, settings, Path(folder))
        row["epoch_s"] = result.train_seconds / epochs
        row["fit_s"] = 100 * row["epoch_s"]
        model = model.to(device).eval()
    elif name == "svm":
        x, target = dm.scale_windows(dm.train_windows)
        start = time.perf_counter()
        model.fit(x, target)
        row["fit_s"] = time.perf_counter() - start
    else:
        settings = TrainerSettings(max_epochs=epochs, accelerator=device, devices=1,
                                   enable_progress_bar=False, enable_model_summary=False,
                                   extra={"num_sanity_val_steps": 0})
        trainer = build_trainer(settings, logger=False, enable_checkpointing=False)
        start = time.perf_counter()
        trainer.fit(model, datamodule=dm)
        row["epoch_s"] = (time.perf_counter() - start) / epochs
        row["fit_s"] = 100 * row["epoch_s"]
        model = model.to(device).eval()
    tests = dm.test_recordings
    if max_test_samples:  # steps/s is a rate: a shorter recording measures it sooner
        tests = [dataclasses.replace(r, u=r.u[:max_test_samples], y=r.y[:max_test_samples])
                 for r in tests]
    n_samples = sum(r.n_samples for r in tests)
    start = time.perf_counter()
    one_step(model, tests, dm.window)
    row["one_step_us_per_sample"] = 1e6 * (time.perf_counter() - start) / n_samples
    start = time.perf_counter()
    free_run(model, tests, dm.window, device=device if name != "svm" else None)
    seconds = time.perf_counter() - start
    longest = max(r.n_samples for r in tests)
    row["free_run_steps_per_s"] = longest / seconds
    row["free_run_samples_per_s"] = n_samples / seconds
    slowest = max(tests, key=lambda r: r.n_samples)
    start = time.perf_counter()
    free_run(model, [slowest], dm.window, device=device if name != "svm" else None)
    row["single_steps_per_s"] = slowest.n_samples / (time.perf_counter() - start)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--models", nargs="+", default=list(CONFIGS))
    parser.add_argument("--max-test-samples", type=int, default=None, help="cut each test "
                        "sine to this many samples (a GPU steps slowly through the 200,000 "
                        "samples of the 0.1 Hz sine)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: "
                        "torch's choice)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    warnings.filterwarnings("ignore")
    for noisy in ("lightning", "lightning.pytorch", "hysteresis_lab"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    log.info("device %s (%s), torch %s, %d threads", args.device,
             torch.cuda.get_device_name() if args.device == "cuda" else "CPU", torch.__version__,
             torch.get_num_threads())
    header = ("| model | s/epoch | fit, 100 epochs [s] | one-step [µs/sample] | "
              "free-run [steps/s] | free-run [recording-samples/s] | one recording [steps/s] |")
    rows = [header, "|---|---|---|---|---|---|---|"]
    for name in args.models:
        r = bench(name, args.device, args.epochs, args.max_test_samples)
        rows.append(f"| {name} | {r.get('epoch_s', float('nan')):.2f} | {r['fit_s']:.0f} | "
                    f"{r['one_step_us_per_sample']:.2f} | {r['free_run_steps_per_s']:.0f} | "
                    f"{r['free_run_samples_per_s']:.0f} | {r['single_steps_per_s']:.0f} |")
        log.info(rows[-1])
    log.info("\n%s", "\n".join(rows))


if __name__ == "__main__":
    main()
