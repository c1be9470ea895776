"""The framework's cost over bare PyTorch: training seconds per epoch, interleaved runs.

    OMP_NUM_THREADS=1 python benchmarks/overhead.py                   # every network, 3 epochs
    OMP_NUM_THREADS=1 python benchmarks/overhead.py --models ffnn --epochs 3 --rounds 3
    OMP_NUM_THREADS=1 python benchmarks/overhead.py --no-write        # print, leave the page

For each network (ffnn, lstm, cnn: the study's sizes; subnet: the defaults) on the default
data set, alternately (the order swapped every round):

* **project**: `hysteresis_lab.fitting.fit` with the ``trainer`` config of
  ``conf/trainer/default.yaml`` (progress bar, model summary, best checkpoint, sanity check,
  learning-rate schedule), only ``max_epochs`` set;
* **bare**: a plain PyTorch loop over the same network (a fresh copy with the same initial
  weights), the same data tensors, batch size, shuffled batches, Adam and learning-rate
  schedule (SUBNET: its gradient clipping, too), and one validation pass per epoch.

An epoch's time is the CPU time (`CLOCK`) from one epoch's start to the next (the project's:
read by a callback, so checkpointing and Lightning's between-epoch work count; its one-off
start — trainer, sanity check, a linear start — does not). The ratio is the median project
epoch over the median bare epoch. Then the free run of one recording (the 200,000-sample
0.1 Hz test sine) through `hysteresis_lab.evaluation.predict.free_run`, with the largest
difference from the torch step (``fast=False``; SUBNET: its torch loop) over its first 4,000
samples, and the multiply-adds per step against the core's peak.

Writes ``docs/results/speed.md`` (command, commit, date, machine, load) unless ``--no-write``.
"""

from __future__ import annotations

import argparse
import copy
import datetime
import logging
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from omegaconf import OmegaConf

from hysteresis_lab.data.datamodules import PaperDataModule
from hysteresis_lab.data.segments import simulation_data
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.fitting import build_model, fit
from hysteresis_lab.lightning_trainer import TrainerSettings

log = logging.getLogger("overhead")

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "results" / "speed.md"
TRAINER_CONFIG = ROOT / "src" / "hysteresis_lab" / "conf" / "trainer" / "default.yaml"
CONFIGS = {
    "ffnn": {"name": "ffnn", "num_layers": 4, "neurons": 100},
    "lstm": {"name": "lstm", "num_layers": 3, "lstm_layers": 2, "units": 66},
    "cnn": {"name": "cnn", "num_layers": 3, "conv_layers": 2, "units": 83, "kernel_size": 5},
    "subnet": {"name": "subnet"},
}
LIMIT = 1.1
#: CPU seconds of this process: on a shared machine the wall clock also counts the waits for a
#: core, which hit both sides at random; one torch thread, so CPU time is the work done
CLOCK = time.process_time
FREE_RUN_GOAL = 200_000


class EpochClock(L.Callback):
    """Start time of every training epoch and the end of training."""

    def __init__(self) -> None:
        self.marks: list[float] = []

    def on_train_epoch_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self.marks.append(CLOCK())

    def on_train_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self.marks.append(CLOCK())


def project_epochs(model: L.LightningModule, dm: Any, epochs: int) -> list[float]:
    """Seconds of each epoch of `training.fit` with the default ``trainer`` config."""
    config = OmegaConf.to_container(OmegaConf.load(TRAINER_CONFIG), resolve=True)
    settings = TrainerSettings.from_config({**config, "max_epochs": epochs})
    clock = EpochClock()
    with tempfile.TemporaryDirectory() as folder:
        fit(model, dm, settings, Path(folder), callbacks=[clock])
    return list(np.diff(clock.marks))


def bare_epochs(model: L.LightningModule, dm: Any, epochs: int) -> list[float]:
    """Seconds of each epoch of a plain PyTorch loop doing the same work."""
    steps = model.simulation_horizon
    if steps:  # SUBNET: free-run segments, clipped gradients (as `training._fit_free_run`)
        data = simulation_data(dm, model, steps)
        data.setup()
        train, val = data._data["train"].tensors, data._data["val"].tensors
        lr = model.training_settings.stage_lr("simulation", refit=False)
        model.initialise_from_recordings(dm.splits.train)
        model.simulation_mode = True
    else:
        train, val = dm._tensors["train"].tensors, dm._tensors["val"].tensors
        lr = model.training_settings.lr
    settings = model.training_settings
    optimizer = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=settings.weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=epochs,
                                                          eta_min=lr * 0.01)
    generator = torch.Generator().manual_seed(dm.seed)
    batch, n = dm.batch_size, len(train[0])
    times = []
    for _ in range(epochs):
        start = CLOCK()
        model.train()
        order = torch.randperm(n, generator=generator)
        for first in range(0, n, batch):
            rows = order[first : first + batch]
            loss = model._loss((train[0][rows], train[1][rows]))
            optimizer.zero_grad()
            loss.backward()
            if steps:
                torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            optimizer.step()
        schedule.step()
        model.eval()
        total = 0.0
        with torch.no_grad():
            for first in range(0, len(val[0]), batch):
                x, target = val[0][first : first + batch], val[1][first : first + batch]
                total += float(model._loss((x, target))) * len(x)
        times.append(CLOCK() - start)
    model.simulation_mode = False
    return times


def overhead(name: str, epochs: int, rounds: int) -> dict[str, Any]:
    layout = "sequence" if name in ("lstm", "cnn") else "flat"
    dm = PaperDataModule(layout=layout)
    dm.setup()
    torch.manual_seed(0)
    initial = build_model(CONFIGS[name], dm, trained_on={"fs": dm.fs})
    times: dict[str, list[float]] = {"project": [], "bare": []}
    for number in range(rounds):
        order = ("project", "bare") if number % 2 == 0 else ("bare", "project")
        for label in order:
            model = copy.deepcopy(initial)
            run = project_epochs if label == "project" else bare_epochs
            seconds = run(model, dm, epochs)
            times[label] += seconds
            log.info("%s round %d %-7s: %s s/epoch", name, number, label,
                     " ".join(f"{s:.3f}" for s in seconds))
    project, bare = (float(np.median(times[k])) for k in ("project", "bare"))
    row = {"project": project, "bare": bare, "ratio": project / bare, "data": _data(initial, dm)}
    row.update(free_run_speed(initial.eval(), dm))
    row["macs"] = macs_per_step(initial, dm.window.seq_len)
    log.info("%s: project %.3f s/epoch, bare %.3f s/epoch, ratio %.2f; free run %.0f steps/s "
             "(|fast - torch| <= %.2g)", name, project, bare, row["ratio"], row["steps_per_s"],
             row["difference"])
    return row


def _data(model: Any, dm: Any) -> str:
    """What an epoch trains on: windows, or free-run segments (simulation-trained)."""
    steps = model.simulation_horizon
    if not steps:
        return f"{len(dm._tensors['train']):,} windows"
    segments = simulation_data(dm, model, steps)
    segments.setup()
    return f"{len(segments._data['train']):,} segments of {steps} steps"


def free_run_speed(model: Any, dm: Any, check_samples: int = 4000) -> dict[str, float]:
    """Steps/s of the free run of the longest test recording, and the largest difference
    from the torch step over its first ``check_samples`` samples."""
    longest = max(dm.test_recordings, key=lambda rec: rec.n_samples)
    free_run(model, [longest.slice(0, 2000)], dm.window)  # compile (or load machine code)
    speeds, wall = [], []
    for _ in range(3):
        start, start_wall = CLOCK(), time.perf_counter()
        free_run(model, [longest], dm.window)
        speeds.append(longest.n_samples / (CLOCK() - start))
        wall.append(longest.n_samples / (time.perf_counter() - start_wall))
    head = longest.slice(0, check_samples)
    fast = free_run(model, [head], dm.window)[0]
    compiled = getattr(model, "compiled_free_run", None)
    if compiled is not None:  # a state-space model: its torch loop is the reference
        model.compiled_free_run = lambda *args, **kwargs: None
    try:
        torch_step = free_run(model, [head], dm.window, fast=False)[0]
    finally:
        if compiled is not None:
            del model.compiled_free_run
    return {"steps_per_s": float(np.median(speeds)), "wall_steps_per_s": float(np.median(wall)),
            "difference": float(np.abs(fast - torch_step).max())}


def macs_per_step(model: torch.nn.Module, seq_len: int) -> int:
    """Multiply-adds of one free-run step: LSTM and Conv1d weights act at every time step of
    the window (each step's window starts from scratch), Linear weights once."""
    total = 0
    for module in model.modules():
        if isinstance(module, torch.nn.LSTM | torch.nn.Conv1d):
            total += seq_len * sum(p.numel() for n, p in module.named_parameters()
                                   if n.startswith("weight"))
        elif isinstance(module, torch.nn.Linear):
            total += module.weight.numel()
    return total


def _peak_macs_per_s() -> float:
    """Float32 multiply-adds per second one core can do at most: 2 FMA units of 512 bits
    (16 lanes) with AVX-512, else 8 lanes, at the clock BogoMIPS / 2 gives."""
    lanes, clock = 8, 2.5e9
    try:
        info = Path("/proc/cpuinfo").read_text()
        lanes = 16 if " avx512f" in info else 8
        bogomips = [float(line.split(":")[1]) for line in info.splitlines()
                    if line.startswith("bogomips")]
        clock = bogomips[0] / 2 * 1e6 if bogomips else clock
    except (OSError, ValueError):
        pass
    return 2 * lanes * clock


def _commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, check=True,
                             capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, capture_output=True, text=True).stdout.strip()
        return out + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__} with "
            f"{torch.get_num_threads()} thread(s), Python {platform.python_version()}")


def write_page(rows: dict[str, dict[str, Any]], args: argparse.Namespace, load: str) -> None:
    lines = [
        "# Speed: the framework against bare PyTorch",
        "",
        "Written by `benchmarks/overhead.py` (do not edit by hand).",
        "",
        f"- command: `OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '?')} python "
        f"benchmarks/overhead.py {' '.join(sys.argv[1:])}`",
        f"- commit: {_commit()}",
        f"- date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
        f"- machine: {_machine()}",
        f"- load: {load}",
        "",
        "## Training: seconds per epoch",
        "",
        f"CPU seconds per epoch (see `CLOCK`), median over {args.rounds} interleaved rounds of "
        f"{args.epochs} epochs each. *project*: "
        "`hysteresis_lab.fitting.fit` with the default `trainer` config (progress bar, model "
        "summary, best checkpoint); *bare*: a plain PyTorch loop over the same network, "
        "tensors, batch size (128), Adam, learning-rate schedule and validation pass. Goal: "
        f"ratio <= {LIMIT}.",
        "",
        "| network | an epoch trains on | project [s/epoch] | bare [s/epoch] | ratio | "
        f"<= {LIMIT} |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        lines.append(f"| {name} | {r['data']} | {r['project']:.3f} | {r['bare']:.3f} | "
                     f"{r['ratio']:.2f} | {'yes' if r['ratio'] <= LIMIT else 'no'} |")
    lines += [
        "",
        "## Free run of one recording",
        "",
        "Steps per CPU second of `free_run` on the 200,000-sample 0.1 Hz test sine (median "
        "of 3, one recording, one thread; *wall*: per second of the wall clock, which on a "
        "shared machine also counts the waits for a core); *difference*: the largest "
        "|fast - torch step| over its first 4,000 samples, in µm (untrained weights: speed "
        f"does not depend on them). Goal: >= {FREE_RUN_GOAL:,} steps/s.",
        "",
        "| network | steps/s | wall [steps/s] | difference from the torch step [µm] | "
        "goal met |",
        "|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        met = "yes" if r["steps_per_s"] >= FREE_RUN_GOAL else "no"
        lines.append(f"| {name} | {r['steps_per_s']:,.0f} | {r['wall_steps_per_s']:,.0f} | "
                     f"{r['difference']:.1e} | {met} |")
    peak = _peak_macs_per_s()
    lines += [
        "",
        "Multiply-adds per free-run step against what one core can do at all (float32, "
        f"{peak / 1e9:.0f} G multiply-adds/s at the peak of its FMA units): a network whose "
        "bound lies under the goal cannot reach it on this CPU by any kernel (the FFNN and "
        "SUBNET kernels run in float64: half their bound).",
        "",
        "| network | multiply-adds per step | bound at peak [steps/s] | reached share of bound |",
        "|---|---|---|---|",
    ]
    for name, r in rows.items():
        bound = peak / r["macs"]
        lines.append(f"| {name} | {r['macs']:,} | {bound:,.0f} | "
                     f"{r['steps_per_s'] / bound:.0%} |")
    lines.append("")
    PAGE.write_text("\n".join(lines))
    log.info("wrote %s", PAGE)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    warnings.filterwarnings("ignore")
    for noisy in ("lightning", "lightning.pytorch", "hysteresis_lab"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    before = os.getloadavg()[0]
    rows = {name: overhead(name, args.epochs, args.rounds) for name in args.models}
    after = os.getloadavg()[0]
    load = (f"1-minute load average {before:.1f} before, {after:.1f} after "
            f"({os.cpu_count()} cores)")
    if after > 1.5 or before > 1.5:
        load += ": measured under load (other processes shared the cores)"
    if not args.no_write:
        write_page(rows, args, load)
    if any(not math.isfinite(r["ratio"]) for r in rows.values()):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
