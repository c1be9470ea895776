"""Peak memory and time of the loop's effect ranking (`diagnose`) on a measured data set.

Reproduces the round-0 diagnosis without the loop's training: a least-squares ARX model of
each output (the loop's linear start in spirit) is simulated free-run on the identification
recordings, and its residual is ranked with the loop's settings (evidence lags of a window
of ``--nb`` input lags, through the model's dynamics). Prints the time, the process's peak
RSS (``ru_maxrss``) and the ranking; ``--json`` writes them for comparison across commits.

    python benchmarks/diagnosis_memory.py --data fsm --candidates hysteresis
    python benchmarks/diagnosis_memory.py --data fsm --recordings 3 --json /tmp/fsm3.json
"""

from __future__ import annotations

import argparse
import json
import logging
import resource
import time
from pathlib import Path

import numpy as np
from scipy import signal

from hysteresis_lab.blocks.sections import arx_least_squares
from hysteresis_lab.data.benchmarks import load_benchmark
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.loop.diagnosis.ranking import TESTS, diagnose, evidence_lags
from hysteresis_lab.models.augment import feature_context

log = logging.getLogger("diagnosis_memory")

#: data set name -> (benchmark name, loader options)
DATA = {
    "fsm": ("fsm_piezo_mirror", {"amplitude": "all"}),
    "cascaded_tanks": ("cascaded_tanks", {}),
    "p885": ("piezo_p885", {}),
    "bouc_wen": ("bouc_wen", {}),
    "emps": ("emps", {}),
}
#: the default simulated positioner: sine bursts of these frequencies (Hz), 1 s each
SIM_FREQUENCIES = (3.0, 11.0, 37.0)
#: ARX orders of the stand-in linear model
NA, NB_MODEL = 4, 10


def simulated() -> list[Recording]:
    """The default simulated positioner driven by a sine burst per `SIM_FREQUENCIES`, and
    with the input held (where only an input-independent effect can show)."""
    from hysteresis_lab.sim import Positioner

    fs = 20_000.0
    t = np.arange(int(fs)) / fs
    recordings = []
    for k, f in enumerate(SIM_FREQUENCIES):
        u = 95.0 * np.sin(2 * np.pi * f * t) * np.sin(np.pi * t)
        y = Positioner({}).simulate(u, fs, seed=k)
        recordings.append(Recording(u[:, None], np.asarray(y).reshape(-1, 1), fs,
                                    name=f"sine_{f:g}Hz"))
    u = np.full(len(t), 30.0)
    y = Positioner({}).simulate(u, fs, seed=len(recordings))
    recordings.append(Recording(u[:, None], np.asarray(y).reshape(-1, 1), fs, name="hold"))
    return recordings


def free_run(recordings: list[Recording]) -> list[np.ndarray]:
    """Each recording's free run of a least-squares ARX model per output (a stable one: the
    ARX denominator where its poles are inside the unit circle, else a FIR)."""
    out = [np.empty_like(r.y, dtype=float) for r in recordings]
    for j in range(recordings[0].ny):
        ys = [r.y[:, j] for r in recordings]
        b, a = arx_least_squares([r.u for r in recordings], ys, na=NA, nb=NB_MODEL)
        if np.max(np.abs(np.roots(a))) >= 1.0:
            b, a = arx_least_squares([r.u for r in recordings], ys, na=0, nb=4 * NB_MODEL)
        b = b.reshape(recordings[0].nu, -1)
        for k, r in enumerate(recordings):
            sim = sum(signal.lfilter(b[c], a, r.u[:, c]) for c in range(r.nu))
            out[k][:, j] = sim + np.mean(r.y[:, j] - sim)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="fsm", choices=sorted([*DATA, "sim"]))
    parser.add_argument("--recordings", type=int, default=0, help="first N (0: all)")
    parser.add_argument("--candidates", nargs="*", default=None, help="default: all")
    parser.add_argument("--declared", nargs="*", default=[], help="effects the model carries")
    parser.add_argument("--nb", type=int, default=10, help="the model window's input lags")
    parser.add_argument("--n-init", type=int, default=100, help="unscored samples at the start")
    parser.add_argument("--test", default="pooled", choices=TESTS)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    if args.data == "sim":
        recordings = simulated()
    else:
        name, options = DATA[args.data]
        recordings = load_benchmark(name, **options).train
    if args.recordings:
        recordings = recordings[: args.recordings]
    context = feature_context(recordings)  # as the loop fixes it
    predictions = free_run(recordings)
    residuals = []
    for r, p in zip(recordings, predictions, strict=True):
        e = r.y - p
        e[: args.n_init] = np.nan
        residuals.append(e)
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    start = time.perf_counter()
    scores = diagnose(recordings, residuals, context, declared=args.declared,
                      candidates=args.candidates,
                      lags=evidence_lags(args.nb), predictions=predictions,
                      test=args.test, through_dynamics=True)
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    log.info("%s: %d recordings x %s samples; diagnosis %.1f s, peak RSS %.2f GB "
             "(%.2f GB before it)", args.data, len(recordings),
             sorted({r.n_samples for r in recordings}), seconds, peak, rss_before)
    for s in scores:
        log.info("  %-20s score %.6g  p %.4g  %s", s.effect, s.score, s.p_value,
                 "significant" if s.significant else "")
    if args.json:
        args.json.write_text(json.dumps({
            "data": args.data, "recordings": len(recordings), "seconds": seconds,
            "peak_rss_gb": peak, "scores": [s.to_dict() for s in scores]}, indent=1) + "\n")


if __name__ == "__main__":
    main()
