"""Fit records: what a finished fit depended on, so that a rerun of a stopped loop (or paper
experiment) in its folder reuses it.

A fit writes ``fit_record.json`` into its folder as its last step: a fingerprint of
everything its result depends on (model, data and trainer settings, seed, the refit rule,
the data themselves and the weights of the network it started from) beside the few numbers
of its result that are not in ``metrics.json``. Run again in the same folder with the same
fingerprint, the fit is loaded instead of trained; a killed fit wrote no record and trains
again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.run_folder import RunFolder

log = logging.getLogger(__name__)

FIT_RECORD = RunFolder.FIT_RECORD


def fingerprint(settings: Mapping[str, Any], splits: DatasetSplits, start: Any | None) -> str:
    """A digest of the fit's ``settings`` (plain, JSON-able), the recordings of ``splits``
    and the weights of the network it starts from (``start``, or None)."""
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode())
    for part in ("train", "val", "test"):
        for rec in getattr(splits, part):
            digest.update(f"{part}:{rec.name}:{rec.fs}".encode())
            for values in (rec.u, rec.y):
                digest.update(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    if start is not None:
        for name, tensor in start.state_dict().items():
            digest.update(name.encode())
            digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


def write_record(directory: Path, key: str, result: Mapping[str, Any]) -> None:
    """Mark the fit in ``directory`` finished: its fingerprint and ``result`` (JSON-able; its
    ``files``, the names of the fit's files in ``directory``, must all be there to reuse it).
    The record appears whole or not at all (a process killed while writing leaves none)."""
    partial = directory / f"{FIT_RECORD}.partial"
    partial.write_text(json.dumps({"fingerprint": key, **result}, indent=1))
    os.replace(partial, directory / FIT_RECORD)


def finished_fit(directory: Path, key: str) -> dict[str, Any] | None:
    """The record of a finished fit in ``directory`` with fingerprint ``key``, or None (no
    record, another fingerprint, or files of the fit missing)."""
    path = directory / FIT_RECORD
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        log.warning("%s is unreadable: the fit in %s trains again", path, directory)
        return None
    if record.get("fingerprint") != key:
        log.info(
            "%s: the finished fit there had other settings, data or start; it trains again",
            directory,
        )
        return None
    files = record.get("files")
    if not files or not all((directory / name).is_file() for name in files):
        log.info("%s: files of the finished fit are missing; it trains again", directory)
        return None
    return record


def forget(directory: Path) -> None:
    """Remove the record of ``directory`` (its files were moved: a rerun refits)."""
    (directory / FIT_RECORD).unlink(missing_ok=True)
