"""The docs site (mkdocs.yml, docs/) and the example notebooks stay true.

* every public name of ``hydroarm`` (``hydroarm.__all__``) is listed in the API reference
  (docs/api/index.md), linked to where it is defined, and that module is rendered by a
  mkdocstrings directive; with the ``docs`` extra installed, the built site's inventory
  holds every one of them;
* the Gymnasium page's Python runs as written;
* the notebooks in examples/notebooks/ are committed without outputs (CI runs them with
  ``pytest --nbmake``).
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import os
import re
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

import hydroarm

ROOT = Path(__file__).resolve().parents[1]
API_PAGES = ROOT / "docs" / "api"
NOTEBOOKS = ROOT / "examples" / "notebooks"
SUBPACKAGES = ("hydroarm.model", "hydroarm.control", "hydroarm.studies", "hydroarm.envs")

# [`hydroarm.Arm`][hydroarm.model.arm.description.Arm]: the public name and the autorefs identifier of its definition
LINK = re.compile(r"\[`hydroarm\.(\w+)`\]\[([\w.]+)\]")
# ::: identifier, then its indented options
DIRECTIVE = re.compile(r"^::: ([\w.]+)[ \t]*\n((?:[ \t]+\S.*\n?)*)", re.M)


def _api_text() -> str:
    return "\n".join(page.read_text() for page in sorted(API_PAGES.glob("*.md")))


def _directives() -> dict[str, str]:
    return {match[1]: match[2] for match in DIRECTIVE.finditer(_api_text())}


def _rendered(module: str, directives: dict[str, str]) -> bool:
    """Whether a directive renders ``module``: itself, or a package above it with its submodules."""
    return module in directives or any(
        module.startswith(f"{package}.") and re.search(r"show_submodules:\s*true", options)
        for package, options in directives.items()
    )


def public_identifiers() -> dict[str, str]:
    """Each public name -> the identifier the API reference links it to."""
    return dict(LINK.findall((API_PAGES / "index.md").read_text()))


def test_every_public_name_is_in_the_api_reference():
    links = public_identifiers()
    missing = sorted(set(hydroarm.__all__) - set(links))
    assert not missing, f"docs/api/index.md does not list {missing}"
    assert not sorted(set(links) - set(hydroarm.__all__)), "docs/api/index.md lists names hydroarm does not export"
    directives = _directives()
    for name in hydroarm.__all__:
        module, _, attr = links[name].rpartition(".")
        assert attr == name, links[name]
        assert not any(part.startswith("_") for part in module.split(".")), f"{name}: a private module"
        # the link names where the object is defined (or a public module that exports it) ...
        assert getattr(importlib.import_module(module), name) is getattr(hydroarm, name), links[name]
        # ... and that module is on an API page
        assert _rendered(module, directives), f"{links[name]}: no mkdocstrings directive renders {module}"


def test_the_subpackages_are_rendered_whole():
    directives = _directives()
    for package in SUBPACKAGES:
        assert package in directives, f"no API page renders {package}"
        assert re.search(r"show_submodules:\s*true", directives[package]), package


def _inventory(path: Path) -> set[str]:
    """The identifiers in a Sphinx inventory (objects.inv, version 2) that mkdocstrings writes."""
    data = path.read_bytes()
    body = data.split(b"\n", 4)[4]
    return {line.split(" ", 1)[0] for line in zlib.decompress(body).decode().splitlines()}


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason="needs the docs extra")
def test_the_built_site_documents_every_public_name(tmp_path):
    site = tmp_path / "site"
    # not --strict: CI's strict build (.ci/run) is the check of links and warnings
    subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--quiet", "--site-dir", str(site)],
        cwd=ROOT,
        check=True,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    documented = _inventory(site / "objects.inv")
    links = public_identifiers()
    missing = sorted(name for name in hydroarm.__all__ if links[name] not in documented)
    assert not missing, f"not rendered on the site: {missing}"
    for package in SUBPACKAGES:
        assert package in documented or any(d.startswith(f"{package}.") for d in documented), package


@pytest.mark.slow
def test_the_gymnasium_page_runs(tmp_path, monkeypatch):
    pytest.importorskip("gymnasium")
    page = ROOT / "docs" / "envs.md"
    blocks = re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S)
    assert len(blocks) >= 3
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(page), "exec"), namespace)  # noqa: S102 - our own docs
    assert len(namespace["rewards"]) > 0
    assert namespace["policy"].env.steps == 1000


def test_notebooks_are_committed_without_outputs():
    notebooks = sorted(NOTEBOOKS.glob("*.ipynb"))
    assert len(notebooks) >= 4
    for path in notebooks:
        cells = json.loads(path.read_text())["cells"]
        for cell in cells:
            if cell["cell_type"] == "code":
                assert cell.get("outputs") == [] and cell.get("execution_count") is None, (
                    f"{path.name}: clear the outputs before committing (Kernel > Restart & Clear Output)"
                )
