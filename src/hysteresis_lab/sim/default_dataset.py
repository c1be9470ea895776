"""The study's protocol on the simulated positioner: multisine development set, twelve sines."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.splits import DatasetSplits
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.signals import multisine, sine
from hysteresis_lab.sim.config import PositionerConfig
from hysteresis_lab.sim.positioner import simulate_recording

log = logging.getLogger(__name__)

HOLD_STREAM = 1  # seed stream of the hold recording (apart from the sines' seeds)
VAL_STREAM = 2  # seed stream of the validation multisine
VAL_SINES_STREAM = 3  # seed stream of the validation sines
TEST_FREQUENCIES_HZ = (0.1, 1, 10, 50, 100, 150, 200, 250, 300, 400, 450, 500)


def sine_name(frequency: float) -> str:
    return f"sine_{frequency:g}Hz"


def sine_signal(frequency: float, fs: float, amplitude: float) -> np.ndarray:
    """A test or added sine's input: two periods (one below 1 Hz), from rest."""
    return sine(frequency, fs=fs, amplitude=amplitude, n_periods=1.0 if frequency < 1.0 else 2.0)


def _hold_recording(
    seconds: float, fs: float, config: PositionerConfig, seed: int, max_samples: int | None
) -> Recording:
    """The input held at 0 V for ``seconds`` from rest (its own noise stream)."""
    n = int(round(seconds * fs))
    u = np.zeros(min(n, max_samples) if max_samples else n)
    hold_seed = int(np.random.default_rng((seed, HOLD_STREAM)).integers(0, 2**31))
    return simulate_recording(u, fs, config, seed=hold_seed, name=f"hold_{seconds:g}s")


def _validation_multisine(
    n: int, fs: float, amplitude: float, config: PositionerConfig, seed: int
) -> Recording:
    """A second multisine realisation (other phases, own noise) for honest validation."""
    phase_seed, noise_seed = np.random.default_rng((seed, VAL_STREAM)).integers(0, 2**31, 2)
    u = multisine(n, fs=fs, amplitude=amplitude, seed=int(phase_seed))
    return simulate_recording(u, fs, config, seed=int(noise_seed), name="multisine_validation")


def _validation_sines(
    frequencies: Sequence[float], fs: float, amplitude: float, config: PositionerConfig,
    seed: int,
) -> list[Recording]:
    """Validation sines at ``frequencies`` (their own noise stream)."""
    seeds = np.random.default_rng((seed, VAL_SINES_STREAM)).integers(
        0, 2**31, size=len(frequencies))
    return [
        simulate_recording(sine_signal(float(f), fs, amplitude), fs, config, seed=int(s),
                           name=f"val_{sine_name(float(f))}")
        for f, s in zip(frequencies, seeds, strict=True)
    ]


def _check_added_sines(
    train_sines: Sequence[float], val_sines: Sequence[float], test_frequencies: Sequence[float]
) -> None:
    """Added sines are at frequencies of their own: no test's, none in both added sets."""
    tests, train, val = (set(map(float, f)) for f in (test_frequencies, train_sines, val_sines))
    for name, added in (("train_sines", train), ("val_sines", val)):
        overlap = sorted(added & tests)
        if overlap:
            raise ConfigError(
                f"{name} {overlap} Hz are also test frequencies: that would train or validate "
                f"on test data. Fix: choose data.splits.{name} between the test frequencies."
            )
    both = sorted(train & val)
    if both:
        raise ConfigError(
            f"{both} Hz are both train_sines and val_sines: validation would repeat training "
            "inputs. Fix: give each added sine one role."
        )
    if len(val) != len(val_sines):
        raise ConfigError(f"val_sines {list(val_sines)} repeats a frequency. Fix: list each once.")


def make_default_dataset(
    effects: Mapping[str, Any] | DictConfig | None = None,
    seed: int = 0,
    n_train: int = 80_000,
    fs: float = 20_000.0,
    test_frequencies: Sequence[float] = TEST_FREQUENCIES_HZ,
    amplitude: float = 100.0,
    max_test_samples: int | None = None,
    train_sines: Sequence[float] = (),
    train_sine_amplitude: float | None = None,
    test_hold_s: float = 0.0,
    val_samples: int = 0,
    val_sines: Sequence[float] = (),
) -> DatasetSplits:
    """Multisine (500 lines, 0-500 Hz, ±amplitude, ``n_train`` samples) and sine test sets.

    Each sine lasts two periods, except those below 1 Hz (one period: the 0.1 Hz one is 10 s =
    200,000 samples); ``max_test_samples`` truncates the test sines (for quick runs). Every
    recording starts at rest. ``train_sines`` adds sines at other frequencies to the training
    set (the study trains on the multisine alone, whose many small lines never drive the
    full-amplitude, high-rate loops of the test sines), of ``train_sine_amplitude`` (default:
    the test amplitude; less keeps identification inside the amplifier's linear range).
    ``test_hold_s`` > 0 adds a test recording that holds the input at 0 V that long: the
    metrology test for drift, the one recording on which nothing the input drives moves.
    ``val_samples`` > 0 adds a validation recording: a second realisation of the multisine
    (same spectrum and amplitude, other random phases, its own noise) of that many samples.
    The multisine is periodic, so a random split of its windows (``val_samples=0``, the
    study's protocol) validates on inputs the model trained on. ``val_sines`` adds sines at
    other frequencies (of ``train_sine_amplitude``) to the validation set: what the loop
    validates and diagnoses on besides the validation multisine (its report recommends them
    where the multisine barely drives an effect the tests drive).
    """
    if isinstance(effects, DictConfig):
        effects = OmegaConf.to_container(effects, resolve=True)  # type: ignore[assignment]
    if train_sine_amplitude is not None and not 0 < train_sine_amplitude <= amplitude:
        raise ConfigError(
            f"train_sine_amplitude={train_sine_amplitude} V must lie in (0, {amplitude:g}] V. "
            "Fix: data.splits.train_sine_amplitude=null (the test amplitude) or a smaller value."
        )
    if not (isinstance(val_samples, int) and val_samples >= 0):
        raise ConfigError(
            f"val_samples={val_samples!r} must be a whole number >= 0. Fix: "
            "data.splits.val_samples=20000 (a second multisine) or 0 (random split of windows)."
        )
    if not test_hold_s >= 0:
        raise ConfigError(
            f"test_hold_s={test_hold_s} s must be >= 0. "
            "Fix: data.splits.test_hold_s=0 (no hold recording) or a duration, e.g. 10."
        )
    _check_added_sines(train_sines, val_sines, test_frequencies)
    config = PositionerConfig.from_dict(effects)
    n_tests = len(test_frequencies)
    seeds = np.random.default_rng(seed).integers(0, 2**31, size=2 + n_tests + len(train_sines))
    u_train = multisine(n_train, fs=fs, amplitude=amplitude, seed=int(seeds[0]))
    train = [simulate_recording(u_train, fs, config, seed=int(seeds[1]), name="multisine")]
    for frequency, rec_seed in zip(train_sines, seeds[2 + n_tests :], strict=True):
        name = f"train_{sine_name(float(frequency))}"
        u = sine_signal(float(frequency), fs, train_sine_amplitude or amplitude)
        train.append(simulate_recording(u, fs, config, seed=int(rec_seed), name=name))
    tests = []
    for frequency, rec_seed in zip(test_frequencies, seeds[2 : 2 + n_tests], strict=True):
        u = sine_signal(frequency, fs, amplitude)
        if max_test_samples:
            u = u[:max_test_samples]
        tests.append(
            simulate_recording(u, fs, config, seed=int(rec_seed), name=sine_name(frequency))
        )
    if test_hold_s > 0:
        tests.append(_hold_recording(test_hold_s, fs, config, seed, max_test_samples))
    val = [_validation_multisine(val_samples, fs, amplitude, config, seed)] if val_samples else []
    val += _validation_sines(val_sines, fs, train_sine_amplitude or amplitude, config, seed)
    return DatasetSplits(
        name="default",
        train=train,
        val=val,
        test=tests,
        metadata={"source": "simulator", "effects": config.to_dict(), "seed": seed},
    )
