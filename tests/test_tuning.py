"""Bayesian tuning through Hydra multirun: resume, SIGKILL, two workers on PostgreSQL, errors."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest
import yaml
from optuna.trial import TrialState

from conftest import optional_dependency
from helpers import data_overrides, popen_app, run_app, small_dataset, sweep_args
from hysteresis_lab.errors import ConfigError
from hysteresis_lab.tuning.bookkeeping import DISCARDED, PID, counted, discard_stale
from hysteresis_lab.tuning.storage import STORAGE_ENV, open_storage, redact, resolve_storage_url


@pytest.fixture(scope="module")
def csv_data(tmp_path_factory) -> list[str]:
    directory = tmp_path_factory.mktemp("tuning_data")
    return data_overrides(*small_dataset(directory, n_train=1500))


PG_PASSWORD = "tuning-test-secret"


def trial_states(db: Path) -> list[tuple[int, str]]:
    """(number, state) of every trial, read-only: polling must never race the worker that is
    creating the storage's tables (optuna's storage would try to create them too)."""
    if not db.exists():
        return []
    try:
        with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as con:
            return con.execute("SELECT number, state FROM trials").fetchall()
    except sqlite3.OperationalError:  # no tables yet, or the database is locked
        return []


def load(results: Path, name: str = "ffnn_csv") -> optuna.Study:
    return optuna.load_study(study_name=name, storage=f"sqlite:///{results}/{name}.db")


def counted_trials(study: optuna.Study) -> list[optuna.trial.FrozenTrial]:
    return [t for t in study.get_trials() if counted(t)]


@pytest.mark.slow
def test_sweep_writes_results_and_resumes_without_repeating(tmp_path, csv_data):
    results = tmp_path / "optuna"
    first = run_app("train", *csv_data, *sweep_args(results, 3))
    assert first.returncode == 0, first.stderr[-3000:]
    study = load(results)
    done = counted_trials(study)
    assert [t.state for t in done] == [TrialState.COMPLETE] * 3
    out = results / "ffnn_csv"
    for name in ("trials.csv", "optimization_history.png", "param_importances.png", "summary.json"):
        assert (out / name).stat().st_size > 0, name
    first_params = [t.params for t in done]
    best_config = results / "best" / "experiment" / "best_ffnn_csv.yaml"
    assert "override /model: ffnn" in best_config.read_text()

    again = run_app("train", *csv_data, *sweep_args(results, 5))
    assert again.returncode == 0, again.stderr[-3000:]
    study = load(results)
    done = counted_trials(study)
    assert len(done) == 5
    assert [t.params for t in done[:3]] == first_params
    keys = [tuple(sorted(t.params.items())) for t in done]
    assert len(set(keys)) == len(keys), "a resumed sweep repeated a trial's parameters"

    # the best config trains straight away, on the sweep's data without naming it again
    best = run_app(
        "train",
        "experiment=best_ffnn_csv",
        "trainer.max_epochs=1",
        "evaluate=false",
        "logger=none",
        f"hydra.searchpath=[file://{results}/best]",
        f"hydra.run.dir={tmp_path}/best_run",
    )
    assert best.returncode == 0, best.stderr[-3000:]
    composed = yaml.safe_load((tmp_path / "best_run" / ".hydra" / "config.yaml").read_text())
    assert composed["data"]["name"] == "csv"
    assert [f"data.train={composed['data']['train']}",
            f"data.test=[{','.join(composed['data']['test'])}]"] == csv_data[1:]


@pytest.mark.slow
def test_sigkill_mid_trial_loses_no_completed_trial(tmp_path, csv_data):
    results = tmp_path / "optuna"
    # no pruning: every trial that runs to its end completes (Hyperband would stop some)
    args = [*csv_data, *sweep_args(results, 3, "trainer.max_epochs=40",
                                   "hydra.sweeper.pruner=none")]
    worker = popen_app("train", *args)
    db = results / "ffnn_csv.db"
    deadline = time.time() + 300
    killed = False
    while time.time() < deadline:
        time.sleep(0.5)
        states = {state for _, state in trial_states(db)}
        if {"COMPLETE", "RUNNING"} <= states:
            os.killpg(worker.pid, signal.SIGKILL)
            killed = True
            break
    worker.wait()
    assert killed, "the sweep never reached a second trial"
    trials = load(results).get_trials()
    kept = {t.number: (t.params, t.value) for t in trials if t.state == TrialState.COMPLETE}
    killed_during = next(t.number for t in trials if t.state == TrialState.RUNNING)

    resumed = run_app("train", *args)
    assert resumed.returncode == 0, resumed.stdout[-3000:] + resumed.stderr[-3000:]
    study = load(results)
    by_number = {t.number: t for t in study.get_trials()}
    for number, (params, value) in kept.items():
        assert by_number[number].state == TrialState.COMPLETE
        assert (by_number[number].params, by_number[number].value) == (params, value)
    assert by_number[killed_during].user_attrs.get(DISCARDED) == "worker died"
    done = counted_trials(study)
    assert len(done) == 3 and all(t.state == TrialState.COMPLETE for t in done)


def test_a_worker_dead_right_after_asking_is_seen_dead_at_once(tmp_path):
    """The trial's first write already names its worker: a worker that dies before doing
    anything else leaves a trial the next worker discards at once, not after the grace."""
    url = f"sqlite:///{tmp_path}/study.db"
    optuna.create_study(study_name="s", storage=url)
    script = (
        "import os, optuna\n"
        "from hysteresis_lab.tuning.bookkeeping import ask_claimed\n"
        f"ask_claimed(optuna.load_study(study_name='s', storage='{url}'))\n"
        "os._exit(0)\n"
    )
    subprocess.run([sys.executable, "-c", script], check=True, timeout=120)
    study = optuna.load_study(study_name="s", storage=url)
    (orphan,) = study.get_trials()
    assert orphan.state == TrialState.RUNNING

    assert discard_stale(study, grace_s=3600.0) == 1
    (orphan,) = study.get_trials()
    assert orphan.state == TrialState.FAIL
    assert orphan.user_attrs[DISCARDED] == "worker died"


@pytest.mark.slow
@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("training.lr=tag(log, interval(1e-3, 1e-4))",
         r"invalid search space in hydra\.sweeper\.params: .*\(low=0\.001, high=0\.0001\)"),
        ("hydra.sweeper.sampler=bayes", r"unknown sampler 'bayes'"),
        ("+model.neuronz=range(1,3)",
         r"search-space parameter '\+model\.neuronz' is not in the config\. Fix:"),
        ("hydra.sweeper.storage=postgresql://nobody@127.0.0.1:9/none",
         r"cannot open the Optuna storage postgresql://nobody@127\.0\.0\.1:9/none"),
        # a password in the configured URL would be saved in every run's config: refused
        (f"hydra.sweeper.storage=postgresql://nobody:{PG_PASSWORD}@127.0.0.1:9/none",
         r"hydra\.sweeper\.storage contains a password, which Hydra would save in every run's "
         r"config\. Fix: export HYSTERESIS_LAB_OPTUNA_STORAGE="),
    ],
    ids=["low_above_high", "sampler", "unknown_parameter", "unreachable", "password"],
)
def test_bad_sweep_settings_fail_before_training(tmp_path, csv_data, override, message):
    results = tmp_path / "optuna"
    proc = run_app("train", *csv_data, *sweep_args(results, 2), override,
                   env={STORAGE_ENV: ""})
    assert proc.returncode != 0
    assert re.search(message, proc.stderr + proc.stdout), proc.stderr + proc.stdout
    assert "Traceback" not in proc.stderr + proc.stdout  # one clear line, not a crash
    assert not (results / "runs").exists()  # no trial was launched
    assert not (results / "ffnn_csv.db").exists() or not load(results).get_trials()


def test_a_password_is_accepted_from_the_environment_only(tmp_path, monkeypatch):
    """The URL with its password may come from HYSTERESIS_LAB_OPTUNA_STORAGE (no file records
    it); in hydra.sweeper.storage it is refused, and logs show it masked."""
    url = f"postgresql://nobody:{PG_PASSWORD}@127.0.0.1:9/none"
    monkeypatch.delenv(STORAGE_ENV, raising=False)
    with pytest.raises(ConfigError, match="hydra.sweeper.storage contains a password"):
        resolve_storage_url(url, "s", tmp_path)
    assert resolve_storage_url("postgresql://nobody@127.0.0.1:9/none", "s", tmp_path) == (
        "postgresql://nobody@127.0.0.1:9/none")
    monkeypatch.setenv(STORAGE_ENV, url)
    assert resolve_storage_url(None, "s", tmp_path) == url
    assert resolve_storage_url(url, "s", tmp_path) == url  # the environment's own URL
    assert PG_PASSWORD not in redact(url) and "***" in redact(url)


@pytest.mark.slow
def test_nan_trial_fails_and_the_study_goes_on(tmp_path, csv_data):
    results = tmp_path / "optuna"
    proc = run_app(
        "train",
        *csv_data,
        *sweep_args(
            results,
            2,
            "training.lr=tag(log, interval(1e8, 1e9))",
            "trainer.max_epochs=3",
        ),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    states = [t.state for t in counted_trials(load(results))]
    assert len(states) == 2
    assert all(s in (TrialState.FAIL, TrialState.PRUNED) for s in states)



#: each architecture's search space in conf/hparams_search/<name>.yaml
SEARCH_SPACES = {
    "lstm": {"model.num_layers", "model.lstm_layers", "model.units", "training.lr"},
    "cnn": {"model.num_layers", "model.conv_layers", "model.units", "model.kernel_size",
            "training.lr"},
    "svm": {"model.kernel", "model.C", "model.degree", "model.gamma"},
    "subnet": {"model.nx", "model.neurons", "model.hidden_layers", "training.lr",
               "training.horizon"},
    "greybox": {"model.hysteresis", "model.n_modes", "model.delay", "training.lr"},
}
#: the learning-rate range each search config gives (the study's for its four)
LR_RANGES = {"subnet": (1e-4, 1e-2), "greybox": (1e-3, 1e-1)}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SEARCH_SPACES))
def test_each_architectures_search_config_runs_trials(name, tmp_path, csv_data):
    """hparams_search=<name>: two trials over that architecture's own search space, then the
    best config, which names the architecture."""
    results = tmp_path / "optuna"
    args = ["-m", f"hparams_search={name}", f"hydra.sweeper.results_dir={results}",
            "hydra.sweeper.n_trials=2", "hydra.sweeper.n_startup_trials=2",
            "trainer.max_epochs=1", "trainer.enable_progress_bar=false",
            f"hydra.sweep.dir={results}/runs"]
    if name == "svm":
        args += ["model.n_components=50", "model.max_samples=300"]
    proc = run_app("train", *csv_data, *args, env={STORAGE_ENV: ""})
    assert proc.returncode == 0, proc.stderr[-3000:]
    trials = counted_trials(load(results, f"{name}_csv"))
    assert [t.state for t in trials] == [TrialState.COMPLETE] * 2
    for trial in trials:
        assert set(trial.params) == SEARCH_SPACES[name]
        low, high = LR_RANGES.get(name, (1e-4, 1e-3))
        assert low <= trial.params.get("training.lr", low) <= high
    best = results / "best" / "experiment" / f"best_{name}_csv.yaml"
    assert f"override /model: {name}" in best.read_text()


@pytest.fixture(scope="module")
def postgres_url(tmp_path_factory):
    """A real PostgreSQL server on TCP loopback that demands a password (pgserver's binaries)."""
    pgserver = optional_dependency("pgserver")
    import psycopg
    from pgserver.postgres_server import pg_ctl

    pgdata = tmp_path_factory.mktemp("pgdata")
    server = pgserver.get_server(pgdata, cleanup_mode="stop")  # initdb, Unix socket only
    with psycopg.connect(server.get_uri()) as conn:
        conn.execute(f"ALTER USER postgres PASSWORD '{PG_PASSWORD}'")
    server.cleanup()
    hba = Path(server.pgdata) / "pg_hba.conf"
    hba.write_text("local all all trust\nhost all all 127.0.0.1/32 scram-sha-256\n")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    options = ["-o", "-h 127.0.0.1", "-o", f"-p {port}", "-o", f"-k {pgdata}"]
    pg_ctl(["-w", *options, "-l", str(pgdata / "tcp.log"), "start"], pgdata=server.pgdata,
           user=server.system_user, timeout=30)
    with pytest.raises(psycopg.OperationalError):  # the password really is checked
        psycopg.connect(f"postgresql://postgres:wrong@127.0.0.1:{port}/postgres").close()
    yield f"postgresql://postgres:{PG_PASSWORD}@127.0.0.1:{port}/postgres"
    pg_ctl(["-w", "stop"], pgdata=server.pgdata, user=server.system_user, timeout=30)


def fresh_database(server_url: str, name: str) -> str:
    """A new, empty database on the test server: Optuna has not created its schema there."""
    import psycopg
    from sqlalchemy.engine import make_url

    url = make_url(server_url)
    with psycopg.connect(server_url, autocommit=True) as conn:
        conn.execute(f"CREATE DATABASE {name}")
    return url.set(database=name).render_as_string(hide_password=False)


def test_workers_opening_a_fresh_postgres_database_together_all_connect(postgres_url):
    """Workers started together race to create Optuna's schema; before the fix one of them
    lost ("relation studies already exists") in about one start in four. Staggered starts
    over several fresh databases make that race likely; every worker must still connect."""
    import random
    from concurrent.futures import ThreadPoolExecutor

    def connect(url: str) -> str:
        time.sleep(random.uniform(0.0, 0.15))
        try:
            open_storage(url)
            return "ok"
        except ConfigError as exc:
            return str(exc)

    for round_ in range(4):
        url = fresh_database(postgres_url, f"race{round_}")
        with ThreadPoolExecutor(6) as pool:
            results = list(pool.map(connect, [url] * 6))
        assert results == ["ok"] * 6, results
        assert optuna.storages.RDBStorage(url).get_all_studies() == []


def test_schema_creation_waits_for_the_other_worker(postgres_url):
    """While another worker holds the schema lock, opening the storage waits for it."""
    from concurrent.futures import ThreadPoolExecutor

    from hysteresis_lab.tuning.storage import _schema_lock

    url = fresh_database(postgres_url, "lock_wait")
    with ThreadPoolExecutor(1) as pool:
        with _schema_lock(url):
            opening = pool.submit(open_storage, url)
            time.sleep(1.0)
            assert not opening.done(), "the storage was created while another worker held the lock"
        assert opening.result(timeout=60) is not None


def test_a_wrong_password_is_not_mistaken_for_a_schema_race(postgres_url):
    from sqlalchemy.engine import make_url

    wrong = make_url(postgres_url).set(password="wrong").render_as_string(hide_password=False)
    start = time.monotonic()
    with pytest.raises(ConfigError, match="cannot open the Optuna storage"):
        open_storage(wrong)
    assert time.monotonic() - start < 5, "an unusable URL must fail at once, not after retries"


@pytest.mark.slow
def test_two_workers_share_one_postgres_study(tmp_path, csv_data, postgres_url):
    env = {"HYSTERESIS_LAB_OPTUNA_STORAGE": postgres_url}
    n_trials = 6
    workers = [
        popen_app(
            "train",
            *csv_data,
            *sweep_args(tmp_path / f"w{i}", n_trials, "trainer.max_epochs=4",
                       "hydra.sweeper.pruner=none"),
            env=env,
        )
        for i in range(2)
    ]
    outputs = [w.communicate(timeout=600)[0] for w in workers]
    assert all(w.returncode == 0 for w in workers), outputs[0][-2000:] + outputs[1][-2000:]
    study = optuna.load_study(study_name="ffnn_csv", storage=postgres_url)
    done = counted_trials(study)
    assert len(done) == n_trials
    assert all(t.state == TrialState.COMPLETE for t in done)
    assert len({t.user_attrs[PID] for t in done}) == 2, "one worker did all the trials"
    assert len({t.number for t in done}) == n_trials
    # the password is neither logged nor saved in any config or output
    assert PG_PASSWORD not in "".join(outputs)
    for path in tmp_path.rglob("*"):
        if path.is_file() and path.suffix in {".yaml", ".log", ".json", ".csv"}:
            assert PG_PASSWORD not in path.read_text(errors="ignore"), path


def test_the_best_trial_file_trains_on_the_data_the_sweep_used(tmp_path):
    """experiment=best_<study> alone (no data overrides) composes the sweep's data node."""
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf, open_dict

    from hysteresis_lab.api import compose as api_compose
    from hysteresis_lab.tuning.results import sweep_data, write_results

    data = ["data=csv", "data.train=/recordings/run.csv", "data.test=[/recordings/sine.csv]",
            "data.n_init=5", "+data.splits.extra=1"]
    with initialize_config_module(config_module="hysteresis_lab.conf"):
        sweep = compose(config_name="train", overrides=[*data, "hparams_search=ffnn"],
                        return_hydra_config=True)
    study = optuna.create_study(study_name="ffnn_csv")
    study.add_trial(optuna.trial.create_trial(
        params={"model.neurons": 17}, value=0.5,
        distributions={"model.neurons": optuna.distributions.IntDistribution(8, 32)}))
    write_results(study, "ffnn", {}, tmp_path / "ffnn_csv", tmp_path / "best" / "experiment",
                  sweep_data(sweep))

    best = api_compose("experiment=best_ffnn_csv", f"hydra.searchpath=[file://{tmp_path}/best]")
    with open_dict(sweep):
        del sweep["hydra"]
    assert OmegaConf.to_container(best.data) == OmegaConf.to_container(sweep.data)
    assert best.data.train == "/recordings/run.csv" and best.data.splits.extra == 1
    assert best.model.name == "ffnn" and best.model.neurons == 17
