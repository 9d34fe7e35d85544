"""Print osmseg's dependency graph and the figures of how easy it is to enter, package by package.

    python docs/import_graph.py            # this checkout
    git worktree add /tmp/old <commit> && python docs/import_graph.py /tmp/old   # another one
    python docs/import_graph.py --png docs/img/architecture.png   # and draw it (docs/architecture.md)

Imports between the three packages and between the wings (sub-packages) of each, import
cycles, and per package: modules, import floors (the longest chain of imports inside it),
private names (``_name``) imported from another module (and from another wing), how often
``Any`` and ``dict[str, Any]`` appear, and the longest function. Counts every import
statement, at module level or inside a function (grimp, the library under import-linter,
which ``make test`` runs to enforce the contracts in pyproject.toml).
"""

from __future__ import annotations

import ast
import collections
import re
import sys
from pathlib import Path
from typing import cast

import grimp

PACKAGES = ("osmseg", "training", "localization")  # lowest layer first
UP = {(low, high) for i, low in enumerate(PACKAGES) for high in PACKAGES[i + 1:]}


def cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph.modules):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.find_modules_directly_imported_by(w)))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def floors(graph: grimp.ImportGraph, package: str) -> int:
    """How many floors the package's modules stand on: the longest chain of imports inside it.

    A module that imports nothing of its package is on floor 1; one that does, one floor above
    the highest it imports (modules of one import cycle share a floor).
    """
    inside = sorted(m for m in graph.modules if m == package or m.startswith(package + "."))
    members = set(inside)
    component = {m: m for m in inside}
    for group in cycles(graph):
        for m in group:
            if m in component:
                component[m] = group[0]
    level: dict[str, int] = {}

    def floor(m: str) -> int:
        key = component[m]
        if key in level:
            return level[key]
        below = [i for i in graph.find_modules_directly_imported_by(m) if i in members and component[i] != key
                 and not _is_package_of(i, m)]
        level[key] = 1 + max((floor(i) for i in below), default=0)
        return level[key]

    sys.setrecursionlimit(10000)
    return max((floor(m) for m in inside), default=0)


def _is_package_of(package: str, module: str) -> bool:
    """``package`` is an ``__init__`` above ``module`` (importing a sibling through it adds no floor)."""
    return module.startswith(package + ".")


def source_figures(root: Path, package: str) -> dict[str, object]:
    """Counted from the source text: ``Any``, private names imported from another module, the longest
    function, and the function with the most parameters."""
    any_count = dict_any = 0
    private: list[str] = []
    longest = widest = (0, "")
    for path in sorted((root / package).rglob("*.py")):
        text = path.read_text()
        any_count += len(re.findall(r"\bAny\b", text)) - len(re.findall(r"^from typing import.*\bAny\b", text, re.M))
        dict_any += text.count("dict[str, Any]")
        tree = ast.parse(text)
        name = ".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__")
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES \
                    and node.module != name:
                private += [f"{name} <- {node.module}.{a.name}" for a in node.names
                            if a.name.startswith("_") and not a.name.startswith("__")]
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > longest[0]:
                    longest = (n, f"{path.relative_to(root)}:{node.lineno} {node.name}")
                a = node.args
                width = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) - (a.args[:1] != [] and
                                                                               a.args[0].arg in ("self", "cls"))
                if width > widest[0]:
                    widest = (width, f"{path.relative_to(root)}:{node.lineno} {node.name}")
    return {"any": any_count, "dict_any": dict_any, "private": private, "longest": longest, "widest": widest}


def wings(graph: grimp.ImportGraph, package: str) -> collections.Counter[tuple[str, str]]:
    """Imports between the sub-packages of ``package``: importer -> imported, modules importing.

    Its top-level modules count as one wing, ``(rooms)``, when it has more than a few (the
    core's shared rooms: grid, classes, errors, ...); else each is its own (localization's
    ``pipeline``).
    """
    top = {m.split(".")[1] for m in graph.modules if m.startswith(package + ".")}
    packages = {name for name in top if any(m.startswith(f"{package}.{name}.") for m in graph.modules)}
    rooms = len(top - packages) > 5

    def wing(module: str) -> str:
        name = module.split(".")[1]
        return "(rooms)" if rooms and name not in packages else name

    edges: collections.Counter[tuple[str, str]] = collections.Counter()
    for module in graph.modules:
        if not module.startswith(package + "."):
            continue
        for imported in graph.find_modules_directly_imported_by(module):
            if imported.startswith(package + "."):
                a, b = wing(module), wing(imported)
                if a != b:
                    edges[(a, b)] += 1
    return edges


def picture(graph: grimp.ImportGraph, path: Path) -> None:
    """The layers as rows (core at the bottom), each package's wings as boxes with their module
    counts, and a line per pair of wings that import each other, as thick as the importing modules
    are many: what docs/architecture.md shows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    where: dict[tuple[str, str], tuple[float, float]] = {}
    sizes: collections.Counter[tuple[str, str]] = collections.Counter()
    for module in graph.modules:
        package = module.split(".")[0]
        sizes[(package, wing_of(graph, package, module))] += 1
    fig, ax = plt.subplots(figsize=(13, 7.5))
    colours = {"osmseg": "#4c72b0", "training": "#dd8452", "localization": "#55a868"}
    for row, package in enumerate(PACKAGES):
        names = sorted(w for p, w in sizes if p == package)
        for i, name in enumerate(names):
            x = (i + 0.5) / len(names)
            where[(package, name)] = (x, row)
            ax.text(x, row, f"{name}\n{sizes[(package, name)]} modules", ha="center", va="center", fontsize=9,
                    bbox={"boxstyle": "round", "fc": colours[package], "alpha": 0.25, "ec": colours[package]})
        ax.text(-0.07, row, package, ha="right", va="center", fontsize=12, weight="bold", color=colours[package])
    edges: collections.Counter[tuple[tuple[str, str], tuple[str, str]]] = collections.Counter()
    for module in graph.modules:
        a = (module.split(".")[0], wing_of(graph, module.split(".")[0], module))
        for imported in graph.find_modules_directly_imported_by(module):
            b = (imported.split(".")[0], wing_of(graph, imported.split(".")[0], imported))
            if a != b:
                edges[(a, b)] += 1
    for (a, b), n in edges.items():
        (x0, y0), (x1, y1) = where[a], where[b]
        ax.annotate("", xy=(x1, y1 + (0.12 if y1 < y0 else -0.12 if y1 > y0 else 0)), xytext=(x0, y0),
                    arrowprops={"arrowstyle": "->", "lw": 0.4 + 0.25 * n ** 0.5, "alpha": 0.35,
                                "color": "#b00" if PACKAGES.index(b[0]) > PACKAGES.index(a[0]) else "#444",
                                "connectionstyle": "arc3,rad=0.15" if y0 == y1 else "arc3,rad=0.0"})
    ax.set_xlim(-0.25, 1.02)
    ax.set_ylim(-0.6, len(PACKAGES) - 0.4)
    ax.axis("off")
    ax.set_title("osmseg's packages as layers (bottom: the core) and their wings; an arrow from the importer to "
                 "what it imports,\nthicker for more importing modules (a red arrow would import upward: there is "
                 "none). Drawn by docs/import_graph.py --png", fontsize=10)
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def wing_of(graph: grimp.ImportGraph, package: str, module: str) -> str:
    """The wing of ``module`` in ``package``: its sub-package, ``(rooms)`` for the top-level modules
    of a package with more than a few, the module itself otherwise (as :func:`wings` groups them)."""
    top = {m.split(".")[1] for m in graph.modules if m.startswith(package + ".")}
    packages = {name for name in top if any(m.startswith(f"{package}.{name}.") for m in graph.modules)}
    if module == package:
        return "(rooms)" if len(top - packages) > 5 else "__init__"
    name = module.split(".")[1]
    return "(rooms)" if len(top - packages) > 5 and name not in packages else name


def main(root: Path, png: Path | None = None) -> None:
    sys.path.insert(0, str(root))
    graph = grimp.build_graph(*PACKAGES, cache_dir=None)
    edges: collections.Counter[tuple[str, str]] = collections.Counter()
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            a, b = module.split(".")[0], imported.split(".")[0]
            if a != b:
                edges[(a, b)] += 1
    print(f"{root}: {len(graph.modules)} modules")
    print("imports between packages (importer -> imported: modules importing):")
    for (a, b), n in sorted(edges.items()):
        print(f"  {a:12} -> {b:12} {n:3}{'   UPWARD' if (a, b) in UP else ''}")
    print(f"upward imports: {sum(n for edge, n in edges.items() if edge in UP)}")
    found = cycles(graph)
    print(f"module import cycles: {len(found)}")
    for component in found:
        print("  " + " <-> ".join(component))
    for package in PACKAGES:
        figures = source_figures(root, package)
        modules = [m for m in graph.modules if m == package or m.startswith(package + ".")]
        private = cast("list[str]", figures["private"])
        across = [line for line in private if _wing(line.split(" <- ")[0]) != _wing(line.split(" <- ")[1])]
        lines, where = cast("tuple[int, str]", figures["longest"])
        params, wide = cast("tuple[int, str]", figures["widest"])
        print(f"{package}: {len(modules)} modules on {floors(graph, package)} import floors; private names imported "
              f"from another module {len(private)} (from another wing {len(across)}); Any {figures['any']} "
              f"(dict[str, Any] {figures['dict_any']}); longest function {lines} lines ({where}); most parameters "
              f"{params} ({wide})")
        for line in across:
            print(f"  private across wings: {line}")
        between = wings(graph, package)
        if any("." in m[len(package) + 1:] for m in modules):  # a package with wings
            print(f"  imports between {package}'s wings (importer -> imported: modules importing):")
            for (a, b), n in sorted(between.items()):
                print(f"    {a:12} -> {b:12} {n:3}")
    if png is not None:
        picture(graph, png)
        print(f"drew {png}")


def _wing(name: str) -> str:
    """The wing a module or name belongs to: its package's sub-package, or the module itself at the top."""
    parts = name.split(".")
    return ".".join(parts[:2])


if __name__ == "__main__":
    args = sys.argv[1:]
    drawn = None
    if "--png" in args:
        at = args.index("--png")
        drawn = Path(args[at + 1]).resolve()
        del args[at:at + 2]
    main(Path(args[0] if args else Path(__file__).resolve().parent.parent).resolve(), drawn)
