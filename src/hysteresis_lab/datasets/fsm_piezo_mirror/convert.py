"""Rebuild ``fsm_<amplitude>mV.npz`` from the original ``.npy`` files (see SOURCE.md).

    python -m hysteresis_lab.datasets.fsm_piezo_mirror.convert <folder with u_*/y_* .npy files>

Each archive holds ``u_train, y_train, u_test, y_test`` as float32, shape (N, 3, R, P) like the
originals, with the outputs converted from metres to micrometres; compressed to keep the
repository small (float32 keeps ~7 significant digits, far below the sensor noise).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)
AMPLITUDES_MV = (100, 200, 300)


def convert(source: Path, target: Path) -> list[Path]:
    written = []
    for amplitude in AMPLITUDES_MV:
        arrays = {}
        for split in ("train", "test"):
            arrays[f"u_{split}"] = np.load(source / f"u_{amplitude}mV_{split}.npy").astype(
                np.float32
            )
            y = np.load(source / f"y_{amplitude}mV_{split}.npy") * 1e6  # m -> um
            arrays[f"y_{split}"] = y.astype(np.float32)
        path = target / f"fsm_{amplitude}mV.npz"
        np.savez_compressed(path, **arrays)
        written.append(path)
        log.info("wrote %s", path)
    return written


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO)
    convert(Path(sys.argv[1]), Path(__file__).parent)
