"""What the console apps show on the terminal: one progress display, each line once, no
library noise, and at the end the result and where every file is (the loop: one line per
round and the report's path, not its content)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from helpers import data_overrides, small_dataset
from hysteresis_lab.data.recording import Recording
from hysteresis_lab.workflows import paper

#: Hydra's console prefix ``[time][logger][LEVEL] - `` and Lightning's own ``LEVEL: ``
PREFIX = re.compile(r"^(\[[^\]]*\]\[[^\]]*\]\[[A-Z]+\] - |[A-Z]+: )")


def run_console(module: str, *overrides: str, cwd: Path) -> str:
    """Run ``python -m hysteresis_lab.cli.<module>``; its stdout and stderr as a terminal
    receives them (one stream, in order)."""
    proc = subprocess.run(
        [sys.executable, "-m", f"hysteresis_lab.cli.{module}", *overrides],
        cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=600,
        env={**os.environ, "HYDRA_FULL_ERROR": "0"},
    )
    output = proc.stdout.decode("utf-8", errors="replace")  # carriage returns kept
    assert proc.returncode == 0, output[-3000:]
    return output


def screen_lines(output: str) -> list[str]:
    """The lines a terminal ends up showing: of each line, what the last carriage return
    left (a progress bar's final state); blank lines dropped."""
    return [shown for line in output.split("\n") if (shown := line.split("\r")[-1].strip())]


def messages(lines: list[str]) -> list[str]:
    """The lines without their logging prefix (time, logger, level)."""
    return [PREFIX.sub("", line) for line in lines]


def twice(lines: list[str]) -> list[str]:
    return [line for line, n in Counter(messages(lines)).items() if n > 1]


@pytest.fixture(scope="module")
def csv_data(tmp_path_factory) -> tuple[Path, list[Path]]:
    return small_dataset(tmp_path_factory.mktemp("terminal_data"))


@pytest.mark.slow
def test_a_training_shows_one_progress_display_each_line_once_and_its_files_last(
    csv_data, tmp_path
):
    run_dir = tmp_path / "run"
    output = run_console("train", *data_overrides(*csv_data), "trainer.max_epochs=2",
                         f"hydra.run.dir={run_dir}", cwd=tmp_path)
    lines = screen_lines(output)
    assert not twice(lines), twice(lines)
    # one progress display: the epochs, then the scoring of the test recordings
    bars = [line for line in lines if "%|" in line]
    assert len(bars) == 2, bars
    assert bars[0].startswith("Epoch 2/2: 100%") and "val_loss=" in bars[0]
    assert bars[1].startswith("Scoring 2 test recording(s): 100%")
    # no log line glued to a progress bar (logging writes above the bar)
    glued = [line for line in lines if "%|" in line and ("] - " in line or "INFO:" in line)]
    assert not glued, glued
    for noise in ("Sanity Checking", "Validation", "Total params", "Tip:", "litlogger",
                  "TPU available", "deprecated", "v_num"):
        assert noise not in output, noise
    # the last lines: the result, then where each file is
    last = messages(lines[-8:])
    assert last[0].startswith("ffnn on csv: mean RMSE one-step")
    assert last[1] == f"run folder: {run_dir}"
    listed = "\n".join(last[2:])
    for name in ("model.ckpt", "metrics.json", "hysteresis_loops.png", "residuals.png",
                 f"--logdir {run_dir / 'tensorboard'}", "train.log"):
        assert name in listed, name
    assert (run_dir / "model.ckpt").is_file() and (run_dir / "metrics.json").is_file()


@pytest.mark.slow
def test_the_model_summary_shows_only_when_asked(csv_data, tmp_path):
    quick = [*data_overrides(*csv_data), "trainer.max_epochs=1", "logger=none", "plots=false"]
    asked = run_console("train", *quick, "trainer.enable_model_summary=true",
                        f"hydra.run.dir={tmp_path / 'asked'}", cwd=tmp_path)
    # once, not also through Lightning's own handler
    assert asked.count("Total params") == 1 and asked.count("| Name") == 1


@pytest.mark.slow
def test_a_loop_prints_one_line_per_round_and_where_its_report_is(tmp_path):
    train, tests = small_dataset(tmp_path, effects={"creep": {"enabled": True}})
    run_dir = tmp_path / "loop"
    output = run_console("loop", *data_overrides(train, tests), "model=ffnn",
                         "loop.max_rounds=1", "trainer.max_epochs=3", "logger=none", "plots=false",
                         "loop.folds=2", "loop.refit_lr_factors=[1.0]",  # a short loop
                         f"hydra.run.dir={run_dir}", cwd=tmp_path)
    report = json.loads((run_dir / "loop_report.json").read_text())
    lines = messages(screen_lines(output))
    assert not twice(lines), twice(lines)
    rounds = [line for line in lines if line.startswith("round ")]
    assert len(rounds) == len(report["rounds"]) == 2, lines
    assert rounds[0].startswith("round 0 (the start, effects []): test free-run RMSE")
    added = report["rounds"][1]["decision"]
    verdict = "kept" if added["kept"] else "dropped"
    assert rounds[1].startswith(f"round 1: + {added['effect']} (explained ")
    assert f"{verdict}: held-out loss " in rounds[1] and " -> " in rounds[1]
    assert lines[-1].startswith(f"report: {run_dir / 'loop_report.md'}")
    assert lines[-2].startswith("result: round ")
    # the report's path, not its content; no fit's own lines (they are in loop.log)
    markdown = (run_dir / "loop_report.md").read_text()
    assert "# Residual loop" in markdown and "# Residual loop" not in output
    assert "### Residual evidence" not in output
    for noise in ("Epoch", "Total params", "saved ", "one-step RMSE", "=== loop round"):
        assert noise not in output, noise
    assert len(lines) <= len(rounds) + 5, lines  # start, device, rounds, result, report
    full_log = (run_dir / "loop.log").read_text()
    assert "=== loop round 1" in full_log and "saved " in full_log


def test_the_paper_run_includes_the_grey_box_beyond_the_study():
    import hysteresis_lab as hl

    cfg = hl.compose("experiment=paper")
    assert list(cfg.paper.models) == ["ffnn", "lstm", "cnn", "svm", "greybox"]
    assert cfg.paper.models.greybox.name == "greybox"
    assert [paper.column_label(key) for key in cfg.paper.models] == [
        "ffnn", "lstm", "cnn", "svm", "grey-box (this project, beyond the study)"]


def test_figure1_names_the_grey_box_as_beyond_the_study():
    t = np.arange(400) / 1000.0
    u = 100.0 * np.sin(2 * np.pi * 5.0 * t)[:, None]
    recordings = [Recording(u=u, y=0.2 * u, fs=1000.0, name=f"sine_{k}") for k in (1, 2)]
    free_run = {rec.name: {"ffnn": 0.21 * rec.u, "greybox": 0.19 * rec.u}
                for rec in recordings}
    legend = paper.figure1(recordings, free_run).axes[0].get_legend()
    labels = [text.get_text() for text in legend.get_texts()]
    assert labels == ["measured", "ffnn", "grey-box (this project, beyond the study)"]

