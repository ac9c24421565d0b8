"""The import cycles inside a package of furuta_cosim (every import, module-level or inside a
function): none is the rule (docs: Development, the architecture), so that a change to a lower
module never needs one to a higher.

    python tools/import_cycles.py [furuta_cosim/identify]
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def graph(folder: Path) -> dict[str, set[str]]:
    """Module -> the modules of the same package it imports (anywhere in it)."""
    package = ".".join(folder.relative_to(ROOT).parts)
    modules = {p.stem for p in folder.glob("*.py") if p.stem != "__init__"}
    edges: dict[str, set[str]] = {}
    for name in modules:
        found = set()
        for node in ast.walk(ast.parse((folder / f"{name}.py").read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                if node.module.startswith(package + "."):
                    found.add(node.module[len(package) + 1:].split(".")[0])
                elif node.module == package:
                    found |= {a.name for a in node.names if a.name in modules}
        edges[name] = found & modules - {name}
    return edges


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Each strongly connected group of more than one module (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for other in sorted(edges[node]):
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    return sorted(groups)


def main() -> int:
    folder = (ROOT / (sys.argv[1] if len(sys.argv) > 1 else "furuta_cosim/identify")).resolve()
    found = cycles(graph(folder))
    for group in found:
        print("cycle: " + ", ".join(group))
    print(f"{len(found)} cycle(s) among {len(graph(folder))} modules of {folder.relative_to(ROOT)}")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
