"""How much of a model's FSM error is its start: the official window against a periodic start.

The FSM test records are periodic steady state. The official score simulates each period
from its first samples (the model may read ``y[:n_init]``, ``n_init = 100``) and scores the
rest; the published baselines (BLA, NL-LFR) instead simulate with ``offset=1000``: the
period's last 1000 input samples run first, so their state has settled when the scored
period begins. This script scores trained models both ways on the same test records:

* **official**: each period as one recording, free run from its first ``first_target``
  measured samples, RMSE from sample ``n_init``;
* **periodic start**: the period's last ``--lead`` samples (input and output) run first, as
  the baselines' ``offset`` does, and the period itself is scored from sample ``n_init``;
* **official, settled part**: the official run scored from sample ``--lead`` only, the error
  once the start's transient has decayed;
* **training records**: the same free run and scoring on the estimation records (two
  periods each): a training error as high as the test's says the model underfits, not that
  it fails to generalise.

RMSE per output, realisation and period, averaged (the benchmark's scoring), in µm per
amplitude. Writes ``docs/results/fsm_start.md``.

    python experiments/fsm_start.py --runs <run folders of hysteresis-lab-train data=fsm>
"""

from __future__ import annotations

import argparse
import datetime
import logging
from pathlib import Path

import numpy as np
import yaml

from hysteresis_lab.data.benchmarks import FSM_AMPLITUDES, fsm_piezo_mirror
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.evaluation.predict import free_run
from hysteresis_lab.evaluation.provenance import commit_stamp
from hysteresis_lab.models.augment import for_model
from hysteresis_lab.models.io import load_model, model_window
from hysteresis_lab.run_folder import RunFolder

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "results" / "fsm_start.md"
N_INIT = 100
#: the published NL-LFR's reference RMSE per amplitude (µm), from the data's SOURCE.md
NL_LFR = {100: 0.0866, 200: 0.1309, 300: 0.1686}

log = logging.getLogger("fsm_start")


def with_lead(rec: Recording, lead: int) -> Recording:
    """The period preceded by its own last ``lead`` samples (it is periodic)."""
    return Recording(u=np.concatenate([rec.u[-lead:], rec.u]),
                     y=np.concatenate([rec.y[-lead:], rec.y]), fs=rec.fs,
                     name=f"{rec.name}+lead", u_units=rec.u_units, y_units=rec.y_units,
                     u_names=rec.u_names, y_names=rec.y_names)


def score(recs: list[Recording], sims: list[np.ndarray], skip: int, start: int = 0) -> dict:
    """Mean per amplitude of the RMSE per output/recording from sample ``start + skip``."""
    per_amp: dict[int, list[float]] = {amp: [] for amp in FSM_AMPLITUDES}
    for rec, sim in zip(recs, sims, strict=True):
        amp = int(rec.metadata["amplitude_mV"])
        err = (sim[start:] - rec.y)[skip:]  # ``start``: the lead run before the period
        per_amp[amp].extend(np.sqrt(np.mean(err**2, axis=0)).tolist())
    return {amp: float(np.mean(v)) for amp, v in per_amp.items()}


def model_table(run: Path, splits: DatasetSplits, lead: int) -> list[str]:
    """The four scorings of the model trained in ``run``, as markdown lines."""
    model_file = RunFolder(run).model_file()
    if model_file is None:
        raise SystemExit(f"{run} holds no model.ckpt / model.skops: train one first")
    model = load_model(model_file)
    window = model_window(model)
    recs = splits.test
    official = free_run(model, for_model(model, recs), window)
    led_recs = [with_lead(r, lead) for r in recs]
    led = free_run(model, for_model(model, led_recs), window)
    rows = {
        f"official (free run from y[:{window.first_target}], scored from sample {N_INIT})":
            score(recs, official, N_INIT),
        f"official run, scored from sample {lead} (start transient left out)":
            score(recs, official, lead),
        f"periodic start (the period's last {lead} samples first, as the baselines' "
        f"offset), scored from sample {N_INIT}": score(recs, led, N_INIT, start=lead),
        f"training records, official start, scored from sample {N_INIT}":
            score(splits.train, free_run(model, for_model(model, splits.train), window),
                  N_INIT),
    }
    overrides = run / ".hydra" / "overrides.yaml"
    trained_with = (" ".join(yaml.safe_load(overrides.read_text())) if overrides.is_file()
                    else "(see the run)")
    lines = [f"`hysteresis-lab-train {trained_with}`:", "",
             "| scoring | 100 mV | 200 mV | 300 mV |", "|---|---|---|---|"]
    for name, values in rows.items():
        lines.append(f"| {name} | " + " | ".join(f"{values[a]:.4f}" for a in FSM_AMPLITUDES)
                     + " |")
        log.info("%s: %s", name, values)
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, nargs="+", required=True,
                        help="run folders of hysteresis-lab-train data=fsm")
    parser.add_argument("--lead", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=OUT, help="the markdown page to write")
    parser.add_argument("--title", default="The FSM: how much of the error is the start")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    splits = fsm_piezo_mirror()
    lines = [
        f"# {args.title}", "",
        f"Written by `python experiments/fsm_start.py --runs <runs> --lead {args.lead}"
        f"{'' if args.out == OUT else ' --out ' + str(args.out)}` on "
        f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC, commit "
        f"{commit_stamp(REPO)}. Free-run RMSE in µm per amplitude, averaged over outputs, "
        "realisations and periods (see the script's docstring); one table per trained model.",
    ]
    for run in args.runs:
        lines += ["", *model_table(run, splits, args.lead)]
    lines += ["", "NL-LFR (published, offset=1000): "
              + " / ".join(f"{NL_LFR[a]} µm" for a in FSM_AMPLITUDES) + " at 100 / 200 / 300 mV."]
    args.out.write_text("\n".join(lines) + "\n")
    log.info("wrote %s", args.out)


if __name__ == "__main__":
    main()
