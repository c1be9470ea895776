"""The docs site (mkdocs.yml, docs/) builds in strict mode: a broken link, a page missing from
the menu or an API object that does not exist fails the build, and so this test."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml

from conftest import optional_dependency
from helpers import REPO


def build(config: Path, site: Path) -> subprocess.CompletedProcess:
    """``mkdocs build --strict`` of ``config`` into ``site`` (run from the repository root)."""
    optional_dependency("mkdocs")
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )


def small_site(tmp_path: Path, pages: dict[str, str], nav: list[str]) -> Path:
    """The project's mkdocs.yml (its checks, extensions and plugins) over a few pages."""
    config = yaml.safe_load((REPO / "mkdocs.yml").read_text())
    docs = tmp_path / "docs"
    docs.mkdir()
    for name, text in pages.items():
        (docs / name).write_text(text)
    config.update(docs_dir=str(docs), nav=nav)
    config["plugins"][1]["mkdocstrings"]["handlers"]["python"]["paths"] = [str(REPO / "src")]
    path = tmp_path / "mkdocs.yml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_the_docs_site_builds_with_every_page_and_the_api(tmp_path):
    site = tmp_path / "site"
    proc = build(REPO / "mkdocs.yml", site)
    assert proc.returncode == 0, proc.stderr[-3000:]
    for page in (REPO / "docs").rglob("*.md"):
        stem = page.relative_to(REPO / "docs").with_suffix("")
        html = stem.parent / "index.html" if stem.name == "index" else stem / "index.html"
        assert (site / html).is_file(), page
    api = (site / "api" / "index.html").read_text()
    assert 'id="hysteresis_lab.api.simulate"' in api  # rendered from the docstrings
    assert "Free-run simulation of a fitted model" in api
    # the snippet pages hold the files they include
    assert "Unreleased" in (site / "changelog" / "index.html").read_text()
    assert "refit_choice.py" in (site / "experiments" / "index.html").read_text()


def test_a_broken_link_or_a_page_missing_from_the_menu_fails(tmp_path):
    config = small_site(tmp_path, {"index.md": "# Home\n\nSee [the models](models.md).\n",
                                   "extra.md": "# Not in the menu\n"}, nav=["index.md"])
    proc = build(config, tmp_path / "site")
    assert proc.returncode != 0
    assert "'models.md', but the target is not found" in proc.stderr
    assert "extra.md" in proc.stderr


def test_a_missing_api_object_fails(tmp_path):
    config = small_site(tmp_path, {"index.md": "# API\n\n::: hysteresis_lab.api.no_such_thing\n"},
                        nav=["index.md"])
    proc = build(config, tmp_path / "site")
    assert proc.returncode != 0
    assert "hysteresis_lab.api.no_such_thing could not be found" in proc.stderr
