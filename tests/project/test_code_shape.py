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


def test_every_room_of_the_core_but_the_cli_and_the_demo_is_kept_from_the_builder() -> None:
    """The contract that keeps ``osmseg.builder`` to the command line and the demo names its sources
    one by one (import-linter has no "all but"): a new module of the core must join the list."""
    import tomllib

    contracts = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    (kept,) = [c for c in contracts if c.get("forbidden_modules") == ["osmseg.builder"]]
    core = REPO_ROOT / "osmseg"
    rooms = {f"osmseg.{p.stem}" for p in core.glob("*.py") if p.stem not in ("__init__", "__main__")}
    rooms |= {f"osmseg.{p.name}" for p in core.iterdir() if (p / "__init__.py").exists()}
    assert rooms - {"osmseg.builder", "osmseg.cli", "osmseg.demo"} <= set(kept["source_modules"])
    assert {"training", "localization"} <= set(kept["source_modules"])


def test_no_private_name_is_imported_across_localizations_wings() -> None:
    """A name starting with ``_`` is used only inside its wing (localization's __init__ promises it)."""
    across = []
    for path in sorted((REPO_ROOT / "localization").rglob("*.py")):
        importer = ".".join(path.relative_to(REPO_ROOT).with_suffix("").parts)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("localization."):
                wing = node.module.split(".")[1]
                if wing != importer.split(".")[1]:
                    across += [f"{importer} <- {node.module}.{a.name}" for a in node.names
                               if a.name.startswith("_") and not a.name.startswith("__")]
    assert not across, "make these public or keep them in their wing: " + "; ".join(across)
