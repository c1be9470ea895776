"""Would held-out sines have chosen the loop's refits the way its validation data did?

    python experiments/refit_choice.py outputs/loop/ffnn_default/<run>
    python experiments/refit_choice.py <run> --frequencies 0.2 2 20 200

A loop round keeps a refit only if it beats its start on the validation free-run loss (held-out
segments of the training data), at the rate whose loss is lowest. This script checks those
choices against signals like the tests: full-amplitude sines at frequencies that are neither
test nor training frequencies, simulated with the run's own simulator settings and scored in
free run over the whole recording. Per refit round it scores the start (the model that stood
before the round) and every rate's refit — also those the loop rejected
(``rejected_refit_model.ckpt``) — and says which one the check sines prefer. Simulator runs
only: measured data have no such extra recordings.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

from hysteresis_lab.errors import HysteresisLabError
from hysteresis_lab.loop.checks import CHECK_FREQUENCIES, refit_choices

log = logging.getLogger("refit_choice")


def _name(rate: float | None) -> str:
    return "start" if rate is None else f"refit lr {rate:.0e}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished hysteresis-lab-loop run folder")
    parser.add_argument("--frequencies", type=float, nargs="+", default=list(CHECK_FREQUENCIES))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        results = refit_choices(args.run, args.frequencies)
    except HysteresisLabError as err:
        raise SystemExit(str(err)) from err
    for result in results:
        log.info("round %d, effects %s:", result["round"], result["effects"])
        for c in result["candidates"]:
            sines = " ".join(f"{v:.3f}" for v in c["check_rmse"].values())
            log.info("  %-14s validation %.3e  check mean %.4f  [%s]%s", _name(c["refit_lr"]),
                     c["validation_loss"], c["check_mean"], sines, "  <- loop" if c["kept"] else "")
        agree = "agree" if result["loop_keeps"] == result["check_prefers"] else "DISAGREE"
        log.info("  check sines prefer %s: %s", _name(result["check_prefers"]), agree)
    (args.run / "refit_choice.json").write_text(json.dumps(results, indent=1, default=str))


if __name__ == "__main__":
    main()
