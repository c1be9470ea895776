"""Choosing the FSM's augmented SUBNET without the test records: one training realisation held out.

The FSM's validation windows are drawn from the training realisations themselves, so they do
not show how a model carries over to a realisation it has not seen, which is what the test
records ask (a larger SUBNET can fit its training records better and score worse on the
tests: `docs/results/fsm_augmented.md`). Here realisation ``--holdout`` of
every amplitude is set aside: the grey-box baseline and each candidate SUBNET train on the
other five, and the held-out realisation (both periods, free run from its first samples,
scored after ``n_init``) chooses between the candidates. The official test scores of the same
models are listed beside it, not used to choose.

RMSE per output and recording, averaged, in µm per amplitude. Writes
``docs/results/fsm_holdout.md``; the two candidates train side by side (one process each).

    python experiments/fsm_holdout.py --root /tmp/fsm-holdout
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import logging
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from fsm_start import N_INIT, NL_LFR, score

from hysteresis_lab import api
from hysteresis_lab.data.benchmarks import FSM_AMPLITUDES, fsm_piezo_mirror
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.models.augment import for_model
from hysteresis_lab.models.io import load_model

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "fsm_holdout.md"
QUIET = ["logger=none", "trainer.enable_progress_bar=false", "plots=false"]
#: the accuracy table's FSM grey-box row (`benchmarks/accuracy.py`)
GREYBOX = ["model=greybox", "model.n_modes=14", "training.lr=5e-4", "model.recording_repeats=2",
           "trainer.max_epochs=10"]
#: the augmented SUBNET's settings, and the candidates' one difference
SUBNET = ["model=subnet", "model.nx=28", "data.window.na=50", "data.window.nb=50",
          "training.horizon=300", "training.lr=3e-3", "data.batch_size=64",
          "trainer.max_epochs=200"]
CANDIDATES = {"64 neurons": ["model.neurons=64"], "32 neurons": ["model.neurons=32"]}

log = logging.getLogger("fsm_holdout")


def held_out_splits(holdout: int) -> tuple[DatasetSplits, list]:
    """The FSM without realisation ``holdout`` in training, and that realisation's records."""
    full = fsm_piezo_mirror()
    keep = [r for r in full.train if r.metadata["realisation"] != holdout]
    held = [r for r in full.train if r.metadata["realisation"] == holdout]
    return dataclasses.replace(full, train=keep), held


def train(overrides: list[str], folder: Path, holdout: int) -> Path:
    """One training run on the held-out splits; its run folder."""
    splits, _ = held_out_splits(holdout)
    api.train(api.compose("data=fsm", *overrides, *QUIET), folder, splits=splits)
    return folder


def scores(folder: Path, recordings: list) -> dict[int, float]:
    model = load_model(folder / "model.ckpt")
    return score(recordings, free_run(model, for_model(model, recordings), model.window), N_INIT)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, required=True, help="folder for the run folders")
    parser.add_argument("--holdout", type=int, default=6, help="realisation set aside (1-6)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    stamp = commit_stamp(REPO)
    baseline = train(GREYBOX, args.root / "greybox", args.holdout)
    runs = {name: ([*SUBNET, *extra, f"model.baseline={baseline}"],
                   args.root / name.replace(" ", "_"))
            for name, extra in CANDIDATES.items()}
    spawn = multiprocessing.get_context("spawn")  # no fork of a process that holds torch
    with ProcessPoolExecutor(max_workers=len(runs), mp_context=spawn) as pool:
        for future in [pool.submit(train, o, f, args.holdout) for o, f in runs.values()]:
            future.result()
    splits, held = held_out_splits(args.holdout)  # its test records are the official ones
    lines = [
        "# The FSM's augmented SUBNET, chosen on a held-out realisation", "",
        f"Written by `python experiments/fsm_holdout.py --root <folder> --holdout "
        f"{args.holdout}` on {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC, "
        f"commit {stamp}. The grey-box baseline and both candidates train on realisations "
        f"other than r{args.holdout} of every amplitude; r{args.holdout} (both periods) "
        "chooses. Free-run RMSE in µm per amplitude (per output and recording, after "
        f"n_init = {N_INIT}, averaged). SUBNET settings: `{' '.join(SUBNET)}` with the "
        "grey-box as `model.baseline`; grey-box: `" + " ".join(GREYBOX) + "`.", "",
        "| candidate | scored on | 100 mV | 200 mV | 300 mV |", "|---|---|---|---|---|",
    ]
    for name, (_, folder) in runs.items():
        for label, recordings in ((f"held-out r{args.holdout} (chooses)", held),
                                  ("official test (not used to choose)", splits.test)):
            values = scores(folder, recordings)
            log.info("%s, %s: %s", name, label, values)
            lines.append(f"| {name} | {label} | "
                         + " | ".join(f"{values[a]:.4f}" for a in FSM_AMPLITUDES) + " |")
    lines += ["", "NL-LFR (published, test, offset=1000): "
              + " / ".join(f"{NL_LFR[a]} µm" for a in FSM_AMPLITUDES) + "."]
    OUT.write_text("\n".join(lines) + "\n")
    log.info("wrote %s", OUT)


if __name__ == "__main__":
    main()
