"""The command-line apps end to end on small simulated data (real files, real TensorBoard logs)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from helpers import REPO, data_overrides, run_app, small_dataset
from hysteresis_lab.data.readers import read_recording
from hysteresis_lab.evaluation.evaluate import scoring_start
from hysteresis_lab.evaluation.metrics import r2, rmse
from hysteresis_lab.evaluation.predict import free_run, one_step
from hysteresis_lab.models.io import load_model

pytestmark = pytest.mark.slow  # every test here runs a console app

QUIET = ["trainer.enable_progress_bar=false", "trainer.enable_model_summary=false"]


@pytest.fixture(scope="module")
def csv_data(tmp_path_factory) -> tuple[Path, list[Path]]:
    return small_dataset(tmp_path_factory.mktemp("cli_data"))


@pytest.fixture(scope="module")
def trained_run(csv_data, tmp_path_factory) -> Path:
    run_dir = tmp_path_factory.mktemp("train_run")
    proc = run_app("train", *data_overrides(*csv_data), "model=ffnn", "trainer.max_epochs=3",
                   "n_step=20", f"hydra.run.dir={run_dir}", *QUIET)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return run_dir


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["data.columns.time=null", "data.fs=1000"],
         "is sampled at 1000 Hz but the model was trained at 2000 Hz"),
        (["data.units.y=mm"], "is in u [V], y [mm] but the model was trained on u [V], y [um]"),
    ],
)
def test_evaluate_refuses_data_at_another_rate_or_in_other_units(
    trained_run, csv_data, tmp_path, overrides, message
):
    train, tests = csv_data
    proc = run_app("evaluate", f"checkpoint={trained_run}", *data_overrides(train, tests),
                   *overrides, f"hydra.run.dir={tmp_path}")
    output = proc.stderr + proc.stdout
    assert proc.returncode == 2, output[-3000:]
    assert message in output and "Fix: " in output and "Traceback" not in output
    assert not (tmp_path / "metrics.json").exists()


def test_train_writes_metrics_checkpoint_figures_and_tensorboard(trained_run, csv_data):
    metrics = json.loads((trained_run / "metrics.json").read_text())
    assert metrics["model"] == "ffnn" and metrics["units"] == {"u": "V", "y": "um"}
    assert set(metrics["tests"]) == {"sine_5", "sine_20"}
    for test in metrics["tests"].values():
        assert {"rmse_one_step", "r2_one_step", "rmse_free_run", "r2_free_run",
                "rmse_20_step"} <= set(test)
    # each mode's numbers are that mode's, of the saved model on the test files
    model = load_model(trained_run / "model.ckpt")
    tests = [read_recording(path) for path in csv_data[1]]
    skip = scoring_start(model.window)
    for mode, predict in (("one_step", one_step), ("free_run", free_run)):
        for rec, predicted in zip(tests, predict(model, tests, model.window), strict=True):
            saved = metrics["tests"][rec.name]
            assert saved[f"rmse_{mode}"] == pytest.approx(
                rmse(rec.y[skip:], predicted[skip:]), rel=1e-4), (rec.name, mode)
            assert saved[f"r2_{mode}"] == pytest.approx(
                r2(rec.y[skip:], predicted[skip:]), rel=1e-4, abs=1e-6), (rec.name, mode)
    assert {"rmse_one_step", "rmse_free_run", "r2_one_step", "r2_free_run"} <= set(metrics["mean"])
    assert metrics["train_seconds"] > 0
    assert (trained_run / "model.ckpt").is_file()
    assert list((trained_run / "checkpoints").glob("best-*.ckpt"))
    assert (trained_run / "hysteresis_loops.png").stat().st_size > 10_000
    events = EventAccumulator(str(trained_run / "tensorboard")).Reload()
    scalars = set(events.Tags()["scalars"])
    assert {"train_loss", "val_loss"} <= scalars
    assert len(events.Scalars("val_loss")) == 3
    assert any("hysteresis_loops" in tag for tag in events.Tags()["images"])


def test_evaluate_reproduces_the_training_metrics(trained_run, csv_data, tmp_path):
    proc = run_app("evaluate", f"checkpoint={trained_run}", *data_overrides(*csv_data),
                   f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    fresh = json.loads((tmp_path / "metrics.json").read_text())["tests"]
    saved = json.loads((trained_run / "metrics.json").read_text())["tests"]
    for name in saved:
        assert fresh[name]["rmse_free_run"] == pytest.approx(saved[name]["rmse_free_run"], rel=1e-6)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["model=transformer"], "unknown model 'transformer'. Valid: cnn, ffnn,"),
        (["model.name=transformer"], "unknown model 'transformer'. Available:"),
        (["+model.neuronz=5"], "has no parameter(s) ['neuronz']"),
        (["data.train=/nonexistent/file.csv"], "no such file"),
        (["data.window.na=-1"], "window na=-1 is invalid"),
        (["model.lr=abc"], "training.lr='abc' must be a number or null. Fix: e.g. "
         "training.lr=0.001"),
        (["seed=abc"], "seed='abc' must be a whole number"),
        (["model=lstm", "model.lstm_layers=1.5"],
         "model.lstm_layers=1.5 must be a whole number. Fix: model.lstm_layers=2"),
        (["model.effects=creep"], "model.effects='creep' must be a list"),
        (["plots=maybe"], "plots='maybe' must be true or false. Fix: plots=true"),
        (["model.effects=[creep,hysteresis,creep]"],
         "model.effects names ['creep'] more than once. Fix: name each effect once, "
         "model.effects=[creep,hysteresis]"),
        (["model=lstm", "training.lr=x"], "training.lr='x' must be a number"),
    ],
)
def test_bad_input_gives_a_clear_error(csv_data, tmp_path, overrides, message):
    proc = run_app("train", *data_overrides(*csv_data), *overrides, "trainer.max_epochs=1",
                   f"hydra.run.dir={tmp_path}", *QUIET)
    assert proc.returncode != 0
    output = proc.stderr + proc.stdout
    assert message in output
    assert "Traceback" not in output


@pytest.mark.parametrize("epochs", ["0", "-1", "null"])
def test_a_training_length_that_trains_nothing_or_forever_is_refused(csv_data, tmp_path, epochs):
    proc = run_app("train", *data_overrides(*csv_data), f"trainer.max_epochs={epochs}",
                   f"hydra.run.dir={tmp_path}", *QUIET)
    output = proc.stderr + proc.stdout
    assert proc.returncode == 2, output[-3000:]
    assert "must be a whole number >= 1" in output and "Fix: e.g. trainer.max_epochs=100" in output
    assert "Traceback" not in output
    assert not list(tmp_path.rglob("*.ckpt"))


@pytest.mark.parametrize(
    ("app", "override", "message"),
    [
        ("train", "trainer.precision=7", "Lightning refused the trainer settings: Precision 7"),
        ("train", "+trainer.foo=1", "unexpected keyword argument 'foo'"),
        ("train", "trainer.devices=3", "trainer.devices=3 gives 3 devices"),
        ("loop", "trainer.devices=2", "Fix: trainer.devices=1"),
    ],
)
def test_trainer_settings_lightning_refuses_stop_before_any_fit(
    csv_data, tmp_path, app, override, message
):
    proc = run_app(app, *data_overrides(*csv_data), override, "trainer.max_epochs=1",
                   f"hydra.run.dir={tmp_path}", *QUIET)
    output = proc.stderr + proc.stdout
    assert proc.returncode == 2, output[-3000:]
    assert message in output and "Traceback" not in output
    assert not list(tmp_path.rglob("*.ckpt"))


def test_a_loop_override_of_the_wrong_type_stops_before_any_fit(csv_data, tmp_path):
    """A truthy string must not pass for ``true``: the loop stops before round 0."""
    proc = run_app("loop", *data_overrides(*csv_data), "loop.warm_start=maybe",
                   "loop.alpha=abc", f"hydra.run.dir={tmp_path}", *QUIET)
    output = proc.stderr + proc.stdout
    assert proc.returncode == 2, output[-3000:]
    assert "loop.warm_start='maybe' must be true or false" in output
    assert "loop.alpha='abc' must be a number. Fix: loop.alpha=0.01" in output
    assert "Traceback" not in output
    assert not (tmp_path / "round_0").exists()


@pytest.mark.parametrize(
    ("app", "overrides", "message"),
    [
        ("train", ["data.test=[]"], "has no test recordings to evaluate on. Fix: give some"),
        ("loop", ["data.test=[]"], "has no test recordings to evaluate on. Fix: give some"),
        ("train", ["n_step=0"], "n_step=0 must be a whole number >= 1"),
    ],
)
def test_an_evaluation_that_cannot_run_stops_before_training(
    csv_data, tmp_path, app, overrides, message
):
    csv_train = data_overrides(*csv_data)[:2]  # data=csv and data.train, no data.test
    test = [] if "data.test=[]" in overrides else data_overrides(*csv_data)[2:]
    proc = run_app(app, *csv_train, *test, *overrides, "trainer.max_epochs=1",
                   f"hydra.run.dir={tmp_path}", *QUIET)
    output = proc.stderr + proc.stdout
    assert proc.returncode == 2, output[-3000:]
    assert message in output
    assert "Traceback" not in output
    assert not list(tmp_path.rglob("*.ckpt")), "it trained before saying so"


def test_evaluate_errors(trained_run, csv_data, tmp_path):
    missing = run_app("evaluate", f"checkpoint={tmp_path}/nothing.ckpt",
                      *data_overrides(*csv_data), f"hydra.run.dir={tmp_path}")
    assert missing.returncode == 2 and "no checkpoint" in missing.stdout + missing.stderr
    # a two-input recording for a one-input model
    mimo = tmp_path / "mimo.csv"
    mimo.write_text("t,u,v,y\n" + "".join(f"{k / 2000},{k},{k},{k}\n" for k in range(100)))
    wrong = run_app("evaluate", f"checkpoint={trained_run}", "data=csv", f"data.test=[{mimo}]",
                    "data.columns.inputs=[u,v]", f"hydra.run.dir={tmp_path}/w")
    output = wrong.stdout + wrong.stderr
    assert wrong.returncode == 2 and "2 input(s)" in output and "expects 1" in output


def test_paper_experiment_writes_table2_and_figure1(tmp_path):
    args = ["train", "experiment=paper", "trainer.max_epochs=1", "logger=none",
            "+data.splits.n_train=4000", "+data.splits.test_frequencies=[1,50,500]",
            "+data.splits.max_test_samples=1500", "paper.models.svm.n_components=100",
            # the grey-box fitted once (not grown, not polished): the table is checked here
            "paper.models.greybox.grow=false", "paper.models.greybox.polish=false",
            f"hydra.run.dir={tmp_path}", *QUIET]
    proc = run_app(*args, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads((tmp_path / "paper_results.json").read_text())
    # the study's four, and this project's grey-box as a fifth column beyond the study
    assert list(results) == ["ffnn", "lstm", "cnn", "svm", "greybox"]
    assert set(results["lstm"]["tests"]) == {"sine_1Hz", "sine_50Hz", "sine_500Hz"}
    assert set(results["greybox"]["tests"]) == set(results["lstm"]["tests"])
    table = (tmp_path / "table2.md").read_text()
    assert "One-step-ahead prediction" in table and "Free-run simulation" in table
    assert "svm RMSE [um]" in table and "**mean**" in table
    assert "grey-box (this project, beyond the study) RMSE [um]" in table
    rows = (tmp_path / "table2.csv").read_text().splitlines()
    assert len(rows) == 1 + 5 * (3 + 2) * 2  # header + models x (tests + mean, std) x modes
    assert sum(row.startswith("greybox,") for row in rows) == (3 + 2) * 2
    assert (tmp_path / "figure1.png").stat().st_size > 20_000
    output = proc.stdout + proc.stderr  # the last lines: each model's mean, then the files
    assert "grey-box (this project, beyond the study) free-run RMSE" in output
    assert f"run folder: {tmp_path}" in output and "table2.md, table2.csv" in output
    # run again in the same folder (a stopped run resumed): every finished fit is reused
    again = run_app(*args, timeout=900)
    assert again.returncode == 0, again.stderr[-3000:]
    assert (again.stdout + again.stderr).count("reusing the finished fit") == 5
    assert json.loads((tmp_path / "paper_results.json").read_text()) == results


def test_plugin_registers_an_architecture_and_its_config(csv_data, tmp_path):
    plugin = REPO / "plugins" / "hysteresis_lab_gru"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "-e",
         str(plugin)], capture_output=True, text=True, timeout=600)
    assert install.returncode == 0, install.stderr[-2000:]
    proc = run_app("train", *data_overrides(*csv_data), "model=gru", "model.units=16",
                   "training.lr=0.005", "trainer.max_epochs=6", f"hydra.run.dir={tmp_path}", *QUIET,
                   subprocess_only=True)  # as a user runs it after installing: a new process
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["model"] == "gru" and metrics["mean"]["r2_one_step"] > 0.5


@pytest.mark.parametrize(("model", "extra"), [
    ("subnet", ["model.nx=4", "model.neurons=16", "model.encoder_neurons=16",
                "training.horizon=50"]),
    ("greybox", ["model.n_modes=1", "model.mode_hz=400", "model.hysteresis=bouc_wen"]),
    ("linear", ["model.order=4"]),
])
def test_models_that_simulate_train_log_and_rescore_through_the_cli(
    model, extra, csv_data, tmp_path
):
    """The simulation-trained models through train and evaluate: validation free-run loss in
    TensorBoard, a saved model that evaluate scores to the same numbers."""
    run_dir = tmp_path / "run"
    proc = run_app("train", *data_overrides(*csv_data), f"model={model}", *extra,
                   "trainer.max_epochs=3", f"hydra.run.dir={run_dir}", *QUIET)
    assert proc.returncode == 0, proc.stderr[-3000:]
    saved = json.loads((run_dir / "metrics.json").read_text())
    assert saved["model"] == model
    # a grey-box grows its cell on the chain without one: each stage logs its own curves
    curves = run_dir / "tensorboard" / ("grow/0_linear" if model == "greybox" else "")
    events = EventAccumulator(str(curves)).Reload()
    # the validation free-run loss of the starting model (a candidate too), then per epoch
    assert len(events.Scalars("val_loss")) == 4
    proc = run_app("evaluate", f"checkpoint={run_dir}", *data_overrides(*csv_data),
                   f"hydra.run.dir={tmp_path / 'evaluate'}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    fresh = json.loads((tmp_path / "evaluate" / "metrics.json").read_text())["tests"]
    for name, metrics in saved["tests"].items():
        assert fresh[name]["rmse_free_run"] == pytest.approx(metrics["rmse_free_run"], rel=1e-6)
