"""Tuning that weighs compute: Pareto studies (validation free-run error x training seconds),
searched NARX lags, and multi-fidelity pruning on by default on the CPU."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import optuna
import pytest
from optuna.distributions import FloatDistribution
from optuna.trial import TrialState

from helpers import data_overrides, run_app, small_dataset, sweep_args
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.tuning.bookkeeping import counted
from hysteresis_lab.tuning.choices import make_pruner, resolve_pruner
from hysteresis_lab.tuning.objectives import STOPPED_EPOCHS, STOPPED_VALUES, check_objectives
from hysteresis_lab.tuning.pareto import main as pareto_main
from hysteresis_lab.tuning.pareto import pareto_front, pareto_points
from hysteresis_lab.tuning.storage import STORAGE_ENV

OBJECTIVES = ["val_free_run_mse", "train_seconds"]


@pytest.fixture(scope="module")
def csv_data(tmp_path_factory) -> list[str]:
    """A training file, two test sines, and a validation recording of its own."""
    directory = tmp_path_factory.mktemp("pareto_data")
    train, tests = small_dataset(directory, n_train=1500)
    val, _ = small_dataset(directory / "val", n_train=600)
    return [*data_overrides(train, tests), f"data.val=[{val}]"]


def sweep(results: Path, n_trials: int, *extra: str, search: str = "ffnn_pareto") -> list[str]:
    return sweep_args(results, n_trials, *extra, search=search)


def dominates(a: list[float], b: list[float]) -> bool:
    return all(x <= y for x, y in zip(a, b, strict=True)) and a != b


@pytest.mark.slow
def test_pareto_study_writes_a_non_dominated_front_and_searches_the_lags(tmp_path, csv_data):
    from hysteresis_lab.data.readers import read_recording
    from hysteresis_lab.models.io import load_model, model_window
    from hysteresis_lab.tuning.objectives import free_run_mse

    results = tmp_path / "optuna"
    proc = run_app("train", *csv_data, *sweep(results, 3), env={STORAGE_ENV: ""})
    assert proc.returncode == 0, proc.stderr[-3000:]
    study = optuna.load_study(
        study_name="ffnn_pareto_csv", storage=f"sqlite:///{results}/ffnn_pareto_csv.db"
    )
    assert len(study.directions) == 2
    complete = [t for t in study.get_trials() if counted(t) and t.state == TrialState.COMPLETE]
    assert len(complete) == 3

    out = results / "ffnn_pareto_csv"
    with (out / "pareto.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert rows and (out / "pareto.png").stat().st_size > 0
    assert "| trial | val_free_run_mse | train_seconds |" in (out / "pareto.md").read_text()
    front = {int(r["trial"]): [float(r[name]) for name in OBJECTIVES] for r in rows}
    for number, values in front.items():
        assert not any(dominates(t.values, values) for t in complete), number
    # every complete trial off the front is dominated by one on it
    for t in complete:
        if t.number not in front:
            assert any(dominates(v, t.values) for v in front.values()), t.number
    best_error = min(complete, key=lambda t: t.values[0])
    assert best_error.number in front
    best_config = results / "best" / "experiment" / "best_ffnn_pareto_csv.yaml"
    assert f"trial {best_error.number}," in best_config.read_text()

    # lags are trial parameters and set the trained model's window; the first objective is
    # that model's free run over the validation recording
    windows = set()
    val = read_recording(Path(csv_data[-1].split("[", 1)[1].rstrip("]")))
    for t in complete:
        assert {"data.window.na", "data.window.nb"} <= set(t.params)
        model = load_model(results / "runs" / str(t.number) / "model.ckpt")
        window = model_window(model)
        assert (window.na, window.nb) == (t.params["data.window.na"], t.params["data.window.nb"])
        windows.add((window.na, window.nb))
        assert free_run_mse(model, [val], window) == pytest.approx(t.values[0], rel=1e-6)
    assert len(windows) > 1, "the sampler never changed the lags"


@pytest.mark.slow
@pytest.mark.parametrize("search", ["ffnn", "ffnn_pareto"])
def test_pruning_is_on_by_default_on_the_cpu_and_prunes_a_clearly_bad_trial(
    tmp_path, csv_data, search
):
    """A trial that cannot learn (learning rate 1e-9) after one that does is stopped at the
    first rung by the default pruner; single- and multi-objective studies alike."""
    results = tmp_path / "optuna"
    common = [
        *csv_data,
        *sweep(results, 1, "hydra.sweeper.min_epochs=1", search=search),
        "model.neurons=16",
        "data.window.na=4",
        "data.window.nb=4",
    ]
    good = run_app("train", *common, "training.lr=tag(log, interval(1e-3, 1.001e-3))")
    assert good.returncode == 0, good.stderr[-3000:]
    assert "successive_halving pruner" in good.stdout + good.stderr
    bad = run_app(
        "train",
        *common,
        "hydra.sweeper.n_trials=2",
        "training.lr=tag(log, interval(1e-9, 1.001e-9))",
    )
    assert bad.returncode == 0, bad.stderr[-3000:]
    name = f"{search}_csv"
    study = optuna.load_study(study_name=name, storage=f"sqlite:///{results}/{name}.db")
    states = [t.state for t in study.get_trials() if counted(t)]
    assert states == [TrialState.COMPLETE, TrialState.PRUNED]
    if search != "ffnn_pareto":
        return
    # the pruned trial is a point at its own fidelity: its model's objectives when pruned
    complete, pruned = (t for t in study.get_trials() if counted(t))
    stopped = pruned.user_attrs[STOPPED_VALUES]
    assert len(stopped) == 2 and all(math.isfinite(v) and v > 0 for v in stopped)
    assert pruned.user_attrs[STOPPED_EPOCHS] >= 1
    assert stopped[0] > complete.values[0]  # lr 1e-9 learned nothing
    with (results / name / "pareto.csv").open() as handle:
        rows = {int(r["trial"]): r for r in csv.DictReader(handle)}
    on_front = stopped[1] < complete.values[1]  # faster, if less accurate
    assert (pruned.number in rows) == on_front
    if on_front:
        assert rows[pruned.number]["stopped"].startswith("pruned at epoch")


def test_the_default_pruner_is_successive_halving_on_the_cpu_and_median_on_a_gpu():
    assert resolve_pruner("auto", "cpu") == "successive_halving"
    assert resolve_pruner("auto", "gpu") == "median"
    assert resolve_pruner("successive_halving", "gpu") == "successive_halving"
    assert isinstance(
        make_pruner("hyperband", min_resource=3, max_resource=30), optuna.pruners.HyperbandPruner
    )
    halving = make_pruner("successive_halving", min_resource=3, max_resource=30)
    assert isinstance(halving, optuna.pruners.SuccessiveHalvingPruner)
    assert halving._min_resource == 3  # noqa: SLF001 - the first rung is the setting's
    # no epoch past the first rung: nothing to prune
    for name in ("hyperband", "successive_halving"):
        assert isinstance(
            make_pruner(name, min_resource=10, max_resource=10), optuna.pruners.NopPruner
        )
    with pytest.raises(ConfigError, match="unknown pruner 'asha'"):
        resolve_pruner("asha", "cpu")
    with pytest.raises(ConfigError, match="hydra.sweeper.objectives="):
        check_objectives(["val_free_run_mse", "flops"])


def test_the_front_holds_the_non_dominated_trials_of_a_stored_study(tmp_path):
    """`pareto_front` and the command that writes it from a storage, on a hand-made study."""
    url = f"sqlite:///{tmp_path}/s.db"
    study = optuna.create_study(study_name="s", storage=url, directions=["minimize"] * 2)
    study.set_user_attr("objectives", OBJECTIVES)
    lr = {"training.lr": FloatDistribution(1e-4, 1e-2, log=True)}
    # trial 5: a diverged free run (inf), the fastest, but no useful model: off the front
    points = [(0.5, 10.0), (0.2, 40.0), (0.6, 12.0), (0.3, 5.0), (0.9, 1.0), (math.inf, 0.5)]
    for i, values in enumerate(points):
        study.add_trial(
            optuna.trial.create_trial(
                params={"training.lr": 1e-3 * (i + 1)}, distributions=lr, values=list(values)
            )
        )
    assert [t.number for t in pareto_front(study)] == [1, 3, 4]
    assert study.trials[5].state == TrialState.COMPLETE

    assert [p.number for p in pareto_points(study)] == [1, 3, 4]  # no pruned trial yet

    pareto_main([url, "s", str(tmp_path / "front")])
    with (tmp_path / "front" / "pareto.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["trial"]) for r in rows] == [1, 3, 4]
    assert [float(r["val_free_run_mse"]) for r in rows] == [0.2, 0.3, 0.9]
    assert (tmp_path / "front" / "pareto.png").stat().st_size > 0


def test_a_pruned_trial_is_a_front_point_at_its_stop(tmp_path):
    """Pruned trials that recorded their objectives when pruned join the table and figure;
    the best trial stays the most accurate complete one."""
    url = f"sqlite:///{tmp_path}/s.db"
    study = optuna.create_study(study_name="s", storage=url, directions=["minimize"] * 2)
    study.set_user_attr("objectives", OBJECTIVES)
    lr = {"training.lr": FloatDistribution(1e-4, 1e-2, log=True)}
    for values in [(0.2, 40.0), (0.5, 10.0)]:
        study.add_trial(optuna.trial.create_trial(
            params={"training.lr": 1e-3}, distributions=lr, values=list(values)))
    # 2: cheaper than any complete trial; 3: beaten by 1; 4: pruned before it could record
    for attrs in [{STOPPED_VALUES: [0.7, 2.0], STOPPED_EPOCHS: 3},
                  {STOPPED_VALUES: [0.6, 12.0], STOPPED_EPOCHS: 9}, {}]:
        study.add_trial(optuna.trial.create_trial(
            params={"training.lr": 1e-3}, distributions=lr, state=TrialState.PRUNED,
            user_attrs=attrs))
    front = pareto_points(study)
    assert [(p.number, p.stopped) for p in front] == [(0, ""), (1, ""), (2, "pruned at epoch 3")]
    assert [t.number for t in pareto_front(study)] == [0, 1]

    pareto_main([url, "s", str(tmp_path / "front")])
    with (tmp_path / "front" / "pareto.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [(int(r["trial"]), r["stopped"]) for r in rows] == [
        (0, ""), (1, ""), (2, "pruned at epoch 3")]
    assert "pruned at epoch 3" in (tmp_path / "front" / "pareto.md").read_text()


@pytest.mark.slow
def test_a_free_run_objective_without_validation_recordings_fails_before_training(tmp_path):
    train, tests = small_dataset(tmp_path / "data", n_train=600)
    results = tmp_path / "optuna"
    proc = run_app(
        "train", *data_overrides(train, tests), *sweep(results, 2), env={STORAGE_ENV: ""}
    )
    assert proc.returncode != 0
    assert "the objective val_free_run_mse simulates the validation recordings" in (
        proc.stdout + proc.stderr
    )
    assert "Traceback" not in proc.stdout + proc.stderr
    assert not (results / "runs").exists()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["lstm", "cnn", "svm", "subnet"])
def test_each_narx_architecture_has_a_pareto_search_with_lags(name, tmp_path, csv_data):
    """hparams_search=<name>_pareto: two trials, each with its own lags as the model's
    window, scored on both objectives."""
    from hysteresis_lab.models.io import load_model, model_window
    from hysteresis_lab.run_folder import RunFolder

    results = tmp_path / "optuna"
    args = [
        "-m",
        f"hparams_search={name}_pareto",
        f"hydra.sweeper.results_dir={results}",
        "hydra.sweeper.n_trials=2",
        "hydra.sweeper.n_startup_trials=2",
        "trainer.max_epochs=1",
        "trainer.enable_progress_bar=false",
        f"hydra.sweep.dir={results}/runs",
    ]
    if name == "svm":
        args += ["model.n_components=50", "model.max_samples=300"]
    if name == "subnet":
        args += ["training.horizon=choice(50)"]
    proc = run_app("train", *csv_data, *args, env={STORAGE_ENV: ""})
    assert proc.returncode == 0, proc.stderr[-3000:]
    study = optuna.load_study(
        study_name=f"{name}_pareto_csv", storage=f"sqlite:///{results}/{name}_pareto_csv.db"
    )
    trials = [t for t in study.get_trials() if counted(t)]
    assert [t.state for t in trials] == [TrialState.COMPLETE] * 2
    for t in trials:
        assert len(t.values) == 2 and t.values[1] > 0
        model_file = RunFolder(results / "runs" / str(t.number)).model_file()
        window = model_window(load_model(model_file))
        assert (window.na, window.nb) == (t.params["data.window.na"], t.params["data.window.nb"])
    assert (results / f"{name}_pareto_csv" / "pareto.csv").is_file()


def test_a_stored_study_keeps_its_objectives():
    """Resuming a study with other objectives is refused before any trial, with the fix."""
    from hysteresis_lab.tuning.sweep import _check_same_objectives

    study = optuna.create_study(study_name="s", directions=["minimize"] * 2)
    _check_same_objectives(study, OBJECTIVES)  # a new study takes the names
    assert study.user_attrs["objectives"] == OBJECTIVES
    _check_same_objectives(study, OBJECTIVES)
    with pytest.raises(ConfigError, match="same hydra.sweeper.objectives, or a new"):
        _check_same_objectives(study, ["val_mse", "train_seconds"])
    single = optuna.create_study(study_name="t")
    with pytest.raises(ConfigError, match="was run with the objectives"):
        _check_same_objectives(single, OBJECTIVES)
