"""A wheel built from the source tree carries its configs: installed without the checkout (no
editable install), every command still composes its config and runs."""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def run(*args: str | Path, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=600, env=env
    )


def inner_venv(venv: Path) -> Path:
    """A venv of this Python that sees this environment's packages but not its
    ``hysteresis_lab``: ``--system-site-packages`` alone would see the base interpreter's
    site-packages, not those of a venv the tests run in. The outer site directories are
    added as plain paths (a ``.pth`` file), so their own ``.pth`` files, e.g. an editable
    install's finder, are not run; pip comes from there too."""
    made = run(sys.executable, "-m", "venv", "--without-pip", venv, cwd=venv.parent)
    assert made.returncode == 0, made.stderr[-3000:]
    python = venv / "bin" / "python"
    inner = run(python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])",
                cwd=venv.parent, env=clean_env())
    outer = [*site.getsitepackages(), *([site.getusersitepackages()] if site.ENABLE_USER_SITE
                                         else [])]
    Path(inner.stdout.strip(), "outer_site_packages.pth").write_text("\n".join(outer) + "\n")
    return python


def clean_env() -> dict[str, str]:
    """This environment without the checkout or the outer venv on the path."""
    return {k: v for k, v in os.environ.items() if k not in {"PYTHONPATH", "VIRTUAL_ENV"}}


@pytest.mark.slow
def test_an_installed_wheel_runs_its_commands_outside_the_checkout(tmp_path):
    # built from a copy of what the sdist holds, so that the checkout gets no build/ folder
    source = tmp_path / "source"
    shutil.copytree(
        REPO / "src", source / "src", ignore=shutil.ignore_patterns("*.egg-info", "__pycache__")
    )
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    dist = tmp_path / "dist"
    built = run(sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", dist, source, cwd=tmp_path)
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = dist.glob("hysteresis_lab-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {"hysteresis_lab/conf/train.yaml", "hysteresis_lab/conf/data/csv.yaml"} <= set(names)

    venv = tmp_path / "venv"
    python = inner_venv(venv)
    installed = run(python, "-m", "pip", "install", "--no-deps", "--no-index", "--force-reinstall",
                    wheel, cwd=tmp_path, env=clean_env())
    assert installed.returncode == 0, installed.stderr[-3000:]

    # outside the checkout, with nothing of it on the path: only the wheel's files are used
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    env = clean_env()
    where = run(
        python, "-c", "import hysteresis_lab; print(hysteresis_lab.__file__)", cwd=cwd, env=env
    )
    assert str(venv) in where.stdout, (where.stdout, where.stderr)
    for command in ("train", "evaluate", "loop", "simulate"):
        proc = run(venv / "bin" / f"hysteresis-lab-{command}", "--help", cwd=cwd, env=env)
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert "== Configuration groups ==" in proc.stdout
    out = cwd / "sine.csv"
    proc = run(
        venv / "bin" / "hysteresis-lab-simulate",
        "signal.kind=sine",
        "signal.frequency=100",
        f"output={out}",
        cwd=cwd,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert out.read_text().startswith("t,u,y")
