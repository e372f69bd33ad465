"""Every name the development scripts (scripts/*.py) and the benchmark suite (bench/) import from
hydroarm exists: a module moved or renamed breaks them at their first line, and most are run
by hand, long after the change (scripts/arm_fast_parts.py still imported ``fast_kernels`` from
``model.arm.description`` after the kernels had moved)."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted((ROOT / "scripts").glob("*.py")) + sorted((ROOT / "bench").rglob("*.py"))


def _hydroarm_imports(path: Path) -> list[tuple[str, str | None]]:
    """(module, name or None) of every absolute ``import hydroarm...`` / ``from hydroarm... import``."""
    found: list[tuple[str, str | None]] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "hydroarm":
            found += [(node.module, alias.name) for alias in node.names if alias.name != "*"]
        elif isinstance(node, ast.Import):
            found += [(alias.name, None) for alias in node.names if alias.name.split(".")[0] == "hydroarm"]
    return found


@pytest.mark.parametrize("path", FILES, ids=[str(p.relative_to(ROOT)) for p in FILES])
def test_every_hydroarm_name_a_script_imports_exists(path):
    missing = []
    for module_name, name in _hydroarm_imports(path):
        module = importlib.import_module(module_name)
        if name is None or hasattr(module, name):
            continue
        try:
            importlib.import_module(f"{module_name}.{name}")
        except ModuleNotFoundError:
            missing.append(f"from {module_name} import {name}")
    assert not missing, f"{path.relative_to(ROOT)}: {missing}"


def test_the_check_finds_a_name_that_is_gone(tmp_path):
    script = tmp_path / "stale.py"
    script.write_text("from hydroarm.model.arm.description import fast_kernels\n")
    assert _hydroarm_imports(script) == [("hydroarm.model.arm.description", "fast_kernels")]
    module = importlib.import_module("hydroarm.model.arm.description")
    assert not hasattr(module, "fast_kernels")
