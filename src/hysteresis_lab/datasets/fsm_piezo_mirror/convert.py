"""Rebuild ``fsm_<amplitude>mV.npz`` from the original ``.npy`` files (see SOURCE.md).

    python -m hysteresis_lab.datasets.fsm_piezo_mirror.convert <folder with u_*/y_* .npy files>

Each archive holds ``u_train, y_train, u_test, y_test`` as float32, shape (N, 3, R, P) like the
originals, with the outputs converted from metres to micrometres; compressed to keep the
repository small (float32 keeps ~7 significant digits, far below the sensor noise). The zip
container carries time stamps, so compare archives with `content_sha256`, not file hashes;
SOURCE.md lists the expected values.
"""

from __future__ import annotations

import hashlib
import logging
import sys
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)
AMPLITUDES_MV = (100, 200, 300)
KEYS = ("u_train", "y_train", "u_test", "y_test")


def convert(source: Path, target: Path) -> list[Path]:
    """Write one compressed float32 archive per amplitude from the original files in ``source``."""
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
        log.info("wrote %s (content sha256 %s)", path, content_sha256(path))
    return written


def content_sha256(path: Path) -> str:
    """SHA-256 of the archive's arrays (raw bytes, keys in sorted order)."""
    digest = hashlib.sha256()
    with np.load(path) as archive:
        for key in sorted(archive.files):
            digest.update(np.ascontiguousarray(archive[key]).tobytes())
    return digest.hexdigest()


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO)
    convert(Path(sys.argv[1]), Path(__file__).parent)
