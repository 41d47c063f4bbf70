"""schemas/ has no import cycle: every import a module makes (at load time, inside a
function, or for type checking only) forms a graph without loops. A model family
validates against `catalog.ModelContext`, not the whole Scenario, and `get_preset` lives
beside the Scenario it returns, so nothing reaches back up (before: 11 of 15 modules on a
cycle, held apart by deferred and TYPE_CHECKING imports)."""

from __future__ import annotations

import ast
from pathlib import Path

SCHEMAS = Path(__file__).resolve().parents[2] / "schemas"


def _imports(path: Path) -> set[str]:
    """The schemas modules a module imports anywhere in its source (relative imports)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            if node.module:
                out.add(node.module.split(".")[0])
            else:  # from . import a, b
                out.update(alias.name for alias in node.names)
    return out


def _graph() -> dict[str, set[str]]:
    return {p.stem: _imports(p) for p in SCHEMAS.glob("*.py")
            if p.stem != "__init__"}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1: on the path, 2: done
    path: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        path.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                return [*path[path.index(n):], n]
            if n not in state and (found := visit(n)):
                return found
        path.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_schemas_modules_import_without_a_cycle():
    graph = _graph()
    assert {"scenario", "catalog", "models", "presets", "vicsek"} <= set(graph)
    assert _cycle(graph) is None, " -> ".join(_cycle(graph) or [])


def test_the_cycle_finder_finds_one():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None
