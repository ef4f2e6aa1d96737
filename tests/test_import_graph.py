"""The package's import graph: no cycle between its parts, and no import from a lower layer
back up (the agent never imports an add-on; controllers never import tasks)."""

from __future__ import annotations

import ast
from pathlib import Path

import sili_robots

ROOT = Path(sili_robots.__file__).parent
#: (part, part it must never import): lower layers do not reach up
FORBIDDEN = [
    ("agent", "addons"),
    ("agent", "tasks"),
    ("agent", "controllers"),
    ("agent", "commands"),
    ("controllers", "tasks"),
    ("tasks", "agent"),
    ("tasks", "addons"),
    ("tasks", "commands"),
    ("addons", "commands"),
]


def part_of(module: str) -> str:
    """``sili_robots.agent.sac`` -> ``agent``; ``sili_robots.cli`` -> ``cli``."""
    return module.split(".")[1] if module.count(".") >= 1 else "__init__"


def imports() -> dict[str, set[str]]:
    """part -> the parts its modules import (at any depth: inside functions too)."""
    graph: dict[str, set[str]] = {}
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        module = ".".join(rel.parts).removesuffix(".__init__")
        src = part_of(module) if module != "sili_robots" else "__init__"
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                if name.startswith("sili_robots.") and part_of(name) != src:
                    graph.setdefault(src, set()).add(part_of(name))
    return graph


def test_no_part_imports_a_higher_layer():
    graph = imports()
    assert "addons" in graph and "agent" in graph["addons"]  # the graph is really read
    bad = [(a, b) for a, b in FORBIDDEN if b in graph.get(a, set())]
    assert not bad, f"imports from a lower layer up: {bad}"


def test_the_parts_import_each_other_without_a_cycle():
    graph = imports()
    graph.pop("__init__", None)  # the package root only registers the tasks and names the API
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycle = [*path[path.index(nxt) :], nxt]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if nxt not in state:
                visit(nxt)
        path.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
