"""What a new user trips over (issue #24): each mistake ends in one line naming the real problem
and its fix, before any work, and a command writes nothing it was not asked to."""

from __future__ import annotations

import pytest

from helpers import data_overrides, run_app, small_dataset

QUIET = ["trainer.enable_progress_bar=false", "trainer.enable_model_summary=false"]


def one_line_error(proc, message: str) -> str:
    """The output of a command that must have stopped with exit status 2 and ``message``."""
    output = proc.stdout + proc.stderr
    assert proc.returncode == 2, output[-3000:]
    assert message in output and "Fix: " in output, output[-3000:]
    assert "Traceback" not in output and "Error executing job" not in output, output[-3000:]
    return output


# ----------------------------------------------------------------------------- evaluate
@pytest.mark.slow
def test_evaluate_without_a_checkpoint_says_so(tmp_path):
    proc = run_app("evaluate", f"hydra.run.dir={tmp_path}/a", cwd=tmp_path)
    one_line_error(proc, "checkpoint is not set. Fix: checkpoint=")
    assert "MissingMandatoryValue" not in proc.stdout + proc.stderr


# ----------------------------------------------------------------------------- train
@pytest.mark.slow
def test_train_help_writes_nothing(tmp_path):
    proc = run_app("train", "--help", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "== Configuration groups ==" in proc.stdout
    assert list(tmp_path.iterdir()) == [], "--help wrote files"
    assert "is not available" not in proc.stderr


@pytest.mark.slow
def test_a_plain_train_run_writes_only_in_its_run_folder(tmp_path):
    train, tests = small_dataset(tmp_path, n_train=1500)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    proc = run_app(
        "train",
        *data_overrides(train, tests),
        "trainer.max_epochs=1",
        "plots=false",
        "logger=none",
        f"hydra.run.dir={tmp_path}/run",
        *QUIET,
        cwd=cwd,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "run" / "metrics.json").is_file()
    assert list(cwd.iterdir()) == [], "the run wrote outside its folder"
    assert "is not available" not in proc.stderr
