"""The README's Python API example, run as written on tiny settings, and the curated API of
``hysteresis_lab/__init__.py``."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

import hysteresis_lab as hl
from helpers import REPO, run_app
from hysteresis_lab.evaluation.metrics import rmse

README = (REPO / "README.md").read_text()
#: appended to the example's own overrides (later overrides win): a short simulator run
TINY = ("+data.splits.n_train=4000", "+data.splits.max_test_samples=3000",
        "+data.splits.test_frequencies=[10,50]", "data.splits.val_samples=2000",
        "trainer.max_epochs=3", "trainer.enable_progress_bar=false",
        "trainer.enable_model_summary=false", "plots=false", "model.num_layers=3",
        "model.neurons=32")


def readme_example() -> str:
    """The code block of the README's "Python API" section."""
    section = README.split("## Python API", 1)[1]
    return re.search(r"```python\n(.*?)```", section, flags=re.S).group(1)


def test_import_is_light_and_every_public_name_resolves():
    code = ("import sys, hysteresis_lab; heavy = {'torch', 'hydra', 'numpy', 'lightning'}; "
            "print(sorted(heavy & set(sys.modules)))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert proc.stdout.strip() == "[]"
    for name in hl.__all__:
        assert getattr(hl, name) is not None, name
    assert "ffnn" in hl.available_models() and "fsm_piezo_mirror" in hl.available_benchmarks()
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        hl.nope  # noqa: B018


def test_the_readme_example_fits_and_simulates(tmp_path, monkeypatch):
    code = readme_example()
    assert code.count("hl.compose(") == 1
    code = re.sub(r"hl\.compose\((.*?)\)", r"hl.compose(\1, *TINY)", code, count=1)
    monkeypatch.chdir(tmp_path)
    namespace = {"TINY": TINY}
    exec(compile(code, "README.md (Python API)", "exec"), namespace)  # noqa: S102

    data, run, model = namespace["data"], namespace["run"], namespace["model"]
    simulated, scores = namespace["simulated"], namespace["scores"]
    assert [r.name for r in data.test] == ["sine_10Hz", "sine_50Hz"]
    assert (tmp_path / "outputs" / "notebook" / "ffnn" / "metrics.json").is_file()
    skip = run.window.first_target
    train_mean = np.concatenate([r.y for r in data.train]).mean(axis=0)
    for rec, y in zip(data.test, simulated, strict=True):
        assert y.shape == rec.y.shape
        free = scores[rec.name]["rmse_free_run"]
        # the scores are of these simulations, and beat predicting the training mean
        assert free == pytest.approx(rmse(rec.y[skip:], y[skip:]), rel=1e-6)
        assert np.isfinite(free) and free < rmse(rec.y[skip:], np.broadcast_to(train_mean,
                                                                               rec.y[skip:].shape))
    # the saved and loaded model simulates as the trained one does
    for before, after in zip(simulated, hl.simulate(model, data.test), strict=True):
        np.testing.assert_allclose(after, before, rtol=1e-5, atol=1e-6)


def test_train_refuses_the_paper_task():
    cfg = hl.compose("experiment=paper")
    with pytest.raises(hl.HysteresisLabError, match="task=paper"):
        hl.train(cfg, "unused")


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("model.lr=abc", "training.lr='abc' must be a number or null. Fix: e.g. training.lr=0.001"),
        ("model.effects=creep", "model.effects='creep' must be a list. Fix: model.effects=[a,b]"),
        ("model.num_layers=2.5", "model.num_layers=2.5 must be a whole number. Fix: "),
    ],
    ids=["lr", "effects", "num_layers"],
)
def test_the_api_checks_overrides_as_the_console_app_does_before_any_folder(
    tmp_path, override, message
):
    out = tmp_path / "run"
    with pytest.raises(hl.HysteresisLabError) as raised:
        hl.train(hl.compose(override, "trainer.max_epochs=1"), out)
    assert message in str(raised.value)
    assert not out.exists(), "a run folder was made before the checks"
    if override == "model.lr=abc":  # the console app says the very same line
        proc = run_app("train", override, "trainer.max_epochs=1",
                       f"hydra.run.dir={tmp_path}/cli", cwd=tmp_path)
        assert proc.returncode == 2 and str(raised.value) in proc.stdout + proc.stderr


def test_the_api_names_the_public_models_for_an_unknown_one():
    with pytest.raises(hl.HysteresisLabError, match=(
        r"^unknown model 'doesnotexist'\. Valid: cnn, ffnn, .*svm\. Fix: model=")) as raised:
        hl.compose("model=doesnotexist")
    assert "_network" not in str(raised.value)


def test_save_model_to_an_unwritable_path_says_so_with_a_fix(tmp_path):
    from hysteresis_lab.models.ffnn import FFNN

    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    where = re.escape(str(blocker / "model.ckpt"))
    with pytest.raises(hl.HysteresisLabError,
                       match=rf"^{where}: cannot write the model file \(.*\)\. Fix: pass a path"):
        hl.save_model(FFNN(nu=1, ny=1, num_layers=2, neurons=4), blocker / "model")
