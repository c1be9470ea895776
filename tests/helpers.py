"""Test helpers: small simulated CSV data sets and running the console apps (in this process or
in a subprocess)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from hysteresis_lab.data.readers import write_csv
from hysteresis_lab.signals import multisine, sine
from hysteresis_lab.sim.positioner import simulate_recording
from in_process import run_app_in_process

REPO = Path(__file__).resolve().parents[1]
FAST_EFFECTS = {"creep": {"enabled": False}}


def small_dataset(
    directory: Path, n_train: int = 3000, fs: float = 2000.0, effects: dict | None = None
) -> tuple[Path, list[Path]]:
    """A multisine training CSV and two sine test CSVs (t,u,y), simulated at ``fs``."""
    effects = effects if effects is not None else FAST_EFFECTS
    cfg = {**effects, "mode1": {"frequency_hz": 300.0}}
    train = simulate_recording(
        multisine(n_train, fs=fs, n_components=50, f_max=50.0, seed=1),
        fs,
        cfg,
        seed=1,
        name="train",
    )
    tests = [
        simulate_recording(sine(f, fs=fs, n_periods=2), fs, cfg, seed=2, name=f"sine_{f:g}")
        for f in (5.0, 20.0)
    ]
    train_path = write_csv(train, directory / "train.csv")
    test_paths = [write_csv(rec, directory / f"{rec.name}.csv") for rec in tests]
    return train_path, test_paths


def data_overrides(train: Path, tests: list[Path]) -> list[str]:
    return ["data=csv", f"data.train={train}", f"data.test=[{','.join(map(str, tests))}]"]


def run_app(
    module: str,
    *overrides: str,
    cwd: Path | None = None,
    env: dict | None = None,
    timeout: float = 600,
    subprocess_only: bool = False,
) -> subprocess.CompletedProcess:
    """Run the console app ``hysteresis_lab.cli.<module>`` with ``overrides``; capture its
    output and exit status.

    In this test process (`run_app_in_process`: no 8 s of ``import lightning`` per call),
    unless ``subprocess_only`` or ``env`` sets ``PYTHONPATH`` (a plugin on the path), which
    need a fresh interpreter: then ``python -m hysteresis_lab.cli.<module>``, stopped after
    ``timeout`` seconds."""
    env = {"HYDRA_FULL_ERROR": "0", **(env or {})}
    if subprocess_only or "PYTHONPATH" in env:
        return subprocess.run(
            [sys.executable, "-m", f"hysteresis_lab.cli.{module}", *overrides],
            cwd=cwd or REPO,
            capture_output=True,
            text=True,
            timeout=timeout,
            env={**os.environ, **env},
        )
    return run_app_in_process(module, *overrides, cwd=cwd or REPO, env=env)


def popen_app(
    module: str, *overrides: str, cwd: Path | None = None, env: dict | None = None
) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", f"hysteresis_lab.cli.{module}", *overrides],
        cwd=cwd or REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(env or {})},
        start_new_session=True,
    )


def sweep_args(results: Path, n_trials: int, *extra: str, search: str = "ffnn") -> list[str]:
    """A small tuning sweep (``-m hparams_search=<search>``) writing under ``results``."""
    return [
        "-m",
        f"hparams_search={search}",
        f"hydra.sweeper.results_dir={results}",
        f"hydra.sweeper.n_trials={n_trials}",
        "hydra.sweeper.n_startup_trials=2",
        "trainer.max_epochs=2",
        "trainer.enable_progress_bar=false",
        f"hydra.sweep.dir={results}/runs",
        "model.neurons=range(8,33)",
        *extra,
    ]
