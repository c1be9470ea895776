"""What a new user trips over (issue #24): each mistake ends in one line naming the real problem
and its fix, before any work, and a command writes nothing it was not asked to."""

from __future__ import annotations

import pytest

from helpers import data_overrides, run_app, small_dataset
from hysteresis_lab.data.readers import read_recording
from hysteresis_lab.errors import DataError

QUIET = ["trainer.enable_progress_bar=false", "trainer.enable_model_summary=false"]


def one_line_error(proc, message: str) -> str:
    """The output of a command that must have stopped with exit status 2 and ``message``."""
    output = proc.stdout + proc.stderr
    assert proc.returncode == 2, output[-3000:]
    assert message in output and "Fix: " in output, output[-3000:]
    assert "Traceback" not in output and "Error executing job" not in output, output[-3000:]
    return output


# ----------------------------------------------------------------------------- readers
@pytest.mark.parametrize(
    ("text", "message", "fix"),
    [
        ("t;u;y\n0,0;1,5;2,5\n0,5;1,5;2,5\n", "has a decimal comma", "decimal point"),
        (
            "t,u,y\n0,0,1,5,2,5\n0,5,1,5,2,5\n",
            "decimal commas between comma separators",
            "decimal point",
        ),
        ("t,u,y,y\n0,1,2,3\n0.5,1,2,3\n", "names column(s) ['y'] more than once", "its own name"),
    ],
    ids=["semicolon", "comma", "duplicate_header"],
)
def test_a_malformed_csv_is_named_for_what_it_is(tmp_path, text, message, fix):
    path = tmp_path / "run.csv"
    path.write_text(text)
    with pytest.raises(DataError, match="Fix: ") as info:
        read_recording(path)
    assert message in str(info.value) and fix in str(info.value.fix)
    assert "non-numeric" not in str(info.value) and "different lengths" not in str(info.value)


def test_a_folder_given_as_a_file_is_called_a_folder(tmp_path):
    with pytest.raises(DataError, match="is a folder, not a file") as info:
        read_recording(tmp_path)
    assert "unknown file type" not in str(info.value)
    with pytest.raises(DataError, match="no such file"):
        read_recording(tmp_path / "no_suffix")


@pytest.mark.slow
def test_evaluate_without_a_test_file_says_so(tmp_path):
    proc = run_app(
        "evaluate",
        f"checkpoint={tmp_path}",
        "data=csv",
        f"hydra.run.dir={tmp_path}/b",
        cwd=tmp_path,
    )
    output = one_line_error(proc, "no test file to evaluate on: data.test is empty")
    assert "data.train" not in output


# ----------------------------------------------------------------------------- evaluate
@pytest.mark.slow
def test_evaluate_without_a_checkpoint_says_so(tmp_path):
    proc = run_app("evaluate", f"hydra.run.dir={tmp_path}/a", cwd=tmp_path)
    one_line_error(proc, "checkpoint is not set. Fix: checkpoint=")
    assert "MissingMandatoryValue" not in proc.stdout + proc.stderr


# ----------------------------------------------------------------------------- simulate
SINE = ["signal.kind=sine", "signal.frequency=200", "signal.n_periods=1"]


@pytest.mark.slow
def test_simulate_refuses_a_folder_or_an_unwritable_output(tmp_path):
    proc = run_app("simulate", *SINE, f"output={tmp_path}", cwd=tmp_path)
    one_line_error(proc, f"output={tmp_path} is a folder, not a file")
    (tmp_path / "a_file.csv").write_text("t,u,y\n")
    proc = run_app("simulate", *SINE, f"output={tmp_path}/a_file.csv/x.csv", cwd=tmp_path)
    one_line_error(proc, "a_file.csv is a file, so no folder can be made there")
    proc = run_app("simulate", *SINE, "output=/proc/no_such_folder/x.csv", cwd=tmp_path)
    one_line_error(proc, "cannot create its folder /proc/no_such_folder")


@pytest.mark.slow
def test_simulate_creates_missing_folders_and_says_so(tmp_path):
    out = tmp_path / "new" / "deeper" / "sine.csv"
    proc = run_app("simulate", *SINE, f"output={out}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"created the folder {out.parent}" in proc.stdout + proc.stderr
    assert out.read_text().startswith("t,u,y")


# ----------------------------------------------------------------------------- train
@pytest.mark.slow
def test_train_help_writes_nothing(tmp_path):
    proc = run_app("train", "--help", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "== Configuration groups ==" in proc.stdout
    assert list(tmp_path.iterdir()) == [], "--help wrote files"
    assert "is not available" not in proc.stderr


@pytest.mark.parametrize("app", ["train", "loop"])
def test_an_unknown_model_lists_the_public_ones_in_one_line(tmp_path, app):
    proc = run_app(app, "model=doesnotexist", cwd=tmp_path)
    output = one_line_error(proc, "unknown model 'doesnotexist'. Valid: cnn, ffnn, ")
    assert "_network" not in output and list(tmp_path.iterdir()) == []
    assert [line for line in output.splitlines() if line.strip()] == [output.strip()]


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


@pytest.mark.slow
def test_a_test_file_shorter_than_the_window_stops_before_training(tmp_path):
    train, tests = small_dataset(tmp_path, n_train=1500)
    short = tmp_path / "short.csv"
    short.write_text("t,u,y\n" + "".join(f"{k / 2000},{k},{-k}\n" for k in range(8)))
    proc = run_app(
        "train",
        *data_overrides(train, [tests[0], short]),
        "trainer.max_epochs=1",
        f"hydra.run.dir={tmp_path}/run",
        *QUIET,
        cwd=tmp_path,
    )
    one_line_error(proc, "has 8 samples, but scoring starts at sample 11")
    assert str(short) in proc.stdout + proc.stderr
    assert not list((tmp_path / "run").rglob("*.ckpt")), "it trained before saying so"
    assert "Epoch" not in proc.stdout + proc.stderr


@pytest.mark.slow
def test_an_absurd_value_in_a_training_file_stops_before_training(tmp_path):
    """One y of 1e300 once trained a model on NaN and exited 0 (issue #35)."""
    train, tests = small_dataset(tmp_path, n_train=1500)
    lines = train.read_text().splitlines()
    cells = lines[41].split(",")
    lines[41] = ",".join([*cells[:-1], "1e300"])  # line 42 of the file
    train.write_text("\n".join(lines) + "\n")
    proc = run_app(
        "train",
        *data_overrides(train, tests),
        "trainer.max_epochs=1",
        f"hydra.run.dir={tmp_path}/run",
        *QUIET,
        cwd=tmp_path,
    )
    output = one_line_error(proc, "in column 'y' at line 42 is beyond the physical range")
    assert str(train) in output and "data.limits.y_abs_max" in output
    assert not (tmp_path / "run" / "metrics.json").exists()
