"""Print osmseg's dependency graph: imports between the three packages, and import cycles.

    python docs/import_graph.py            # this checkout
    git worktree add /tmp/old <commit> && python docs/import_graph.py /tmp/old   # another one

Counts every import statement, at module level or inside a function (grimp, the library
under import-linter, which ``make test`` runs to enforce the layers in pyproject.toml).
"""

from __future__ import annotations

import collections
import sys
from pathlib import Path

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


def main(root: Path) -> None:
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


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent).resolve())
