"""Functions under ~80 lines (docs/GUIDE's style; issue 33): no function or method in src over
:data:`MAX_LINES` lines, its signature, docstring and nested functions included."""

from __future__ import annotations

import ast
from pathlib import Path

MAX_LINES = 80
SRC = Path(__file__).resolve().parents[1] / "src" / "hydroarm"


def long_functions(root: Path = SRC, limit: int = MAX_LINES) -> list[str]:
    """``path:line name (lines)`` of every function or method under ``root`` longer than ``limit`` lines."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                lines = node.end_lineno - first + 1
                if lines > limit:
                    found.append(f"{path.relative_to(root.parent)}:{node.lineno} {node.name} ({lines} lines)")
    return found


def test_no_function_in_src_is_over_80_lines():
    assert long_functions() == []


def test_the_check_finds_a_long_function(tmp_path):
    """The walk sees functions, methods and nested functions, decorators counted."""
    lines = [f"x{i} = {i}" for i in range(MAX_LINES)]  # a body of 80 lines: 81 with its def
    source = ["def short():", "    return 1", "", "", "class C:", "    @staticmethod", "    def long():"]
    source += ["        " + line for line in lines]
    source += (
        ["", "", "def outer():", "    def inner():"] + ["        " + line for line in lines] + ["    return inner"]
    )
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "m.py").write_text("\n".join(source) + "\n")
    found = long_functions(tmp_path / "pkg")
    assert sorted(entry.split(" ")[1] for entry in found) == ["inner", "long", "outer"]
