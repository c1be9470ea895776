"""The diagnosis through the model's dynamics says how many samples it leaves out of each
recording (issue #35): on a 1000-sample recording, not the 7162 its dynamics would take."""

from __future__ import annotations

import logging

import numpy as np
from scipy import signal

from hysteresis_lab.data.recording import Recording
from hysteresis_lab.loop.diagnosis.ranking import (
    MAX_SKIPPED_SHARE,
    _model_dynamics,
    _prepare,
    _settling,
    diagnose,
    evidence_lags,
)
from hysteresis_lab.models.augment import feature_context

FS = 1000.0
POLE = 0.99  # a slow model: its start transient settles over more than 1000 samples


def _slow_case(n: int, seed: int) -> tuple[Recording, np.ndarray, np.ndarray]:
    """A recording of ``n`` samples, the slow model's free run and its residual."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, n)
    model = signal.lfilter([1 - POLE], [1, -POLE], u)
    y = model + 0.01 * rng.normal(size=n)
    return Recording(u=u, y=y, fs=FS, name=f"diag{n}"), model, y - model


def test_the_log_names_the_samples_left_out_of_each_recording(caplog):
    cases = [_slow_case(1000, 0), _slow_case(20000, 1)]
    recordings = [c[0] for c in cases]
    settling = _settling(np.array([1.0, -POLE]))
    assert 1000 < settling < 20000 * MAX_SKIPPED_SHARE  # capped on one, not on the other
    with caplog.at_level(logging.INFO, logger="hysteresis_lab.loop.diagnosis.ranking"):
        diagnose(recordings, [c[2][:, None] for c in cases], feature_context(recordings[1:]),
                 [], candidates=["drift"], lags=evidence_lags(4),
                 predictions=[c[1][:, None] for c in cases], through_dynamics=True)
    line = next(r.getMessage() for r in caplog.records
                if "through the model's dynamics: output" in r.getMessage())
    assert "left out at the start: 100 of 1000 on diag1000, " in line, line
    assert "the first" not in line and "of each residual" not in line, line
    # the long one is not capped: it loses the settling time the note names
    long_left = int(line.split(" of 20000 on diag20000")[0].rsplit(", ", 1)[1])
    assert 1000 < long_left < 20000 * MAX_SKIPPED_SHARE, line
    assert f"settles in {long_left} samples; at most 10% of a residual" in line, line
    # what the log says is what is left out
    context = feature_context(recordings[1:])
    a = _model_dynamics(recordings, [c[2][:, None] for c in cases],
                        [c[1][:, None] for c in cases], [False, False], context, [])[0]
    for (rec, _, residual), left in ((cases[0], 100), (cases[1], long_left)):
        kept = _prepare(rec, residual[:, None], context, [], 10 ** 9, (0,), dynamics=a).keep
        assert kept[0] == left
