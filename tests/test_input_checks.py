"""Training data a model can learn little from are named in a warning (issue #35): an input
that never moves, too few samples for the window, an effect slower than the record."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from hysteresis_lab.data.checks import MIN_WINDOWS_PER_REGRESSOR, warn_weak_excitation
from hysteresis_lab.data.readers import write_csv
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.data.user_files import load_user_files
from hysteresis_lab.data.windows import WindowSpec
from hysteresis_lab.models.augment import feature_context, warn_unshown
from hysteresis_lab.workflows.pipeline import RunConfig, run_model
from narx import CONFIGS, TRAINER

DATA = {"window": {"na": 2, "nb": 2, "nk": 1}, "scaling": {"mode": "standard"}}


def csv_files(tmp_path, u: np.ndarray, fs: float = 2000.0) -> list:
    """A training and a test CSV of input ``u`` (V) and a lagged response (um)."""
    y = np.convolve(u, [0.0, 0.5, 0.3], mode="full")[: len(u)] + 0.01 * np.arange(len(u)) / fs
    wave = np.sin(2 * np.pi * 7 * np.arange(len(u)) / fs)
    return [
        write_csv(Recording(u=u, y=y, fs=fs, u_names=("u",), y_names=("y",), name=name),
                  tmp_path / f"{name}.csv")
        for name, u in (("run", u), ("sine", wave))
    ]


def warnings_of(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_a_run_on_a_constant_input_warns_what_is_wrong_and_what_is_needed(tmp_path, caplog):
    train, test = csv_files(tmp_path, np.full(600, 5.0))
    splits = load_user_files(str(train), [str(test)])
    config = RunConfig.build(dict(CONFIGS["svm"]), DATA, TRAINER, tmp_path / "run",
                             use_tensorboard=False, evaluate=False)
    with caplog.at_level(logging.WARNING):
        run_model(config, splits=splits)
    constant = [w for w in warnings_of(caplog) if "is constant" in w]
    assert len(constant) == 1, warnings_of(caplog)
    assert f"input 'u' is constant (5 V) in all the training data ({train})" in constant[0]
    assert "Record with an input that moves" in constant[0]


def test_a_moving_input_among_constant_ones_is_not_called_constant(tmp_path, caplog):
    u = np.full(600, 5.0)
    u[300:] = 6.0  # one step: it moves
    train, test = csv_files(tmp_path, u)
    with caplog.at_level(logging.WARNING):
        lines = warn_weak_excitation(load_user_files(str(train), [str(test)]), WindowSpec())
    assert lines == [] and not any("constant" in w for w in warnings_of(caplog))


def test_too_few_samples_for_the_window_are_named_with_how_many_are_needed(tmp_path, caplog):
    window = WindowSpec(na=10, nb=10, nk=1)
    needed = MIN_WINDOWS_PER_REGRESSOR * 20 + window.first_target
    rng = np.random.default_rng(0)
    short, test = csv_files(tmp_path, rng.uniform(-1, 1, needed - 1))
    with caplog.at_level(logging.WARNING):
        lines = warn_weak_excitation(load_user_files(str(short), [str(test)]), window)
    assert len(lines) == 1 and lines == warnings_of(caplog)
    assert f"hold {needed - 1} samples" in lines[0] and "for 20 regressors" in lines[0]
    assert f"Record at least {needed} samples" in lines[0]
    long_enough, _ = csv_files(tmp_path, rng.uniform(-1, 1, needed))
    assert warn_weak_excitation(load_user_files(str(long_enough), [str(test)]), window) == []


def test_creep_on_a_record_much_shorter_than_its_filters_is_warned_about(tmp_path, caplog):
    """0.2 s of record: creep's 1, 10 and 100 s filters are left out, and the run says so."""
    rng = np.random.default_rng(1)
    train, test = csv_files(tmp_path, rng.uniform(-1, 1, 400))  # 0.2 s at 2 kHz
    splits = load_user_files(str(train), [str(test)])
    config = RunConfig.build({**CONFIGS["svm"], "effects": ["creep"]}, DATA, TRAINER,
                             tmp_path / "run", use_tensorboard=False, evaluate=False)
    with caplog.at_level(logging.WARNING):
        run_model(config, splits=splits)
    creep = [w for w in warnings_of(caplog) if w.startswith("creep:")]
    assert len(creep) == 1, warnings_of(caplog)
    assert "its slowest filter is 100 s but the longest training record is 0.2 s" in creep[0]
    assert "the filters of 1, 10, 100 s are left out" in creep[0]
    assert "record at least 200 s, or drop creep" in creep[0]


@pytest.mark.parametrize(("seconds", "fs", "expected"), [
    (300.0, 2000.0, None),
    (300.0, 50.0, "its filters of 0.1 s span fewer than 20 samples at 50 Hz"),
])
def test_creep_is_warned_about_only_where_a_filter_is_left_out(seconds, fs, expected):
    n = int(seconds * fs)
    rec = Recording(u=np.sin(np.arange(n) / fs), y=np.zeros(n), fs=fs)
    lines = warn_unshown(["creep", "hysteresis"], feature_context([rec]))
    if expected is None:
        assert lines == []
    else:
        assert len(lines) == 1 and expected in lines[0] and "sample at 200 Hz" in lines[0]


def test_a_model_with_creep_filters_of_its_own_is_warned_about_those():
    """model=linear / greybox carry ``creep_time_constants_s``: the warning names theirs."""
    fs, n = 2000.0, 400  # 0.2 s
    rec = Recording(u=np.sin(np.arange(n) / fs), y=np.zeros(n), fs=fs)
    context = feature_context([rec])
    assert warn_unshown(["creep"], context, {"creep_time_constants_s": [0.01, 0.05]}) == []
    lines = warn_unshown(["creep"], context, {"name": "linear",
                                              "creep_time_constants_s": [0.02, 1.0]})
    assert len(lines) == 1 and "its slowest filter is 1 s" in lines[0]
    assert "the filters of 1 s never move over it" in lines[0]
    assert "record at least 2 s" in lines[0] and "used:" not in lines[0]
