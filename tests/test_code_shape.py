"""The code stays readable in small pieces: no function or method of the three packages is longer
than 80 lines (issue 21: the long ones were split, and this keeps them so)."""

from __future__ import annotations

import ast

from conftest import REPO_ROOT

LONGEST = 80


def test_no_function_is_longer_than_80_lines() -> None:
    long = []
    for package in ("osmseg", "training", "localization"):
        for path in sorted((REPO_ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    lines = (node.end_lineno or node.lineno) - node.lineno + 1
                    if lines > LONGEST:
                        long.append(f"{path.relative_to(REPO_ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, "split these functions: " + "; ".join(long)
