"""The tests' in-process console app (`in_process.run_app_in_process`) leaves the test process
as it found it, and reports what a fresh interpreter would."""

from __future__ import annotations

import logging
import os
import signal
import sys
import warnings

from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig

from in_process import run_app_in_process


def _process_state() -> dict:
    root = logging.getLogger()
    return {"cwd": os.getcwd(), "environ": dict(os.environ), "argv": list(sys.argv),
            "path": list(sys.path), "handlers": list(root.handlers), "level": root.level,
            "filters": list(warnings.filters), "showwarning": warnings.showwarning,
            "signals": [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]}


def test_an_app_run_in_process_puts_the_process_back(tmp_path):
    before = _process_state()
    # through Hydra (its logging, a log file in the run folder), then a one-line error
    proc = run_app_in_process("evaluate", f"hydra.run.dir={tmp_path}/run", cwd=tmp_path,
                              env={"HYSTERESIS_LAB_TEST_VARIABLE": "set"})
    assert proc.returncode == 2 and "checkpoint is not set" in proc.stdout + proc.stderr
    assert proc.args[0] == "hysteresis-lab-evaluate"
    assert (tmp_path / "run" / "evaluate.log").read_text().count("checkpoint is not set") == 1
    assert _process_state() == before
    assert not HydraConfig.initialized() and not GlobalHydra.instance().is_initialized()


def test_an_error_before_logging_is_set_up_reaches_stderr_as_in_a_fresh_interpreter(tmp_path):
    # pytest's own log handlers sit on the root logger: the app must not write into them
    proc = run_app_in_process("train", "model=doesnotexist", cwd=tmp_path, env={})
    assert proc.returncode == 2
    assert "unknown model 'doesnotexist'" in proc.stderr and proc.stdout == ""
    assert list(tmp_path.iterdir()) == []
