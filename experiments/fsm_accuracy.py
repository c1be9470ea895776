"""FSM piezo-mirror accuracy with the benchmark's scoring, beside the published references.

    hysteresis-lab-train model=ffnn data=fsm hydra.run.dir=outputs/fsm_ffnn
    python experiments/fsm_accuracy.py outputs/fsm_ffnn/metrics.json

The official score is the free-run (simulation) RMSE in µm per output and test realisation
after the first 100 samples, averaged over realisations and outputs, per amplitude level;
``metrics.json`` already holds the per-realisation RMSE averaged over the three outputs.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

from hysteresis_lab.data.benchmarks import FSM_AMPLITUDES, FSM_REFERENCE_UM

log = logging.getLogger("fsm_accuracy")


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    metrics = json.loads(Path(sys.argv[1]).read_text())
    rows = ["| amplitude | " + " | ".join(FSM_REFERENCE_UM) + f" | {metrics['model']} free run "
            f"| {metrics['model']} one step |", "|---" * (len(FSM_REFERENCE_UM) + 3) + "|"]
    for amp in FSM_AMPLITUDES:
        tests = [m for name, m in metrics["tests"].items() if name.startswith(f"{amp}mV_")]
        if not tests:
            continue
        free = sum(m["rmse_free_run"] for m in tests) / len(tests)
        one = sum(m["rmse_one_step"] for m in tests) / len(tests)
        refs = " | ".join(f"{FSM_REFERENCE_UM[k][amp]:.4f}" for k in FSM_REFERENCE_UM)
        rows.append(f"| {amp} mV | {refs} | {free:.4f} | {one:.4f} |")
    log.info("RMSE [µm] on the official FSM test set\n%s", "\n".join(rows))


if __name__ == "__main__":
    main()
