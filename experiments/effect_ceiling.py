"""How much of a fitted model's free-run error is an undeclared simulator effect's own output?

    python experiments/effect_ceiling.py outputs/undeclared/drift --block drift
    python experiments/effect_ceiling.py outputs/undeclared/saturation --block saturation \
        --clip-input 90

The ceiling of the closed loop on one undeclared-effect case (``experiments/undeclared_effects.py``
writes the run folders). The run's own Hydra config rebuilds its test recordings; the effect's
contribution ``d`` is the noise-free output with ``--block`` switched on minus the same with it
off. For every test recording the script reports the model's free-run RMSE, the RMS of ``d`` and
the correlation of the de-meaned residual ``e`` with ``d``: subtracting the best multiple of the
true contribution would cut the RMSE by ``1 - sqrt(1 - corr²)``, the part of the error that is
the effect as it reaches the output (a refit beats that figure only by also changing the rest of
the model's error; where ``d`` is below 1 % of ``e`` no share is given). ``--clip-input V`` also
runs the same model on the test inputs clipped at +-V: for amplifier clipping, the free-run RMSE
that the exact clipping block ahead of the fitted network would give.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from hysteresis_lab.errors import HysteresisLabError
from hysteresis_lab.loop.checks import ceiling

log = logging.getLogger("effect_ceiling")


def _change(row: dict) -> float:
    return 100 * (row["rmse_clipped_input"] / row["rmse_free_run"] - 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a hysteresis-lab-loop run folder")
    parser.add_argument("--block", required=True, help="the simulator block left undeclared")
    parser.add_argument("--round", type=int, default=0, help="the loop round whose model to use")
    parser.add_argument(
        "--clip-input", type=float, default=None, help="volts: also run on inputs clipped here"
    )
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        rows = ceiling(args.run, args.block, args.round, args.clip_input)
    except HysteresisLabError as err:
        raise SystemExit(str(err)) from err
    clipped = args.clip_input is not None
    log.info(
        "%-12s %9s %11s %6s %10s%s",
        "test",
        "RMSE [um]",
        "effect [um]",
        "corr",
        "max cut %",
        f" {'clipped input':>14s}" if clipped else "",
    )
    for row in rows:
        log.info(
            "%-12s %9.3f %11.3f %6.2f %10.1f%s",
            row["test"],
            row["rmse_free_run"],
            row["effect_rms"],
            row["corr"],
            row["max_cut_pct"],
            f" {row['rmse_clipped_input']:9.3f} ({_change(row):+.0f} %)" if clipped else "",
        )


if __name__ == "__main__":
    main()
